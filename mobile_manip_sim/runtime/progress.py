"""Progress of long work on stderr: how much is done of how much, the rate, the time to go.

    progress = Progress("simulate", duration, "s", rate_unit="× real time")
    progress.follow(lambda: sim.t)   # optional: read while the work is inside one long call
    progress.update(done)            # from the work loop
    progress.close()

    with Progress("sweep", None, "starting a LocalCluster of 2 workers"):   # a phase
        ...

Two forms:
- a status line (the default), rewritten in place, on a terminal only — a pipe or a log gets
  nothing. It is written when the work starts, refreshed by `update` at most every REFRESH s,
  and by a ticker thread every second even while the work sits in one long compiled call (then
  `follow()` says how far it is). A phase (`total` None: work whose size is unknown, such as a
  cluster starting) says what is under way and for how long.
- whole lines (``lines=True``): a line whenever nothing was written for TICK s, on a terminal
  only. `note` writes the work's own lines through it, which also resets the silence.

Used by `simulate`, `replay --resimulate`, `sweep` and `bench`.
"""
from __future__ import annotations

import math
import sys
import threading
import time
from typing import Callable

REFRESH = 0.5   # s between two rewrites of the status line by `update`
TICK = 5.0      # s of silence at most (the promise is 10 s)


def duration_text(seconds: float) -> str:
    """A duration as people read it: '42 s', '3 min 20 s', '6 h 40 min'; '?' when unknown."""
    if not math.isfinite(seconds) or seconds < 0:
        return "?"
    seconds = round(seconds)
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60} min"


class Progress:
    def __init__(self, what: str, total: float | None, unit: str, *, done: float = 0.0,
                 rate_unit: str | None = None, per: float = 1.0, lines: bool = False,
                 stream=None):
        self.what, self.total, self.unit = what, total, unit
        self.rate_unit, self.per = rate_unit or f"{unit}/s", per   # rate: done per `per` s
        self.stream = stream or sys.stderr
        self.lines = lines
        self.active = _is_terminal(self.stream)
        self.done = self.first = done
        self.extra = ""
        self._follow: Callable[[], float] | None = None
        self._lock = threading.Lock()
        self._start = self._written = time.monotonic()
        self._stop = threading.Event()
        self._ticker = None
        if self.active:
            if not lines:   # at once: a phase that starts talks within its first second
                self._write(self.status())
            self._ticker = threading.Thread(target=self._tick, name="progress", daemon=True)
            self._ticker.start()

    def follow(self, source: Callable[[], float]) -> None:
        """Read how much is done from `source()` (a number) when the ticker writes."""
        self._follow = source

    def update(self, done: float, extra: str = "") -> None:
        self.done, self.extra = done, extra
        if self.active and not self.lines and time.monotonic() - self._written >= REFRESH:
            self._write(self.status())

    def note(self, text: str) -> None:
        """One line of the work's own (always written, progress or not)."""
        with self._lock:
            clear = "\r\x1b[K" if self.active and not self.lines else ""
            self.stream.write(f"{clear}{text}\n")
            self.stream.flush()
            self._written = time.monotonic()

    def status(self) -> str:
        done = self.done
        if self._follow is not None:
            done = max(done, self._follow())
        elapsed = time.monotonic() - self._start
        if self.total is None:   # a phase
            return f"{self.what}: {self.unit} ({duration_text(elapsed)}){self.extra}"
        rate = (done - self.first) / elapsed if elapsed > 0 else 0.0
        to_go = (self.total - done) / rate if rate > 0 else math.inf
        share = f" ({100 * done / self.total:.0f} %)" if self.total > 0 else ""
        return (f"{self.what}: {done:.6g} of {self.total:.6g} {self.unit}{share}, "
                f"{rate * self.per:.3g} {self.rate_unit}, {duration_text(to_go)} to go{self.extra}")

    def close(self) -> None:
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()
        if self.active and not self.lines:
            with self._lock:
                self.stream.write(f"\r\x1b[K{self.status()}\n")
                self.stream.flush()

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _tick(self) -> None:
        while not self._stop.wait(min(TICK, 1.0)):
            if time.monotonic() - self._written >= (TICK if self.lines else 1.0):
                self._write(self.status())

    def _write(self, text: str) -> None:
        with self._lock:
            if self._stop.is_set() and threading.current_thread() is self._ticker:
                return
            self.stream.write(f"{text}\n" if self.lines else f"\r\x1b[K{text}")
            self.stream.flush()
            self._written = time.monotonic()


def _is_terminal(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):   # no isatty, or closed
        return False
