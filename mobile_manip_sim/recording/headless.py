"""`simulate --record DIR`: the headless run recorded like a node run (same topics, same
message contents for the same states), through `RunRecorder`: what a viewer needs to draw the
robot too (/tf with every link at each sample; /tf_static and /robot_description at t = 0).

Sample k is stamped by the run's time line (`timeline.Grid`): like the node's publication k,
and a last sample off the rate's grid (at ``duration``) with the duration in nanoseconds. The
commands are the scene's constant efforts (after its effort limits), recorded once at t = 0.
"""
from __future__ import annotations

from mobile_manip_sim.recording.bag_writer import DEFAULT_CHUNK_SIZE
from mobile_manip_sim.recording.recorder import RunRecorder
from mobile_manip_sim.ros.frames import FrameTree
from mobile_manip_sim.ros.messages import description, state_messages, tf_cdr, tf_static_cdr
from mobile_manip_sim.ros.topics import DESCRIPTION_TOPIC, TF_STATIC_TOPIC, TF_TOPIC
from mobile_manip_sim.ros.urdf import robot_description
from mobile_manip_sim.runtime.timeline import Grid


class HeadlessRecorder:
    """``sample(sim)`` after each sample of a `simulate` run, ``close()`` at the end."""

    def __init__(self, path, scene, settings, sample_rate: float, duration: float | None = None,
                 *, chunk_size: int = DEFAULT_CHUNK_SIZE):
        extra = {"source": "simulate", "sample_rate": repr(float(sample_rate))}
        if duration is not None:
            extra["duration"] = repr(float(duration))
        self.recorder = RunRecorder(path, scene, settings, extra, chunk_size=chunk_size,
                                    view=True)
        self.writer = self.recorder.writer
        self._names = scene.robot.joint_names()
        self._tree = FrameTree(scene.robot)
        self._latched = {TF_STATIC_TOPIC: tf_static_cdr(self._tree, 0),
                         DESCRIPTION_TOPIC: description(robot_description(scene))}
        self._grid = Grid(sample_rate, duration)
        self._k = 0

    def sample(self, sim) -> None:
        k = self._k
        stamp = self._grid.stamp(k)
        try:
            messages = state_messages(sim, stamp, self._names)
            messages[TF_TOPIC] = tf_cdr(self._tree, sim.q, stamp)
            if k == 0:
                messages.update(self._latched)
            self.recorder.states(stamp, messages)
            if k == 0:
                self.recorder.commands(0, sim.wheel_efforts, sim.joint_efforts)
            self.recorder.impacts(sim.impacts)
        except BaseException:
            self.recorder.abandon()
            raise
        self._k += 1

    def close(self) -> None:
        self.recorder.close()
