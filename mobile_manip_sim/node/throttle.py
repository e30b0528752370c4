"""`Throttle`: one warning of a kind per `WARN_EVERY` wall seconds (a flood of bad commands, a
node that keeps falling behind, a lockstep peer that keeps silent)."""
from __future__ import annotations

import time
from typing import Callable

WARN_EVERY = 5.0   # s of wall time between repeats of one kind of warning


class Throttle:
    """``warn(key, text)`` logs ``text`` through ``log`` unless a warning of the same ``key``
    went out less than WARN_EVERY s ago; True when it did log."""

    def __init__(self, log: Callable[[str], None], clock: Callable[[], float] = time.monotonic):
        self.log, self.clock = log, clock
        self._warned_at: dict[tuple, float] = {}   # key → wall time of its last warning

    def warn(self, key: tuple, text: str) -> bool:
        now = self.clock()
        last = self._warned_at.get(key)
        if last is not None and now - last < WARN_EVERY:
            return False
        self._warned_at[key] = now
        self.log(text)
        return True
