"""A scene's ``controller:`` section → a validated `ControllerSection`: how the arm is driven
in a headless run (docs/scene.md, "The arm controller") and the commands applied at t = 0.

    controller:
      arm: position            # effort | position | velocity | joint_trajectory
      feedforward: gravity     # none | gravity | computed_torque
      gains: {kp: 300, ki: [...], kd: ...}   # one number or one per arm joint; optional
      positions: [...]         # position mode: the set-point (default: the initial pose)
      velocities: [...]        # velocity mode: the joint velocities (default: zero)
      trajectory:              # joint_trajectory mode (default: hold the initial pose)
        points:
          - {time_from_start: 1.0, positions: [...], velocities: [...], accelerations: [...]}

Scene layer (numpy only): the engine turns it into an `engine.arm_control.ArmControl` and the
commands of `engine.arm_commands`. The mode and feedforward names are that module's; a check that
needs the dynamics (holding a point against gravity within the effort limits) is the engine's.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from . import schema
from .coordinates import arm_size, arm_slide
from .errors import UserError
from .limits import ANGLE, DURATION, SPEED, TRAJECTORY_POINTS

ARM_MODES = ("effort", "position", "velocity", "joint_trajectory")
FEEDFORWARDS = ("none", "gravity", "computed_torque")
GAINS = ("kp", "ki", "kd")
COMMAND_OF_MODE = {"position": "positions", "velocity": "velocities",
                   "joint_trajectory": "trajectory"}


@dataclass(frozen=True)
class ControllerSection:
    arm: str = "effort"
    feedforward: str = "gravity"
    gains: dict | None = None           # {"kp": (n_arm,), …}, the keys given
    positions: np.ndarray | None = None
    velocities: np.ndarray | None = None
    trajectory: tuple | None = None     # (times, positions, velocities, accelerations); the
                                        # last two None when the points give none


def parse_controller(doc, robot, stroke_limits_on: bool) -> ControllerSection | None:
    """The validated section (None when the scene has none). Gain bounds are checked again by
    `ArmControl`; strokes here when the scene's stroke limits are on."""
    if doc is None:
        return None
    path = "controller"
    doc = schema.mapping(doc, path)
    schema.keys(doc, path, optional=("arm", "feedforward", "gains", "positions", "velocities",
                                     "trajectory"))
    n_arm = arm_size(robot.n_links)
    arm = _choice(doc.get("arm", "effort"), f"{path}.arm", ARM_MODES)
    feedforward = _choice(doc.get("feedforward", "gravity"), f"{path}.feedforward", FEEDFORWARDS)
    for key, mode in (("positions", "position"), ("velocities", "velocity"),
                      ("trajectory", "joint_trajectory")):
        if key in doc and arm != mode:
            raise UserError(f"{path}.{key}", f"applies to arm: {mode}, not arm: {arm}")
    if arm != "effort" and n_arm == 0:
        raise UserError(f"{path}.arm", "the robot has no arm to control")
    gains = None
    if "gains" in doc:
        if arm == "effort":
            raise UserError(f"{path}.gains", "the arm is in effort mode: no gains apply")
        value = schema.mapping(doc["gains"], f"{path}.gains")
        schema.keys(value, f"{path}.gains", optional=GAINS)
        gains = {name: tuple(schema.vector_or_scalar(value[name], n_arm, f"{path}.gains.{name}",
                                                     nonnegative=True, hi=1e9))
                 for name in GAINS if name in value}
    section = ControllerSection(arm=arm, feedforward=feedforward, gains=gains)
    stroke = np.asarray(robot.stroke).reshape(-1, 2) if stroke_limits_on else None
    names = robot.joint_names()[2:]
    if "positions" in doc:
        positions = schema.vector(doc["positions"], n_arm, f"{path}.positions", lo=-ANGLE, hi=ANGLE)
        _check_stroke(positions, stroke, names, f"{path}.positions")
        section = replace(section, positions=positions)
    if "velocities" in doc:
        section = replace(section, velocities=schema.vector(
            doc["velocities"], n_arm, f"{path}.velocities", lo=-SPEED, hi=SPEED))
    if "trajectory" in doc:
        section = replace(section, trajectory=_trajectory(doc["trajectory"], n_arm, stroke, names))
    return section


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
