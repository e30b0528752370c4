"""Count numba's compiles as they happen: a node that has loaded its kernels
(`Simulation.load_kernels`) says so when anything compiles after all (a compile holds a step
for seconds to minutes), and the tests prove that nothing does.

numba fires its ``numba:compile`` event only when it compiles a kernel, not when it loads one
from its on-disk cache, so the count is the number of kernels compiled (a kernel compiled with
its callees counts each of them). Without numba it counts nothing. `CompileNotice` rests on it
too: the node's start-up says so when it compiles instead of loading.
"""
from __future__ import annotations

import threading
import time


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


class CompileNotice:
    """Says that work which should only load the kernels is compiling them (an install never
    warmed up: minutes): ``first`` once, at the first compile — a warmed start, which loads
    them from the cache, says nothing — then a line every ``every`` s while the work lasts, and
    at its end, unless an exception ended it, how long it took. ``say`` takes each line (a
    logger's method).

        with CompileNotice(log.warning, "compiling the kernels …"):
            sim.load_kernels()
    """

    def __init__(self, say, first: str, every: float = 10.0):
        self._say, self._first, self._every = say, first, every
        self._watch = CompileWatch(self._compiling)
        self._done = threading.Event()
        self._ticker: threading.Thread | None = None
        self._start = 0.0

    def __enter__(self) -> "CompileNotice":
        self._watch.start()
        return self

    def __exit__(self, kind, *exc) -> None:
        self._watch.stop()
        self._done.set()
        if self._ticker is not None:
            self._ticker.join()
            if kind is None:   # not stopped halfway (Ctrl-C, SIGTERM, an error)
                self._say(f"kernels compiled in {time.monotonic() - self._start:.0f} s "
                          f"({self._watch.count} of them)")

    def _compiling(self, name: str) -> None:
        # numba compiles under one lock: the calls come one at a time
        if self._ticker is not None:
            return
        self._start = time.monotonic()
        self._say(self._first)
        self._ticker = threading.Thread(target=self._tick, name="compile notice", daemon=True)
        self._ticker.start()

    def _tick(self) -> None:
        # it runs while numba compiles: LLVM's passes, called through ctypes, release the GIL
        while not self._done.wait(self._every):
            self._say(f"still compiling the kernels ({time.monotonic() - self._start:.0f} s, "
                      f"{self._watch.count} compiled so far)")
