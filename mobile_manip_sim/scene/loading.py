"""Scene files (YAML) → a validated, immutable `Scene`: robot, initial state, efforts, effects,
integrator. Every mistake raises `UserError` naming its key path (``robot.arm.links[1].length``).

The full format, with every key and its default, is documented in docs/scene.md.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

from . import methods, schema
from .controller import ControllerSection, parse_controller
from .coordinates import ARM_Q, ARM_U, BASE_POSE, WHEELS, arm_size
from .errors import UserError
from .limits import (
    ANGLE,
    ATOL,
    DAMPING,
    DENSITY,
    DT,
    DURATION,
    EFFORT,
    GRAVITY,
    INERTIA,
    LENGTH,
    MASS,
    MAX_LINKS,
    MAX_SAMPLES,
    MAX_STEPS,
    RADIUS,
    RTOL,
    SPEED,
)
from .model import Base, RobotModel

DEFAULT_SCENE = "paper_two_link.yaml"

METHODS = methods.NAMES                     # the registry: mobile_manip_sim/scene/methods.py
FIXED_STEP_METHODS = methods.FIXED_STEP_NAMES
IMPACT_LAWS = ("impulse", "reflect")


@dataclass(frozen=True)
class StrokeLimits:
    """End stops at each rod's stroke ends: restitution e ∈ [0, 1], the impact law, and the
    approach speed (m/s) below which a rod at its stop is held at rest instead of bouncing."""

    restitution: float = 0.0
    law: str = "impulse"
    rest_speed: float = 1e-3


@dataclass(frozen=True)
class Effects:
    """The physical effects a scene turns on; each is off (and free) unless asked for."""

    gravity: float = 0.0
    stroke_limits: StrokeLimits | None = None
    wheel_inertia: bool = False
    joint_damping: tuple | None = None      # per arm joint, N·m·s/rad or N·s/m
    wheel_damping: float | None = None      # N·m·s/rad on each wheel
    effort_limits: dict | None = None       # {"wheels": (2,), "joints": (2n,)} absolute bounds
                                            # (`true` in the file: the robot's, `robot.limits`)
    locked_joints: tuple = ()               # arm joint names held fixed
    fixed_base: bool = False
    payload: float | None = None            # kg at the tip of the last rod

    def names_on(self) -> list[str]:
        on = []
        for name in EFFECT_NAMES:
            value = getattr(self, name)
            if value not in (None, False, 0.0, ()):
                on.append(name)
        return on


EFFECT_NAMES = ("gravity", "stroke_limits", "wheel_inertia", "joint_damping", "wheel_damping",
                "effort_limits", "locked_joints", "fixed_base", "payload")


@dataclass(frozen=True)
class IntegratorSettings:
    """`method` from METHODS; `dt` (s), the step of the fixed-step methods (the adaptive ones
    ignore it); `rtol`, `atol` for the adaptive ones."""

    method: str = "dop853"
    dt: float = 1e-3
    rtol: float = 1e-9
    atol: float = 1e-12

    @property
    def fixed_step(self) -> bool:
        return self.method in FIXED_STEP_METHODS


@dataclass(frozen=True)
class Scene:
    name: str
    robot: RobotModel
    initial_q: np.ndarray
    initial_u: np.ndarray
    wheel_efforts: np.ndarray
    joint_efforts: np.ndarray
    effects: Effects
    integrator: IntegratorSettings
    duration: float
    document: dict = field(repr=False, compare=False)  # the YAML with all defaults applied
    controller: ControllerSection | None = None          # how the arm is driven (None: efforts)
    # the robot's own limits, `robot.limits` (a motor's ratings; None where it declares none):
    # {"effort": {"wheels": (2,) | None, "joints": (2n,) | None} | None, "velocity": likewise}
    limits: dict = field(default_factory=lambda: {"effort": None, "velocity": None})

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.document, sort_keys=False)


def _number(value, path, *, positive=False, nonnegative=False, lo=None, hi=None) -> float:
    return schema.number(value, path, positive=positive, nonnegative=nonnegative, lo=lo, hi=hi)


_vector = schema.vector
_vector_or_scalar = schema.vector_or_scalar
_mapping = schema.mapping
_keys = schema.keys
_flag = schema.flag


# --- the sections ---------------------------------------------------------------------------

def _base(doc) -> Base:
    path = "robot.base"
    doc = _mapping(doc, path)
    keys = ("mass", "yaw_inertia", "com_offset", "wheel_radius", "half_track", "wheel_inertia")
    _keys(doc, path, required=keys)
    bounds = {"mass": MASS, "yaw_inertia": (1e-12, INERTIA[1]), "wheel_radius": RADIUS,
              "half_track": LENGTH, "wheel_inertia": INERTIA}
    values = {k: _number(doc[k], f"{path}.{k}", lo=bounds[k][0], hi=bounds[k][1])
              for k in bounds}
    values["com_offset"] = _number(doc["com_offset"], f"{path}.com_offset", lo=-LENGTH[1],
                                   hi=LENGTH[1])
    return Base(**values)


def _inertia(value, path) -> np.ndarray:
    if (isinstance(value, (list, tuple)) and len(value) == 3
            and all(isinstance(r, (list, tuple)) for r in value)):
        J = np.array([_vector(r, 3, f"{path}[{i}]", lo=-INERTIA[1], hi=INERTIA[1])
                      for i, r in enumerate(value)])
        if not np.allclose(J, J.T, rtol=0, atol=1e-12 * max(1.0, np.abs(J).max())):
            raise UserError(path, "3×3 inertia must be symmetric")
    else:
        J = np.diag(_vector(value, 3, path, lo=INERTIA[0], hi=INERTIA[1]))
    if np.linalg.eigvalsh(J).min() < 0:
        raise UserError(path, "inertia must be positive semi-definite")
    return J


def _link(doc, path) -> dict:
    doc = _mapping(doc, path)
    _keys(doc, path, required=("length", "mass_per_length"),
          optional=("inertia_per_length", "joint_rpy", "stroke"))
    length = _number(doc["length"], f"{path}.length", lo=LENGTH[0], hi=LENGTH[1])
    link = {
        "length": length,
        "mass_per_length": _number(doc["mass_per_length"], f"{path}.mass_per_length",
                                   lo=DENSITY[0], hi=DENSITY[1]),
        "inertia_per_length": _inertia(doc.get("inertia_per_length", [0.0, 0.0, 0.0]),
                                       f"{path}.inertia_per_length"),
        "joint_rpy": _vector(doc.get("joint_rpy", [0.0, 0.0, 0.0]), 3, f"{path}.joint_rpy",
                             lo=-2 * math.pi, hi=2 * math.pi),
        "stroke": _vector(doc.get("stroke", [0.0, length]), 2, f"{path}.stroke",
                          lo=0.0, hi=length),
    }
    if link["stroke"][0] > link["stroke"][1]:
        raise UserError(f"{path}.stroke", "lower end must not exceed upper end")
    return link


def _robot(doc) -> RobotModel:
    doc = _mapping(doc, "robot")
    _keys(doc, "robot", required=("base",), optional=("arm", "limits"))
    arm = _mapping(doc.get("arm", {}), "robot.arm")
    _keys(arm, "robot.arm", optional=("mount", "links"))
    links = schema.sequence(arm.get("links", []), "robot.arm.links", max_length=MAX_LINKS)
    return RobotModel.build(
        _base(doc["base"]),
        _vector(arm.get("mount", [0.0, 0.0, 0.0]), 3, "robot.arm.mount", lo=-LENGTH[1],
                hi=LENGTH[1]),
        [_link(link, f"robot.arm.links[{i}]") for i, link in enumerate(links)])


def _limit_groups(value, path: str, n_arm: int, hi: float) -> dict:
    """{"wheels": (2,), "joints": (n_arm,)} of a mapping of bounds (each a list or one number for
    the group; a group left out: None)."""
    value = _mapping(value, path)
    _keys(value, path, optional=("wheels", "joints"))
    return {group: (_vector_or_scalar(value[group], size, f"{path}.{group}", positive=True,
                                      hi=hi)
                    if group in value else None)
            for group, size in (("wheels", 2), ("joints", n_arm))}


def _robot_limits(doc, robot: RobotModel) -> dict:
    """`robot.limits`: the robot's effort (N·m, N) and velocity (rad/s, m/s) limits per joint
    group, a motor's ratings (docs/scene.md, "Limits a robot has")."""
    doc = _mapping(doc.get("limits", {}), "robot.limits")
    _keys(doc, "robot.limits", optional=("effort", "velocity"))
    n_arm = arm_size(robot.n_links)
    return {kind: (_limit_groups(doc[kind], f"robot.limits.{kind}", n_arm, hi)
                   if kind in doc else None)
            for kind, hi in (("effort", EFFORT), ("velocity", SPEED))}


def _effects(doc, robot: RobotModel, limits: dict) -> Effects:
    doc = _mapping(doc, "effects")
    _keys(doc, "effects", optional=EFFECT_NAMES)
    n_arm = arm_size(robot.n_links)
    effects = {}
    if "gravity" in doc:
        effects["gravity"] = _number(doc["gravity"], "effects.gravity", lo=GRAVITY[0],
                                     hi=GRAVITY[1])
    if "stroke_limits" in doc:
        value = doc["stroke_limits"]
        if value is True or value == {}:
            value = {}
        if value is None:
            raise UserError("effects.stroke_limits", "expected true, false or a mapping, got null")
        if value is not False:
            value = _mapping(value, "effects.stroke_limits")
            _keys(value, "effects.stroke_limits", optional=("restitution", "law", "rest_speed"))
            law = value.get("law", "impulse")
            if law not in IMPACT_LAWS:
                raise UserError("effects.stroke_limits.law",
                                f"unknown law {schema.short(law)} (choose one of: "
                                f"{', '.join(IMPACT_LAWS)})")
            effects["stroke_limits"] = StrokeLimits(
                restitution=_number(value.get("restitution", 0.0),
                                    "effects.stroke_limits.restitution",
                                    lo=0.0, hi=1.0),
                law=law,
                rest_speed=_number(value.get("rest_speed", 1e-3),
                                   "effects.stroke_limits.rest_speed",
                                   lo=0.0, hi=SPEED))
    if "wheel_inertia" in doc:
        effects["wheel_inertia"] = _flag(doc["wheel_inertia"], "effects.wheel_inertia")
    if "joint_damping" in doc:
        effects["joint_damping"] = tuple(_vector_or_scalar(
            doc["joint_damping"], n_arm, "effects.joint_damping", lo=DAMPING[0], hi=DAMPING[1]))
    if "wheel_damping" in doc:
        effects["wheel_damping"] = _number(doc["wheel_damping"], "effects.wheel_damping",
                                           lo=DAMPING[0], hi=DAMPING[1])
    if "effort_limits" in doc:
        value = doc["effort_limits"]
        if value is True:   # the robot's own: one owner of the numbers
            if limits["effort"] is None:
                raise UserError("effects.effort_limits", "true takes the robot's effort limits, "
                                                         "but robot.limits.effort declares none")
            effects["effort_limits"] = limits["effort"]
        elif value is not False:
            effects["effort_limits"] = _limit_groups(value, "effects.effort_limits", n_arm,
                                                     EFFORT)
    if "locked_joints" in doc:
        names = doc["locked_joints"]
        if not isinstance(names, list):
            raise UserError("effects.locked_joints",
                            f"expected a list of joint names, got {schema.short(names)}")
        arm_names = robot.joint_names()[ARM_U]
        for i, name in enumerate(names):
            if name not in arm_names:
                raise UserError(f"effects.locked_joints[{i}]",
                                f"no arm joint named {schema.short(name)} "
                                f"(joints: {', '.join(arm_names) or 'none'})")
            if name in names[:i]:
                raise UserError(f"effects.locked_joints[{i}]", f"{name} is listed twice")
        effects["locked_joints"] = tuple(names)
    if "fixed_base" in doc:
        effects["fixed_base"] = _flag(doc["fixed_base"], "effects.fixed_base")
    if "payload" in doc:
        value = doc["payload"]
        if isinstance(value, dict):
            _keys(value, "effects.payload", required=("mass",))
            value = value["mass"]
        effects["payload"] = _number(value, "effects.payload", lo=MASS[0], hi=MASS[1])
        if robot.n_links == 0:
            raise UserError("effects.payload", "needs at least one arm link to carry it")
    return Effects(**effects)


def _integrator(doc) -> IntegratorSettings:
    doc = _mapping(doc, "integrator")
    _keys(doc, "integrator", optional=("method", "dt", "rtol", "atol"))
    for name, value in doc.items():
        if value is None:
            raise UserError(f"integrator.{name}", "expected a value, got null")
    return make_integrator(IntegratorSettings(), **doc)


def make_integrator(settings: IntegratorSettings, method=None, dt=None, rtol=None, atol=None,
                    prefix="integrator") -> IntegratorSettings:
    """Settings with the given overrides (scene keys or command-line flags), validated."""
    def key(name):
        return f"{prefix}{name}" if prefix.endswith("-") else f"{prefix}.{name}"

    method = settings.method if method is None else method
    if not isinstance(method, str) or method not in METHODS:
        raise UserError(key("method"), f"unknown method {schema.short(method)} "
                                       f"(choose one of: {', '.join(METHODS)})")
    return IntegratorSettings(
        method=method,
        dt=settings.dt if dt is None else _number(dt, key("dt"), lo=DT[0], hi=DT[1]),
        rtol=settings.rtol if rtol is None else _number(rtol, key("rtol"), lo=RTOL[0], hi=RTOL[1]),
        atol=settings.atol if atol is None else _number(atol, key("atol"), lo=ATOL[0], hi=ATOL[1]))


def check_work(duration: float, settings: IntegratorSettings, duration_key: str, dt_key: str,
               sample_rate: float | None = None, rate_key: str = "--sample-rate") -> None:
    """Refuse a run whose work is beyond the documented limits (docs/errors.md): more than
    MAX_STEPS fixed steps, more than MAX_SAMPLES samples, or a fixed step longer than the sample
    interval (the samples would not be at the step's resolution)."""
    if settings.fixed_step and duration / settings.dt > MAX_STEPS:
        key = dt_key if settings.dt < 1e-6 else duration_key
        raise UserError(key, f"{duration:.6g} s / dt {settings.dt:.6g} s is more than "
                             f"{MAX_STEPS} steps")
    if sample_rate is None:
        return
    if duration * sample_rate > MAX_SAMPLES:
        raise UserError(rate_key, f"{duration:.6g} s × {sample_rate:.6g} Hz is more than "
                                  f"{MAX_SAMPLES} samples")
    if settings.fixed_step and settings.dt > 1.0 / sample_rate * (1 + 1e-12):
        raise UserError(dt_key, f"the fixed step {settings.dt:.6g} s is longer than the sample "
                                f"interval {1.0 / sample_rate:.6g} s ({rate_key})")


def parse_scene(doc, name="scene") -> Scene:
    """Validate a scene document (the parsed YAML mapping)."""
    doc = _mapping(doc, "")
    _keys(doc, "", required=("robot",),
          optional=("name", "initial", "efforts", "effects", "integrator", "duration",
                    "controller"))
    robot = _robot(doc["robot"])
    n = robot.n_links
    initial = _mapping(doc.get("initial", {}), "initial")
    _keys(initial, "initial", optional=("pose", "wheels", "joints", "velocity"))
    default_joints = [value for i in range(n) for value in (0.0, float(robot.stroke[i][0]))]
    pose = _vector(initial.get("pose", [0.0, 0.0, 0.0]), 3, "initial.pose", lo=-ANGLE, hi=ANGLE)
    wheels = _vector(initial.get("wheels", [0.0, 0.0]), 2, "initial.wheels", lo=-ANGLE, hi=ANGLE)
    if n == 0 and initial.get("joints"):
        raise UserError("robot.arm",
                        "missing: initial.joints gives arm joints but the robot has no arm")
    joints = _vector(initial.get("joints", default_joints), arm_size(n), "initial.joints",
                     lo=-ANGLE, hi=ANGLE)
    for i in range(n):
        lo, hi = robot.stroke[i]
        if not lo <= joints[2 * i + 1] <= hi:
            raise UserError(f"initial.joints[{2 * i + 1}]",
                            f"l{i + 1} = {joints[2 * i + 1]} is outside its stroke [{lo}, {hi}]")
    velocity = _vector(initial.get("velocity", [0.0] * robot.n_u), robot.n_u, "initial.velocity",
                       lo=-SPEED, hi=SPEED)
    efforts = _mapping(doc.get("efforts", {}), "efforts")
    _keys(efforts, "efforts", optional=("wheels", "joints"))
    if n == 0 and efforts.get("joints"):
        raise UserError("robot.arm",
                        "missing: efforts.joints gives arm efforts but the robot has no arm")
    limits = _robot_limits(_mapping(doc["robot"], "robot"), robot)
    effects = _effects(doc.get("effects", {}), robot, limits)
    controller = parse_controller(doc.get("controller"), robot, effects.stroke_limits is not None)
    integrator = _integrator(doc.get("integrator", {}))
    scene_name = schema.string(doc.get("name", name), "name")
    scene = Scene(
        name=scene_name, robot=robot,
        initial_q=np.concatenate([pose, wheels, joints]), initial_u=velocity,
        wheel_efforts=_vector(efforts.get("wheels", [0.0, 0.0]), 2, "efforts.wheels",
                              lo=-EFFORT, hi=EFFORT),
        joint_efforts=_vector(efforts.get("joints", [0.0] * arm_size(n)), arm_size(n),
                              "efforts.joints",
                              lo=-EFFORT, hi=EFFORT),
        effects=effects, integrator=integrator,
        duration=_number(doc.get("duration", 1.0), "duration", positive=True, hi=DURATION[1]),
        document={}, controller=controller, limits=limits)
    if controller is not None and controller.arm_controller.active \
            and np.any(scene.joint_efforts):
        raise UserError("efforts.joints", f"the arm is driven by controller.arm_controller: "
                                          f"{controller.arm_controller.mode} (remove the joint "
                                          f"efforts)")
    check_work(scene.duration, integrator, "duration", "integrator.dt")
    object.__setattr__(scene, "document", _document(doc, scene))
    return scene


def _document(doc: dict, scene: Scene) -> dict:
    """The scene as YAML-ready data, every default filled in (recorded into bags)."""
    full = copy.deepcopy(doc)
    full["name"] = scene.name
    full["duration"] = scene.duration
    full["initial"] = {"pose": scene.initial_q[BASE_POSE].tolist(),
                       "wheels": scene.initial_q[WHEELS].tolist(),
                       "joints": scene.initial_q[ARM_Q].tolist(),
                       "velocity": scene.initial_u.tolist()}
    full["efforts"] = {"wheels": scene.wheel_efforts.tolist(),
                       "joints": scene.joint_efforts.tolist()}
    s = scene.integrator
    full["integrator"] = {"method": s.method, "dt": s.dt, "rtol": s.rtol, "atol": s.atol}
    return full


def load_scene(path: str | Path | None = None) -> Scene:
    """Read and validate a scene file; None loads the embedded default (the paper's run)."""
    if path is None:
        text = resources.files("mobile_manip_sim").joinpath("config", DEFAULT_SCENE).read_text()
        name = Path(DEFAULT_SCENE).stem
    else:
        path = Path(path)
        text = schema.read_text_file(path, kind="scene file")
        name = path.stem
    return scene_from_text(text, name)


def scene_from_text(text: str, name: str = "scene") -> Scene:
    doc = schema.load_yaml(text, what=name)
    if doc is None:
        raise UserError(name, "the scene file is empty")
    if not isinstance(doc, dict):
        raise UserError(name, f"expected a mapping of scene keys, got {schema.short(doc)}")
    return parse_scene(doc, name)
