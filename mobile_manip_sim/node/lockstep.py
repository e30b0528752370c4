"""Synchronous mode (parameter `synchronous`): the node steps in lockstep with a controller.

The first state goes out once someone listens to a state topic and someone publishes a command
topic (`ready`). After state k went out, segment k is computed only once a new command has come
on every command topic that has a publisher (so wheel and arm commands sent in reply to one
state apply together), or after `sync_timeout` wall seconds: then the last command is held and
the node says so. No ROS here: the waiting is the command intake's (commands.py).
"""
from __future__ import annotations

import time
from typing import Callable

from ..runtime.timeline import NS, format_ns
from .throttle import Throttle

SAY_EVERY = 5.0   # s of wall time between two lines saying what the start waits for


class Lockstep:
    """``commands`` is the node's `CommandIntake`; ``listening()`` says whether a state topic
    has a subscriber."""

    def __init__(self, commands, listening: Callable[[], bool], timeout: float,
                 throttle: Throttle, clock: Callable[[], float] = time.monotonic):
        self.commands, self.listening = commands, listening
        self.timeout = timeout
        self._throttle, self._clock = throttle, clock
        self._said: float | None = None   # when the waiting start last said what it waits for

    def ready(self) -> bool:
        """The start condition: someone listens, someone commands."""
        return self.listening() and any(self.commands.commanded())

    def waiting(self, say: Callable[[str], None]) -> None:
        """Called while the start waits: every SAY_EVERY s, one line naming what is missing
        (a controller that publishes on a topic the node does not take heard nothing)."""
        now = self._clock()
        if self._said is None:
            self._said = now
        if now - self._said < SAY_EVERY:
            return
        self._said = now
        missing = []
        if not self.listening():
            missing.append("a subscriber of its states")
        if not any(self.commands.commanded()):
            missing.append(f"a publisher on {' or '.join(self.commands.topic_names())} (none "
                           f"has one)")
        if missing:
            say(f"synchronous: the first state waits for {' and '.join(missing)}")

    def publishing(self, now_ns: int) -> None:
        """Just before a state goes out: commands sent before it are not replies to it."""
        self.commands.drain(now_ns)
        self.commands.mark_published()

    def answered(self, now_ns: int) -> bool:
        self.commands.drain(now_ns)
        fresh = self.commands.replies()
        commanding = self.commands.commanded()
        return any(fresh) and all(f or not c for f, c in zip(fresh, commanding, strict=True))

    def await_replies(self, now_ns: int, interrupted: Callable[[], bool]) -> None:
        """Before computing the segment from ``now_ns``: until every commanding topic has
        answered the latest state, ``interrupted()`` (pause, reset, step, stop) or the timeout."""
        end = self._clock() + self.timeout
        while not (self.answered(now_ns) or interrupted()):
            remaining = end - self._clock()
            if remaining <= 0:
                self._throttle.warn(("sync",), f"synchronous: no command within sync_timeout "
                                               f"{self.timeout:g} s after t = "
                                               f"{format_ns(now_ns)} s; holding the last one")
                return
            self.commands.wait(remaining)


class ClockFollower:
    """The pacer of a node that does not publish /clock (publish_clock false): state k, stamped
    t_k, goes out once the /clock it hears (another simulator's) has reached t_k, so every
    message of every robot is stamped on that one clock and none ahead of it; the node runs
    as fast as that clock, never faster, and behind it when it cannot keep up (its stamps then
    lie in the past, never in the future). Until a /clock is heard, only t = 0 goes out.
    `heard` is called from the /clock subscription; ``notify()`` wakes the stepping thread.
    It stands in for a `runtime.pacing.Pacer` (the same methods; real_time_factor is moot)."""

    POLL = 0.5   # s: the longest wait between looks at the clock (a notification ends it early)
    JUMP = 3600.0   # s: a /clock that leaps further ahead at once is followed, and said

    def __init__(self, real_time_factor: float, period: float,
                 clock: Callable[[], float] = time.monotonic):
        self.real_time_factor, self.period, self.clock = real_time_factor, period, clock
        self.heard_ns: int | None = None
        self.anchor = self.window = (clock(), 0)
        self.notify: Callable[[], None] = lambda: None
        self.warn: Callable[[tuple, str], object] = lambda key, text: None   # throttled

    paced = True
    follows = True   # the loop's ~/step waits for the clock too

    def heard_message(self, sec: int, nanosec: int) -> None:
        """A /clock message's time: one whose nanosec is not below 10⁹ is no time (refused,
        said); else `heard`."""
        if not 0 <= nanosec < NS:
            self.warn(("clock", "nanosec"), f"/clock: nanosec {nanosec} is not in [0, 1e9): "
                                            f"not a time, ignored")
            return
        self.heard(sec * NS + nanosec)

    def heard(self, clock_ns: int) -> None:
        """The latest time heard (a clock that jumps back is followed); a leap ahead by more
        than JUMP s is followed too, and said."""
        if self.heard_ns is not None and clock_ns - self.heard_ns > self.JUMP * NS:
            self.warn(("clock", "jump"), f"/clock leapt {(clock_ns - self.heard_ns) / NS:g} s "
                                         f"ahead, from t = {format_ns(self.heard_ns)} s to "
                                         f"{format_ns(clock_ns)} s: following it")
        self.heard_ns = clock_ns
        self.notify()

    def delay(self, stamp: int) -> float:
        """≤ 0 when the heard clock has reached ``stamp``, else how long to wait at most."""
        return -1.0 if self.heard_ns is not None and stamp <= self.heard_ns else self.POLL

    def late(self, stamp: int, late: float) -> None:
        return None   # following a clock is never late: it waits for it

    def reanchor(self, now_ns: int) -> None:
        self.anchor = self.window = (self.clock(), now_ns)

    def set_real_time_factor(self, factor: float, now_ns: int) -> None:
        self.real_time_factor = factor   # the heard clock paces, not the factor

    def restart_window(self) -> None:
        self.window = self.anchor
