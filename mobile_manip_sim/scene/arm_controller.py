"""The arm controller as one record: how the arm is driven (`ArmController`: mode, PID gains,
feed-forward and the feed-forward's model error) and the table of modes (`MODES`: each mode's
name, command topic, kind of command, the message a bag records, the engine setter that
applies a command and how messages name an array command's entries). The node's parameters,
a scene's ``controller:`` section, a bag's metadata, the recorder, the bag reader, the timeline
and the engine all read these (docs/controllers.md).

Scene layer (numpy only): the defaults that need the dynamics (the default gains of a robot)
are the engine's (`engine.arm_control.for_robot`).

Adding a mode: one row of MODES (with its topic and the `Simulation` method that applies its
command) and that method in `engine/arm_commands.py`.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from .errors import UserError
from .limits import ARM_GAIN, MASS, MODEL_ERROR

FLOAT_ARRAY = "std_msgs/msg/Float64MultiArray"
JOINT_TRAJECTORY = "trajectory_msgs/msg/JointTrajectory"


def _real(v) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)


def _number(record, name, key, lo, hi) -> None:
    v = getattr(record, name)
    if not _real(v) or not lo <= float(v) <= hi:
        raise UserError(key, f"expected a number in [{lo:g}, {hi:g}], got {v!r}")
    object.__setattr__(record, name, float(v))


@dataclass(frozen=True)
class ArmMode:
    """One row of the table of modes."""
    name: str          # the mode's name (node parameter arm_controller, scene, bag metadata)
    topic: str         # its command topic (canonical; the node creates it relative)
    command: str       # the kind of command: a scene's key for it, the engine's argument
    recorded: str      # the message type a bag records on `topic` (commands as applied)
    setter: str | None  # the `Simulation` method applying one command (None: efforts)
    symbols: tuple = ()  # an array command's entries per link, as messages name them

    @property
    def controlled(self) -> bool:
        """A PID inside the simulated system drives the arm (not raw efforts)."""
        return self.setter is not None

    @property
    def array(self) -> bool:
        """Its commands are one value per arm joint (else a trajectory)."""
        return self.recorded == FLOAT_ARRAY


MODES = {mode.name: mode for mode in (
    ArmMode("effort", "/arm_effort_controller/commands", "efforts", FLOAT_ARRAY, None,
            ("tau", "F")),
    ArmMode("position", "/arm_position_controller/commands", "positions", FLOAT_ARRAY,
            "set_arm_positions", ("q", "l")),
    ArmMode("velocity", "/arm_velocity_controller/commands", "velocities", FLOAT_ARRAY,
            "set_arm_velocities", ("qdot", "ldot")),
    ArmMode("joint_trajectory", "/joint_trajectory_controller/joint_trajectory", "trajectory",
            JOINT_TRAJECTORY, "set_arm_trajectory"),
)}
ARM_MODES = tuple(MODES)
EFFORT = "effort"   # no controller: the arm takes efforts (a headless scene's default)


class Feedforward(IntEnum):
    """The model-based feed-forward of a controlled arm; the value is the compiled code's id."""
    NONE = 0
    GRAVITY = 1
    COMPUTED_TORQUE = 2

    @property
    def label(self) -> str:
        return self.name.lower()


FEEDFORWARDS = tuple(kind.label for kind in Feedforward)
DEFAULT_FEEDFORWARD = Feedforward.GRAVITY.label
GAINS = ("kp", "ki", "kd")


@dataclass(frozen=True)
class ModelError:
    """The feed-forward's model against the plant's: ``mass`` and ``inertia`` relative errors
    (0.2: the feed-forward takes every link 20 % heavier) — ``mass`` on the rods' mass per length
    and the base's mass, ``inertia`` on the rods' cross-section inertia, the base's yaw inertia
    and the wheels' spin inertia — and ``payload`` the payload mass (kg) it assumes, None for the
    plant's."""
    mass: float = 0.0
    inertia: float = 0.0
    payload: float | None = None

    def __post_init__(self):
        for name in ("mass", "inertia"):
            _number(self, name, f"arm_model_error.{name}", *MODEL_ERROR)
        if self.payload is not None:
            _number(self, "payload", "arm_model_error.payload", 0.0, MASS[1])

    @property
    def exact(self) -> bool:
        """The feed-forward uses the plant's own model."""
        return self.mass == 0.0 and self.inertia == 0.0 and self.payload is None


@dataclass(frozen=True)
class ArmController:
    """How the arm is driven: `mode` (a name of MODES), PID gains per arm joint in the order
    (revolute_1, prismatic_1, …) — kp N·m/rad or N/m, ki N·m/(rad·s) or N/(m·s), kd N·m·s/rad
    or N·s/m; one number stands for every joint, () for the robot's defaults — the
    `feedforward` (FEEDFORWARDS) and its `model_error`. Validated on construction (a UserError
    naming the node parameter)."""

    mode: str = EFFORT
    kp: tuple = ()
    ki: tuple = ()
    kd: tuple = ()
    feedforward: str = DEFAULT_FEEDFORWARD
    model_error: ModelError = ModelError()

    def __post_init__(self):
        if self.mode not in MODES:
            raise UserError("arm_controller", f"unknown mode {self.mode!r} (choose one of: "
                                              f"{', '.join(ARM_MODES)})")
        if self.feedforward not in FEEDFORWARDS:
            raise UserError("arm_feedforward", f"unknown feedforward {self.feedforward!r} "
                                               f"(choose one of: {', '.join(FEEDFORWARDS)})")
        for name in GAINS:
            value = getattr(self, name)
            values = (value,) if np.ndim(value) == 0 else tuple(value)
            for v in values:
                if not _real(v) or not ARM_GAIN[0] <= v <= ARM_GAIN[1]:
                    raise UserError(f"arm_gains.{name}", f"expected numbers in [{ARM_GAIN[0]:g}, "
                                                         f"{ARM_GAIN[1]:g}], got {v!r}")
            object.__setattr__(self, name, tuple(float(v) for v in values))
        if not isinstance(self.model_error, ModelError):
            raise UserError("arm_model_error", f"expected a ModelError, got "
                                               f"{self.model_error!r}")

    @property
    def row(self) -> ArmMode:
        """The mode's row of MODES."""
        return MODES[self.mode]

    @property
    def active(self) -> bool:
        """A controller drives the arm (its states are in s)."""
        return self.row.controlled

    @property
    def feedforward_id(self) -> int:
        return int(Feedforward[self.feedforward.upper()])
