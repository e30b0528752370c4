"""`Pacer`: when the node's publications are due on the wall clock, and whether it keeps up.

Publication k is due at ``wall₀ + (t_k − t₀) / real_time_factor`` from an anchor (wall₀, t₀).
The anchor moves when the factor changes, on resume and on reset — and when the node falls
behind by more than the tolerance: it then paces on from there instead of bursting to catch up,
and reports the real-time factor it measured since the last report. ROS-free, with an
injectable clock, so the rules are tested without waiting (test_pacing.py).
"""
from __future__ import annotations

import time
from typing import Callable

from .timeline import NS

LAG_TOLERANCE = 0.1        # s behind the wall clock before the node says it cannot keep up
LAG_PERIODS = 5.0          # … or this many publication periods, when that is longer


class Pacer:
    """Paces publications ``period`` simulated seconds apart at ``real_time_factor`` (0: as
    fast as possible, nothing is ever due later than now)."""

    def __init__(self, real_time_factor: float, period: float,
                 clock: Callable[[], float] = time.monotonic):
        self.real_time_factor = real_time_factor
        self.period = period
        self.clock = clock
        self.anchor = (clock(), 0)     # (wall s, simulated ns) pacing origin
        self.window = self.anchor      # start of the real-time-factor measurement

    @property
    def paced(self) -> bool:
        return self.real_time_factor > 0

    def reanchor(self, now_ns: int) -> None:
        """Pace from ``now_ns`` on as from this wall instant (start, resume, reset)."""
        self.anchor = (self.clock(), now_ns)
        self.window = self.anchor

    def set_real_time_factor(self, factor: float, now_ns: int) -> None:
        self.real_time_factor = factor
        self.reanchor(now_ns)

    def delay(self, stamp: int) -> float:
        """Wall seconds until the publication stamped ``stamp`` ns is due (≤ 0: now or late)."""
        if not self.paced:
            return 0.0
        wall0, ns0 = self.anchor
        return wall0 + (stamp - ns0) / NS / self.real_time_factor - self.clock()

    def late(self, stamp: int, late: float) -> float | None:
        """Publishing ``stamp`` ``late`` wall seconds after it was due. Beyond the tolerance:
        pace on from here (no burst to catch up) and return the real-time factor measured
        since the window began (NaN when no wall time passed); within it: None."""
        if not self.paced or late <= max(LAG_TOLERANCE, LAG_PERIODS * self.period
                                         / self.real_time_factor):
            return None
        wall = self.clock()
        wall0, ns0 = self.window
        measured = (stamp - ns0) / NS / (wall - wall0) if wall > wall0 else float("nan")
        self.anchor = (wall, stamp)
        return measured

    def wait_for(self, stamp: int, first: bool = False,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        """Sleep until the sample stamped ``stamp`` ns is due, pacing from it when it is a run's
        ``first``; a sample already past is noted `late` (no burst to catch up). For the
        headless views, which pace a run's own samples."""
        if first:
            self.reanchor(stamp)
        delay = self.delay(stamp)
        if delay > 0:
            sleep(delay)
        else:
            self.late(stamp, -delay)

    def restart_window(self) -> None:
        """Measure the real-time factor from the current anchor on (after a report)."""
        self.window = self.anchor
