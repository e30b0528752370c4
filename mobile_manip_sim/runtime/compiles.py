"""Count numba's compiles as they happen: a node that has loaded its kernels
(`Simulation.load_kernels`) says so when anything compiles after all (a compile holds a step
for seconds to minutes), and the tests prove that nothing does.

numba fires its ``numba:compile`` event only when it compiles a kernel, not when it loads one
from its on-disk cache, so the count is the number of kernels compiled (a kernel compiled with
its callees counts each of them). Without numba it counts nothing.
"""
from __future__ import annotations

import threading


class CompileWatch:
    """From `start` until `stop`: `names` of the kernels numba compiled, in order, and
    ``on_compile(name)`` called for each (in the compiling thread)."""

    def __init__(self, on_compile=None):
        self.names: list[str] = []
        self._on_compile = on_compile
        self._lock = threading.Lock()
        self._listener = None

    @property
    def count(self) -> int:
        with self._lock:
            return len(self.names)

    def start(self) -> "CompileWatch":
        from ..dynamics.jit import ENABLED
        if not ENABLED or self._listener is not None:
            return self
        from numba.core import event

        watch = self

        class Listener(event.Listener):
            def on_start(self, ev):
                dispatcher = ev.data.get("dispatcher")
                function = getattr(dispatcher, "py_func", None)
                name = (f"{function.__module__}.{function.__qualname__}" if function is not None
                        else str(dispatcher))
                with watch._lock:
                    watch.names.append(name)
                if watch._on_compile is not None:
                    watch._on_compile(name)

            def on_end(self, ev):
                pass

        self._listener = Listener()
        event.register("numba:compile", self._listener)
        return self

    def stop(self) -> None:
        if self._listener is not None:
            from numba.core import event
            event.unregister("numba:compile", self._listener)
            self._listener = None
