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

from ..runtime.timeline import format_ns
from .throttle import Throttle


class Lockstep:
    """``commands`` is the node's `CommandIntake`; ``listening()`` says whether a state topic
    has a subscriber."""

    def __init__(self, commands, listening: Callable[[], bool], timeout: float,
                 throttle: Throttle, clock: Callable[[], float] = time.monotonic):
        self.commands, self.listening = commands, listening
        self.timeout = timeout
        self._throttle, self._clock = throttle, clock

    def ready(self) -> bool:
        """The start condition: someone listens, someone commands."""
        return self.listening() and any(self.commands.commanded())

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
