"""The arm's controller side of the node (parameter arm_controller): in position and velocity
mode each new array from the command intake is applied once, at the segment start where it is
taken; in joint_trajectory mode the trajectories and goals of `trajectory_action`. Every
command enters the engine through `timeline.apply_arm_command` (as re-simulation feeds it) and
is returned as applied, for the bag. Effort mode has nothing here (the effort topic is the
command intake's, applied by `timeline.apply_commands`)."""
from __future__ import annotations

from ..ros.messages import arm_command_message
from ..ros.topics import relative
from ..runtime.timeline import apply_arm_command
from ..scene.arm_controller import MODES
from ..scene.errors import UserError


def arm_array_topic(controller) -> str | None:
    """The command intake's arm topic for an `ArmController`: the effort topic, an arm
    controller's array topic, or None (trajectories only)."""
    return controller.row.topic if controller.row.array else None


class ArmDriver:
    """``mode`` a controlled row of `scene.arm_controller.MODES`; ``names`` the arm's joints
    (node order)."""

    def __init__(self, node, mode: str, names, warn, info, source: str | None = None):
        """``source``: the topic that carries the arrays when it is not the mode's own
        (ros2_control's joint commands), for the refusals' lines."""
        self.mode, self.names, self._warn = mode, list(names), warn
        self.source = source or (relative(MODES[mode].topic) if MODES[mode].array else None)
        self.trajectories = None
        if not MODES[mode].array:
            from .trajectory_action import TrajectoryInterface
            self.trajectories = TrajectoryInterface(node, self.names, warn, info)
        self._taken = 0   # the command intake's arm count when its last array was applied

    def restart(self, received: int) -> None:
        """The node's t = 0: the engine holds the initial pose; goals end; arrays taken before
        (``received`` so far) are not applied again."""
        self._taken = received
        if self.trajectories is not None:
            self.trajectories.goals.forget("the simulation was reset")

    def segment_start(self, sim, start_ns: int, values, received: int):
        """Apply what is new at the segment start ``start_ns``: the intake's array ``values``
        (``received`` counts them), or the trajectory goals' step. Returns what makes the
        message to record (as applied) when called — built only for a bag: a 100,000-point
        trajectory's message took the stepping thread a second — or None."""
        if MODES[self.mode].array:
            if received == self._taken:
                return None
            self._taken = received
            try:   # the intake checked length and finiteness; the engine the limits
                apply_arm_command(sim, self.mode, values)
            except UserError as error:
                self._warn(("arm", "refused"), f"{self.source}: {error}; keeping the last "
                                               f"set-point")
                return None
            return lambda: arm_command_message(self.mode, values, self.names, start_ns)
        if self.trajectories is None:
            return None
        step = self.trajectories.segment_start(
            sim, start_ns, lambda trajectory: apply_arm_command(sim, self.mode, trajectory))
        if step.command is None:
            return None
        return lambda: arm_command_message(self.mode, step.command, self.names, start_ns)
