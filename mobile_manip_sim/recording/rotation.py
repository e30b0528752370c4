"""`RotatingRecorder`: the node's recording, one bag per time line.

A bag holds one time line: when a state arrives whose stamp is not after the last one recorded
(the t = 0 state after a ~/reset), the bag is closed and recording goes on in
``<path>_1``, ``<path>_2``, … up to ``max_bags`` bags (a peer calling ~/reset in a loop
cannot fill the disk with directories): the reset after the last one ends recording, said in one
line. A failure (a full disk, an unusable new directory) is one error line and the end of
recording, never of the run. The node's stepping thread writes (and the shutdown after that
thread stopped), outside the lock its services take, so closing a bag never delays a service; a
timer calls `flush` while the stepping thread is idle (a lock of its own keeps the two apart).
"""
from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Callable

if TYPE_CHECKING:   # a bag's recorder (mcap, the CDR tables) is imported only when one opens
    from mobile_manip_sim.recording.recorder import RunRecorder


class RotatingRecorder:
    """``open_bag(path)`` makes each bag's `RunRecorder`; ``info`` and ``error`` take one line
    of text each (the node's logger)."""

    def __init__(self, path: str, open_bag: Callable[[str], RunRecorder],
                 info: Callable[[str], None], error: Callable[[str], None],
                 max_bags: int | None = None):
        self.base_path = str(path)
        self.max_bags = max_bags
        self._lock = threading.RLock()
        self._open_bag = open_bag
        self.info, self.error = info, error
        self._count = 0
        self._last_stamp: int | None = None   # last state stamp in the open bag
        self.recorder: RunRecorder | None = self._open(self.base_path)   # errors: raised

    @property
    def path(self):
        return self.recorder.path if self.recorder is not None else None

    def _open(self, path: str) -> RunRecorder:
        recorder = self._open_bag(path)
        self._count += 1
        self._last_stamp = None
        return recorder

    def states(self, stamp: int, messages: dict, impacts) -> None:
        """After each publication: the state messages at ``stamp`` ns and the engine's impact
        list so far (the engine is at ``stamp``)."""
        with self._lock:
            self._states(stamp, messages, impacts)

    def flush(self) -> None:
        """From a timer: the open chunk to disk when the recorder's flush interval has passed."""
        with self._lock:
            self._do(lambda recorder: recorder.flush_if_due())

    def _states(self, stamp: int, messages: dict, impacts) -> None:
        if self.recorder is None:
            return
        if self._last_stamp is not None and stamp <= self._last_stamp:
            self._rotate()
            if self.recorder is None:
                return
        self._last_stamp = stamp

        def record(recorder):
            recorder.states(stamp, messages)
            recorder.impacts(impacts)
        self._do(record)

    def commands(self, stamp: int, base, joints) -> None:
        """At each segment start: the commands held from ``stamp`` ns on, as applied."""
        with self._lock:
            self._do(lambda recorder: recorder.commands(stamp, base, joints))

    def arm_command(self, stamp: int, message) -> None:
        """An arm controller's command applied at the segment start ``stamp`` ns."""
        with self._lock:
            self._do(lambda recorder: recorder.arm_command(stamp, message))

    def close(self, info=None, error=None) -> None:
        """Finish the open bag (impacts, summary, metadata.yaml); idempotent. ``info`` and
        ``error`` replace the loggers (at shutdown the node's may be gone)."""
        with self._lock:
            if self.recorder is None:
                return
            path = self.recorder.path
            self._do(lambda recorder: recorder.close(), error)
            if self.recorder is not None:
                self.recorder = None
                (info or self.info)(f"bag {path} closed")

    def _rotate(self) -> None:
        previous = self.recorder.path
        self._do(lambda recorder: recorder.close())
        if self.recorder is None:
            return
        self.recorder = None
        if self.max_bags is not None and self._count >= self.max_bags:
            self.error(f"recording stopped at the reset: {self._count} bags recorded, the most "
                       f"one node records (one per time line); the simulation goes on")
            return
        try:
            self.recorder = self._open(f"{self.base_path}_{self._count}")
        except Exception as failure:
            self.error(f"recording stopped at the reset: {failure}")
            return
        self.info(f"reset: bag {previous} closed, recording on in {self.recorder.path}")

    def _do(self, action, error=None) -> None:
        """``action(recorder)``; a failure is one error line and the end of recording."""
        if self.recorder is None:
            return
        try:
            action(self.recorder)
        except Exception as failure:
            recorder, self.recorder = self.recorder, None
            recorder.abandon()
            (error or self.error)(f"recording stopped: {failure}; the simulation goes on "
                                  f"without it")
