"""A URDF of a scene's robot, for `robot_state_publisher` (/robot_description) and viewers.

The URDF describes the same multibody the simulator integrates (docs/model.md), so Pinocchio's URDF
parser with a planar root joint at ``base_link`` gives the core's mass matrix
(``M = Sᵀ M_full S``, see test/ros/test_urdf.py). The tree — links, joints, origins, axes, the
frame prefix — is `frames.FrameTree`'s; this module adds the bodies, drawings and limits:

- ``arm_link_k`` is joint frame k of docs/model.md (origin O_k, x along rod k, z the joint axis); it
  is massless, so it has no ``<inertial>``.
- ``arm_rod_k`` has its frame at the rod's DISTAL end (η = l_k, where joint k+1 sits); the rod
  occupies x ∈ [−L_k, 0] in it: mass μL at (−L/2, 0, 0), inertia of a uniform slender rod
  (μL·L²/12 about y and z) plus the cross-section inertia J·L.
- ``tip`` is the distal end of the last rod (the mount point when there is no arm). With the
  ``payload`` effect it carries the payload as a point mass; otherwise it is a massless frame.
- The arm's revolute joints are ``continuous``: the model has no angle stops and
  robot_state_publisher needs no limits for them. The prismatic joints' limits are the strokes.
  Efforts and velocities in ``<limit>`` are the scene's effort limits when it sets them, otherwise
  the placeholder ``UNLIMITED`` (URDF requires the attributes; nothing here enforces them).
- Masses: the base's mass and yaw inertia already include the wheels (M_pw, I_pw), so the wheel
  links are massless; they carry only the spin inertia I_w about y. When the scene's
  ``wheel_inertia`` effect is off the simulator uses I_w = 0, and so does the URDF: the wheel
  links then have no ``<inertial>`` at all — the URDF is always the simulated model, never more.
- ``base_link``'s ixx and iyy are set equal to the yaw inertia I_pw so that the inertia is valid
  for tools that want one; the planar model never uses them (the base cannot roll or pitch).
- ``base_footprint`` is the massless root, on the floor (z = 0) under the axle midpoint, so the
  wheels touch the ground in a viewer; ``base_link`` sits r above it. The TF tree is
  ``odom → base_footprint → base_link → …``, every transform from `frames.FrameTree`.
  The core's heights are measured from the axle: a URDF point is the core's point + r·z.

Joint names equal `RobotModel.joint_names()`, i.e. the names in /joint_states.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np

from ..scene.coordinates import rod
from ..scene.effects import settings as effect_settings
from ..scene.loading import Scene
from .frames import BASE_LINK, FOOTPRINT, TIP, FrameTree

UNLIMITED = 1.0e6          # effort (N·m or N) and velocity placeholder where the scene sets none
DEFAULT_ROD_RADIUS = 0.02  # m, drawn radius of a rod whose cross-section inertia is zero
PAYLOAD_RADIUS = 0.04      # m, drawn radius of the payload sphere


def _num(value: float) -> str:
    return repr(float(value))  # shortest text that reads back as the same double


def _vec(values) -> str:
    return " ".join(_num(v) for v in values)


def _origin(parent: ET.Element, xyz=(0.0, 0.0, 0.0), rpy=(0.0, 0.0, 0.0)) -> None:
    ET.SubElement(parent, "origin", xyz=_vec(xyz), rpy=_vec(rpy))


def _inertial(link: ET.Element, mass: float, com, inertia: np.ndarray) -> None:
    """``<inertial>`` with the inertia (kg·m²) about the centre of mass `com`, link axes."""
    element = ET.SubElement(link, "inertial")
    _origin(element, com)
    ET.SubElement(element, "mass", value=_num(mass))
    I = np.asarray(inertia, dtype=float)
    ET.SubElement(element, "inertia", ixx=_num(I[0, 0]), ixy=_num(I[0, 1]), ixz=_num(I[0, 2]),
                  iyy=_num(I[1, 1]), iyz=_num(I[1, 2]), izz=_num(I[2, 2]))


def _visual(link: ET.Element, geometry: str, material: str, xyz=(0.0, 0.0, 0.0),
            rpy=(0.0, 0.0, 0.0), **size) -> None:
    element = ET.SubElement(link, "visual")
    _origin(element, xyz, rpy)
    shape = ET.SubElement(ET.SubElement(element, "geometry"), geometry)
    for key, value in size.items():
        shape.set(key, _vec(value) if isinstance(value, (tuple, list)) else _num(value))
    ET.SubElement(element, "material", name=material)


def _joint(robot: ET.Element, name: str, kind: str, parent: str, child: str, xyz=(0.0, 0.0, 0.0),
           rpy=(0.0, 0.0, 0.0), axis=None) -> ET.Element:
    joint = ET.SubElement(robot, "joint", name=name, type=kind)
    _origin(joint, xyz, rpy)
    ET.SubElement(joint, "parent", link=parent)
    ET.SubElement(joint, "child", link=child)
    if axis is not None:
        ET.SubElement(joint, "axis", xyz=_vec(axis))
    return joint


def _limit(joint: ET.Element, effort, lower=None, upper=None) -> None:
    limit = ET.SubElement(joint, "limit")
    if lower is not None:
        limit.set("lower", _num(lower))
        limit.set("upper", _num(upper))
    limit.set("effort", _num(UNLIMITED if effort is None else effort))
    limit.set("velocity", _num(UNLIMITED))


def _damping(joint: ET.Element, damping) -> None:
    if damping:
        ET.SubElement(joint, "dynamics", damping=_num(damping))


def robot_description(scene: Scene, root: str = FOOTPRINT, prefix: str = "") -> str:
    """The URDF (XML text) of `scene`'s robot with the scene's effects (payload, wheel inertia,
    damping, effort limits) applied as the simulator applies them; `root` names the link on the
    ground under the axle midpoint. The joints, their origins and axes are `frames.FrameTree`'s;
    every link name carries ``prefix`` (joint names stay those of /joint_states)."""
    model, effects = scene.robot, effect_settings(scene)
    tree = FrameTree(model, root, prefix)
    base = model.base
    d, r, b = base.com_offset, base.wheel_radius, base.half_track
    # the scene's bounds (None where it sets none) and damping, as the simulator applies them
    limits = effects.effort_limits
    efforts = [None if limits is None or math.isinf(limits[j]) else limits[j]
               for j in range(model.n_u)]   # one per joint: the joints are indexed as u
    damping = np.zeros(model.n_u) if effects.rate_damping is None else effects.rate_damping

    robot = ET.Element("robot", name=scene.name)
    for name, rgba in (("chassis", (0.3, 0.3, 0.35, 1.0)), ("wheel", (0.1, 0.1, 0.1, 1.0)),
                       ("rod", (0.85, 0.45, 0.1, 1.0)), ("payload", (0.2, 0.4, 0.8, 1.0))):
        ET.SubElement(ET.SubElement(robot, "material", name=name), "color", rgba=_vec(rgba))
    ET.SubElement(robot, "link", name=tree.frame(root))
    wheel_width = min(0.5 * r, b)
    I_w = base.wheel_inertia if effects.wheel_inertia else 0.0

    for joint in tree.joints:   # each child link, then the joint that carries it
        link = ET.SubElement(robot, "link", name=tree.frame(joint.child))
        if joint.child == BASE_LINK:
            # Base: body = base + wheels, mass M_pw at G = (d, 0, 0), yaw inertia I_pw about G.
            _visual(link, "box", "chassis", xyz=(d, 0.0, 0.0),
                    size=(2.0 * (abs(d) + r), 2.0 * b - wheel_width, r))
            _inertial(link, base.mass, (d, 0.0, 0.0), base.yaw_inertia * np.eye(3))
        elif joint.index is not None and joint.index < 2:
            # Wheels: a positive angle about +y rolls the robot forward (docs/model.md).
            _visual(link, "cylinder", "wheel", rpy=(math.pi / 2, 0.0, 0.0), radius=r,
                    length=wheel_width)
            if I_w > 0.0:
                _inertial(link, 0.0, (0.0, 0.0, 0.0), np.diag([0.0, I_w, 0.0]))
        elif joint.kind == "prismatic":
            k = rod(joint.index) - 1
            L, mu = float(model.length[k]), float(model.mass_per_length[k])
            J = np.asarray(model.inertia_per_length[k], dtype=float)
            # A solid round rod has J_xx = μ ρ²/2 per unit length: draw it with that radius ρ.
            radius = math.sqrt(2.0 * J[0, 0] / mu) if J[0, 0] > 0.0 else DEFAULT_ROD_RADIUS
            _visual(link, "cylinder", "rod", xyz=(-0.5 * L, 0.0, 0.0),
                    rpy=(0.0, math.pi / 2, 0.0), radius=min(radius, 0.25 * L), length=L)
            mass = mu * L
            bending = mass * L ** 2 / 12.0
            _inertial(link, mass, (-0.5 * L, 0.0, 0.0), np.diag([0.0, bending, bending]) + J * L)
        elif joint.child == TIP and effects.tip_mass:
            # Tip: the distal end of the last rod (the rod frame's origin), or the mount point.
            _visual(link, "sphere", "payload", radius=PAYLOAD_RADIUS)
            _inertial(link, effects.tip_mass, (0.0, 0.0, 0.0), np.zeros((3, 3)))
        element = _joint(robot, joint.name, joint.kind, tree.frame(joint.parent),
                         tree.frame(joint.child), xyz=joint.xyz, rpy=joint.rpy, axis=joint.axis)
        if joint.kind == "prismatic":
            k = rod(joint.index) - 1
            _limit(element, efforts[joint.index], lower=model.stroke[k][0],
                   upper=model.stroke[k][1])
        elif joint.index is not None and efforts[joint.index] is not None:
            _limit(element, efforts[joint.index])
        if joint.index is not None:
            _damping(element, damping[joint.index])

    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"
