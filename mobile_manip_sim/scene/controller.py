"""A scene's ``controller:`` section → a validated `ControllerSection`: the arm controller of a
headless run (`arm_controller.ArmController`, docs/controllers.md) and the command it takes at
t = 0.

    controller:
      rate: 1000               # Hz, the controllers' update rate (0: continuous); optional
      arm_controller: position # effort | position | velocity | joint_trajectory (old name: arm)
      feedforward: gravity     # none | gravity | computed_torque
      gains: {kp: 300, ki: [...], kd: ...}   # one number or one per arm joint; optional
      model_error: {mass: 0.2, inertia: 0.0, payload: 0.5}   # the feed-forward's model; optional
      positions: [...]         # position mode: the set-point (default: the initial pose)
      velocities: [...]        # velocity mode: the joint velocities (default: zero)
      trajectory:              # joint_trajectory mode (default: hold the initial pose)
        points:
          - {time_from_start: 1.0, positions: [...], velocities: [...], accelerations: [...]}

The key of a mode's command is its row's ``command`` (`arm_controller.MODES`). Scene layer (numpy
only): a check that needs the dynamics (holding a point against gravity within the effort
limits) is the engine's.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import schema
from .arm_controller import (
    ARM_MODES,
    DEFAULT_FEEDFORWARD,
    EFFORT,
    FEEDFORWARDS,
    GAINS,
    MODES,
    ArmController,
    ModelError,
)
from .coordinates import arm_size, arm_slide
from .errors import UserError
from .limits import ANGLE, CONTROL_RATE, DURATION, MASS, MODEL_ERROR, SPEED, TRAJECTORY_POINTS

MODE_KEY, OLD_MODE_KEY = "arm_controller", "arm"   # the old name is still read
COMMAND_KEYS = tuple(mode.command for mode in MODES.values() if mode.controlled)

# Hz: the update rate of the simulated controllers (the wheel-speed loop, the arm controller), as
# ros2_control's controller manager's update_rate. 1 kHz: the rate of the arms' own control
# boxes and of many ros2_control drivers (100 Hz, the controller manager's default, is a
# deployment's choice for slow loops; the arm's default gains, 20 rad/s of bandwidth, lose
# little phase at 1 kHz: 0.01 rad of hold delay at 20 rad/s). 0: continuous controllers, for
# idealised studies.
DEFAULT_CONTROL_RATE = 1000.0


@dataclass(frozen=True)
class ControllerSection:
    arm_controller: ArmController = ArmController()
    # the mode's command at t = 0 (its row's ``command``): an (n_arm,) array, or the trajectory
    # (times, positions, velocities, accelerations), the last two None when the points give
    # none; None: hold the initial pose
    command: object = None
    rate: float = DEFAULT_CONTROL_RATE   # Hz, the controllers' update rate (0: continuous)


def control_rate(section: ControllerSection | None) -> float:
    """The controllers' update rate (Hz) of a scene's section, the default when it has none."""
    return DEFAULT_CONTROL_RATE if section is None else section.rate


def parse_controller(doc, robot, stroke_limits_on: bool) -> ControllerSection | None:
    """The validated section (None when the scene has none). Gain counts are checked again by
    the engine (`arm_control.for_robot`); strokes here when the scene's stroke limits are on."""
    if doc is None:
        return None
    path = "controller"
    doc = schema.mapping(doc, path)
    schema.keys(doc, path, optional=(MODE_KEY, OLD_MODE_KEY, "feedforward", "gains",
                                     "model_error", "rate", *COMMAND_KEYS))
    rate = (schema.number(doc["rate"], f"{path}.rate", lo=CONTROL_RATE[0], hi=CONTROL_RATE[1])
            if "rate" in doc else DEFAULT_CONTROL_RATE)
    if MODE_KEY in doc and OLD_MODE_KEY in doc:
        raise UserError(f"{path}.{OLD_MODE_KEY}", f"the old name of {MODE_KEY}: give one")
    key = OLD_MODE_KEY if OLD_MODE_KEY in doc else MODE_KEY
    n_arm = arm_size(robot.n_links)
    mode = MODES[_choice(doc.get(key, EFFORT), f"{path}.{key}", ARM_MODES)]
    feedforward = _choice(doc.get("feedforward", DEFAULT_FEEDFORWARD), f"{path}.feedforward",
                          FEEDFORWARDS)
    for other in COMMAND_KEYS:
        if other in doc and other != mode.command:
            owner = next(m.name for m in MODES.values() if m.command == other)
            raise UserError(f"{path}.{other}", f"applies to {key}: {owner}, not {key}: "
                                               f"{mode.name}")
    if mode.controlled and n_arm == 0:
        raise UserError(f"{path}.{key}", "the robot has no arm to control")
    gains = {}
    for name in ("gains", "model_error"):
        if name in doc and not mode.controlled:
            raise UserError(f"{path}.{name}", f"the arm is in effort mode: no {name} apply")
    if "gains" in doc:
        value = schema.mapping(doc["gains"], f"{path}.gains")
        schema.keys(value, f"{path}.gains", optional=GAINS)
        gains = {name: tuple(schema.vector_or_scalar(value[name], n_arm, f"{path}.gains.{name}",
                                                     nonnegative=True, hi=1e9))
                 for name in GAINS if name in value}
    error = _model_error(doc["model_error"]) if "model_error" in doc else ModelError()
    controller = ArmController(mode.name, feedforward=feedforward, model_error=error, **gains)
    stroke = np.asarray(robot.stroke).reshape(-1, 2) if stroke_limits_on else None
    names = robot.joint_names()[2:]
    command = doc.get(mode.command) if mode.controlled else None
    if command is not None and mode.array:   # one value per arm joint (the engine checks more)
        bound = SPEED if mode.command == "velocities" else ANGLE
        key = f"{path}.{mode.command}"
        command = schema.vector(command, n_arm, key, lo=-bound, hi=bound)
        if mode.command == "positions":
            _check_stroke(command, stroke, names, key)
    elif command is not None:
        command = _trajectory(command, n_arm, stroke, names)
    return ControllerSection(controller, command, rate)


def _model_error(doc) -> ModelError:
    path = "controller.model_error"
    doc = schema.mapping(doc, path)
    schema.keys(doc, path, optional=("mass", "inertia", "payload"))
    values = {name: schema.number(doc[name], f"{path}.{name}", lo=MODEL_ERROR[0],
                                  hi=MODEL_ERROR[1])
              for name in ("mass", "inertia") if name in doc}
    if doc.get("payload") is not None:
        values["payload"] = schema.number(doc["payload"], f"{path}.payload", lo=0.0, hi=MASS[1])
    return ModelError(**values)


def _choice(value, path, choices) -> str:
    if not isinstance(value, str) or value not in choices:
        raise UserError(path, f"unknown value {schema.short(value)} (choose one of: "
                              f"{', '.join(choices)})")
    return value


def outside_stroke(point, stroke) -> tuple[int, str] | None:
    """(index of the first prismatic joint of `point` (n_arm) outside its stroke (n, 2), what
    is wrong) or None."""
    for k, (lo, hi) in enumerate(stroke):
        length = point[arm_slide(k + 1)]
        if not lo <= length <= hi:
            return arm_slide(k + 1), f"{length:g} m is outside the stroke [{lo:g}, {hi:g}]"
    return None


def _check_stroke(point, stroke, names, path) -> None:
    found = None if stroke is None else outside_stroke(point, stroke)
    if found is not None:
        raise UserError(f"{path}[{found[0]}]", f"{names[found[0]]}: {found[1]}")


def _trajectory(doc, n_arm, stroke, names) -> tuple:
    path = "controller.trajectory"
    doc = schema.mapping(doc, path)
    schema.keys(doc, path, required=("points",))
    points = schema.sequence(doc["points"], f"{path}.points", max_length=TRAJECTORY_POINTS)
    if not points:
        raise UserError(f"{path}.points", "expected at least one point")
    times, rows = [], {"positions": [], "velocities": [], "accelerations": []}
    for i, point in enumerate(points):
        where = f"{path}.points[{i}]"
        point = schema.mapping(point, where)
        schema.keys(point, where, required=("time_from_start", "positions"),
                    optional=("velocities", "accelerations"))
        t = schema.number(point["time_from_start"], f"{where}.time_from_start", lo=0.0,
                          hi=DURATION[1])
        if times and t <= times[-1]:
            raise UserError(f"{where}.time_from_start", f"{t:g} s is not after the previous "
                                                        f"point's {times[-1]:g} s")
        times.append(t)
        for key, bound in (("positions", ANGLE), ("velocities", SPEED), ("accelerations", 1e9)):
            if key in point:
                rows[key].append(schema.vector(point[key], n_arm, f"{where}.{key}", lo=-bound,
                                               hi=bound))
            elif rows[key] and key != "positions":
                raise UserError(f"{where}.{key}", "missing (given for an earlier point: every "
                                                  "point or none)")
            if key != "positions" and rows[key] and len(rows[key]) != i + 1:
                raise UserError(f"{where}.{key}", "given here but not for point 0: every point "
                                                  "or none")
        _check_stroke(rows["positions"][-1], stroke, names, f"{where}.positions")
    if rows["accelerations"] and not rows["velocities"]:
        raise UserError(f"{path}.points[0].accelerations", "need velocities too (quintic "
                                                           "interpolation takes both)")
    return (np.array(times), np.array(rows["positions"]),
            np.array(rows["velocities"]) if rows["velocities"] else None,
            np.array(rows["accelerations"]) if rows["accelerations"] else None)
