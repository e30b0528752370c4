"""Scene files (YAML) → a validated, immutable `Scene`: robot, initial state, efforts, effects,
integrator. Every mistake raises `UserError` naming its key path (``robot.arm.links[1].length``).

The full format, with every key and its default, is documented in README.md ("Scene format").
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

from .errors import UserError
from .model import Base, RobotModel

DEFAULT_SCENE = "paper_two_link.yaml"

METHODS = ("euler", "semi_implicit_euler", "rk4", "rk45", "dop853", "radau", "bdf")
FIXED_STEP_METHODS = ("euler", "semi_implicit_euler", "rk4")
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

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.document, sort_keys=False)


# --- small validators: each names the key path in its error --------------------------------

def _number(value, path, *, positive=False, nonnegative=False, lo=None, hi=None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise UserError(path, f"expected a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise UserError(path, f"must be finite, got {value}")
    if positive and value <= 0:
        raise UserError(path, f"must be positive, got {value}")
    if nonnegative and value < 0:
        raise UserError(path, f"must not be negative, got {value}")
    if lo is not None and value < lo or hi is not None and value > hi:
        raise UserError(path, f"must be in [{lo}, {hi}], got {value}")
    return value


def _vector(value, length, path, **checks) -> np.ndarray:
    if not isinstance(value, (list, tuple)):
        raise UserError(path, f"expected a list of {length} numbers, got {value!r}")
    if len(value) != length:
        raise UserError(path, f"expected {length} values, got {len(value)}")
    return np.array([_number(v, f"{path}[{i}]", **checks) for i, v in enumerate(value)])


def _vector_or_scalar(value, length, path, **checks) -> np.ndarray:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return np.full(length, _number(value, path, **checks))
    return _vector(value, length, path, **checks)


def _mapping(value, path) -> dict:
    if not isinstance(value, dict):
        raise UserError(path, f"expected a mapping, got {value!r}")
    return value


def _keys(mapping, path, required=(), optional=()) -> None:
    prefix = f"{path}." if path else ""
    for key in mapping:
        if key not in required and key not in optional:
            allowed = ", ".join(list(required) + list(optional))
            raise UserError(f"{prefix}{key}", f"unknown key (allowed: {allowed})")
    for key in required:
        if key not in mapping:
            raise UserError(f"{prefix}{key}", "missing")


def _flag(value, path) -> bool:
    if not isinstance(value, bool):
        raise UserError(path, f"expected true or false, got {value!r}")
    return value


# --- the sections ---------------------------------------------------------------------------

def _base(doc) -> Base:
    path = "robot.base"
    doc = _mapping(doc, path)
    keys = ("mass", "yaw_inertia", "com_offset", "wheel_radius", "half_track", "wheel_inertia")
    _keys(doc, path, required=keys)
    positive = {"mass", "yaw_inertia", "wheel_radius", "half_track"}
    values = {k: _number(doc[k], f"{path}.{k}", positive=k in positive, nonnegative=True)
              for k in keys if k != "com_offset"}
    values["com_offset"] = _number(doc["com_offset"], f"{path}.com_offset")
    return Base(**values)


def _inertia(value, path) -> np.ndarray:
    if isinstance(value, (list, tuple)) and len(value) == 3 and all(isinstance(r, (list, tuple)) for r in value):
        J = np.array([_vector(r, 3, f"{path}[{i}]") for i, r in enumerate(value)])
        if not np.allclose(J, J.T, rtol=0, atol=1e-12 * max(1.0, np.abs(J).max())):
            raise UserError(path, "3×3 inertia must be symmetric")
    else:
        J = np.diag(_vector(value, 3, path, nonnegative=True))
    if np.linalg.eigvalsh(J).min() < 0:
        raise UserError(path, "inertia must be positive semi-definite")
    return J


def _link(doc, path) -> dict:
    doc = _mapping(doc, path)
    _keys(doc, path, required=("length", "mass_per_length"),
          optional=("inertia_per_length", "joint_rpy", "stroke"))
    length = _number(doc["length"], f"{path}.length", positive=True)
    link = {
        "length": length,
        "mass_per_length": _number(doc["mass_per_length"], f"{path}.mass_per_length", positive=True),
        "inertia_per_length": _inertia(doc.get("inertia_per_length", [0.0, 0.0, 0.0]),
                                       f"{path}.inertia_per_length"),
        "joint_rpy": _vector(doc.get("joint_rpy", [0.0, 0.0, 0.0]), 3, f"{path}.joint_rpy"),
        "stroke": _vector(doc.get("stroke", [0.0, length]), 2, f"{path}.stroke",
                          lo=0.0, hi=length),
    }
    if link["stroke"][0] > link["stroke"][1]:
        raise UserError(f"{path}.stroke", "lower end must not exceed upper end")
    return link


def _robot(doc) -> RobotModel:
    doc = _mapping(doc, "robot")
    _keys(doc, "robot", required=("base",), optional=("arm",))
    arm = _mapping(doc.get("arm", {}), "robot.arm")
    _keys(arm, "robot.arm", optional=("mount", "links"))
    links = arm.get("links", [])
    if not isinstance(links, list):
        raise UserError("robot.arm.links", f"expected a list, got {links!r}")
    return RobotModel.build(
        _base(doc["base"]),
        _vector(arm.get("mount", [0.0, 0.0, 0.0]), 3, "robot.arm.mount"),
        [_link(link, f"robot.arm.links[{i}]") for i, link in enumerate(links)])


def _effects(doc, robot: RobotModel) -> Effects:
    doc = _mapping(doc, "effects")
    _keys(doc, "effects", optional=EFFECT_NAMES)
    n_arm = 2 * robot.n_links
    effects = {}
    if "gravity" in doc:
        effects["gravity"] = _number(doc["gravity"], "effects.gravity", nonnegative=True)
    if "stroke_limits" in doc:
        value = doc["stroke_limits"]
        if value is True or value == {}:
            value = {}
        if value is not False and value is not None:
            value = _mapping(value, "effects.stroke_limits")
            _keys(value, "effects.stroke_limits", optional=("restitution", "law", "rest_speed"))
            law = value.get("law", "impulse")
            if law not in IMPACT_LAWS:
                raise UserError("effects.stroke_limits.law",
                                f"unknown law {law!r} (choose one of: {', '.join(IMPACT_LAWS)})")
            effects["stroke_limits"] = StrokeLimits(
                restitution=_number(value.get("restitution", 0.0), "effects.stroke_limits.restitution",
                                    lo=0.0, hi=1.0),
                law=law,
                rest_speed=_number(value.get("rest_speed", 1e-3), "effects.stroke_limits.rest_speed",
                                   nonnegative=True))
    if "wheel_inertia" in doc:
        effects["wheel_inertia"] = _flag(doc["wheel_inertia"], "effects.wheel_inertia")
    if "joint_damping" in doc:
        effects["joint_damping"] = tuple(_vector_or_scalar(
            doc["joint_damping"], n_arm, "effects.joint_damping", nonnegative=True))
    if "wheel_damping" in doc:
        effects["wheel_damping"] = _number(doc["wheel_damping"], "effects.wheel_damping",
                                           nonnegative=True)
    if "effort_limits" in doc:
        value = _mapping(doc["effort_limits"], "effects.effort_limits")
        _keys(value, "effects.effort_limits", optional=("wheels", "joints"))
        effects["effort_limits"] = {
            group: (_vector_or_scalar(value[group], size, f"effects.effort_limits.{group}", positive=True)
                    if group in value else None)
            for group, size in (("wheels", 2), ("joints", n_arm))}
    if "locked_joints" in doc:
        names = doc["locked_joints"]
        if not isinstance(names, list):
            raise UserError("effects.locked_joints", f"expected a list of joint names, got {names!r}")
        arm_names = robot.joint_names()[2:]
        for i, name in enumerate(names):
            if name not in arm_names:
                raise UserError(f"effects.locked_joints[{i}]",
                                f"no arm joint named {name!r} (joints: {', '.join(arm_names) or 'none'})")
        effects["locked_joints"] = tuple(names)
    if "fixed_base" in doc:
        effects["fixed_base"] = _flag(doc["fixed_base"], "effects.fixed_base")
    if "payload" in doc:
        value = doc["payload"]
        if isinstance(value, dict):
            _keys(value, "effects.payload", required=("mass",))
            value = value["mass"]
        effects["payload"] = _number(value, "effects.payload", positive=True)
        if robot.n_links == 0:
            raise UserError("effects.payload", "needs at least one arm link to carry it")
    return Effects(**effects)


def _integrator(doc) -> IntegratorSettings:
    doc = _mapping(doc, "integrator")
    _keys(doc, "integrator", optional=("method", "dt", "rtol", "atol"))
    return make_integrator(IntegratorSettings(), **doc)


def make_integrator(settings: IntegratorSettings, method=None, dt=None, rtol=None, atol=None,
                    prefix="integrator") -> IntegratorSettings:
    """Settings with the given overrides (scene keys or command-line flags), validated."""
    def key(name):
        return f"{prefix}{name}" if prefix.endswith("-") else f"{prefix}.{name}"

    method = settings.method if method is None else method
    if method not in METHODS:
        raise UserError(key("method"), f"unknown method {method!r} (choose one of: {', '.join(METHODS)})")
    return IntegratorSettings(
        method=method,
        dt=settings.dt if dt is None else _number(dt, key("dt"), positive=True),
        rtol=settings.rtol if rtol is None else _number(rtol, key("rtol"), positive=True),
        atol=settings.atol if atol is None else _number(atol, key("atol"), positive=True))


def parse_scene(doc, name="scene") -> Scene:
    """Validate a scene document (the parsed YAML mapping)."""
    doc = _mapping(doc, "")
    _keys(doc, "", required=("robot",),
          optional=("name", "initial", "efforts", "effects", "integrator", "duration"))
    robot = _robot(doc["robot"])
    n = robot.n_links
    initial = _mapping(doc.get("initial", {}), "initial")
    _keys(initial, "initial", optional=("pose", "wheels", "joints", "velocity"))
    default_joints = [value for i in range(n) for value in (0.0, float(robot.stroke[i][0]))]
    pose = _vector(initial.get("pose", [0.0, 0.0, 0.0]), 3, "initial.pose")
    wheels = _vector(initial.get("wheels", [0.0, 0.0]), 2, "initial.wheels")
    joints = _vector(initial.get("joints", default_joints), 2 * n, "initial.joints")
    for i in range(n):
        lo, hi = robot.stroke[i]
        if not lo <= joints[2 * i + 1] <= hi:
            raise UserError(f"initial.joints[{2 * i + 1}]",
                            f"l{i + 1} = {joints[2 * i + 1]} is outside its stroke [{lo}, {hi}]")
    velocity = _vector(initial.get("velocity", [0.0] * robot.n_u), robot.n_u, "initial.velocity")
    efforts = _mapping(doc.get("efforts", {}), "efforts")
    _keys(efforts, "efforts", optional=("wheels", "joints"))
    effects = _effects(doc.get("effects", {}), robot)
    integrator = _integrator(doc.get("integrator", {}))
    scene_name = doc.get("name", name)
    if not isinstance(scene_name, str):
        raise UserError("name", f"expected a string, got {scene_name!r}")
    scene = Scene(
        name=scene_name, robot=robot,
        initial_q=np.concatenate([pose, wheels, joints]), initial_u=velocity,
        wheel_efforts=_vector(efforts.get("wheels", [0.0, 0.0]), 2, "efforts.wheels"),
        joint_efforts=_vector(efforts.get("joints", [0.0] * 2 * n), 2 * n, "efforts.joints"),
        effects=effects, integrator=integrator,
        duration=_number(doc.get("duration", 1.0), "duration", positive=True),
        document={})
    object.__setattr__(scene, "document", _document(doc, scene))
    return scene


def _document(doc: dict, scene: Scene) -> dict:
    """The scene as YAML-ready data, every default filled in (recorded into bags)."""
    full = copy.deepcopy(doc)
    full["name"] = scene.name
    full["duration"] = scene.duration
    full["initial"] = {"pose": scene.initial_q[:3].tolist(), "wheels": scene.initial_q[3:5].tolist(),
                       "joints": scene.initial_q[5:].tolist(), "velocity": scene.initial_u.tolist()}
    full["efforts"] = {"wheels": scene.wheel_efforts.tolist(), "joints": scene.joint_efforts.tolist()}
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
        try:
            text = path.read_text()
        except (OSError, UnicodeDecodeError) as error:
            raise UserError(str(path), f"cannot read scene file ({getattr(error, 'strerror', None) or error})") from None
        name = path.stem
    return scene_from_text(text, name)


def scene_from_text(text: str, name: str = "scene") -> Scene:
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark else ""
        raise UserError(name, f"not valid YAML{where}: {getattr(error, 'problem', error)}") from None
    if doc is None:
        raise UserError(name, "the scene file is empty")
    return parse_scene(doc, name)
