"""`simulate --record DIR`: the headless run recorded like a node run (same topics, same
message contents for the same states), through `RunRecorder`.

Sample k is stamped like the node's publication k (``stamp_ns(k, rate)``); a last sample off
the rate's grid (at ``duration``) is stamped with the duration in nanoseconds. The commands are
the scene's constant efforts (after its effort limits), recorded once at t = 0.
"""
from __future__ import annotations

from fractions import Fraction

from mobile_manip_sim.messages import seconds_ns, stamp_ns, state_messages
from mobile_manip_sim.recording.bag_writer import DEFAULT_CHUNK_SIZE
from mobile_manip_sim.recording.recorder import RunRecorder


def sample_stamps(sample_rate: float, duration: float) -> list[tuple[int, float]]:
    """(stamp in ns, simulated time in s that `simulate` advances to) of every sample of a run
    of ``duration`` s: what ``HeadlessRecorder`` writes, and what a re-run must advance to."""
    from mobile_manip_sim.simulate import sample_times  # the adapter owns its sampling

    rate = Fraction(sample_rate)
    return [(stamp_ns(k, rate) if t == k / sample_rate else seconds_ns(t), t)
            for k, t in enumerate(sample_times(duration, sample_rate))]


class HeadlessRecorder:
    """``sample(sim)`` after each sample of a `simulate` run, ``close()`` at the end."""

    def __init__(self, path, scene, settings, sample_rate: float, duration: float | None = None,
                 *, chunk_size: int = DEFAULT_CHUNK_SIZE):
        extra = {"source": "simulate", "sample_rate": repr(float(sample_rate))}
        if duration is not None:
            extra["duration"] = repr(float(duration))
        self.recorder = RunRecorder(path, scene, settings, extra, chunk_size=chunk_size)
        self.writer = self.recorder.writer
        self._names = scene.robot.joint_names()
        self._rate = Fraction(float(sample_rate))
        self._stamps = [stamp for stamp, _ in sample_stamps(sample_rate, duration)] \
            if duration is not None else []
        self._k = 0

    def sample(self, sim) -> None:
        k = self._k
        stamp = self._stamps[k] if k < len(self._stamps) else stamp_ns(k, self._rate)
        try:
            self.recorder.states(stamp, state_messages(sim, stamp, self._names))
            if k == 0:
                self.recorder.commands(0, sim.wheel_efforts, sim.joint_efforts)
            self.recorder.impacts(sim.impacts)
        except BaseException:
            self.recorder.abandon()
            raise
        self._k += 1

    def close(self) -> None:
        self.recorder.close()
