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
  robot_state_publisher needs no limits for them. The prismatic joints' lower and upper limits are
  the strokes. Every moving joint has a ``<limit>`` (`joint_limits`): its effort is the limit the
  simulator enforces (``effects.effort_limits``), else the robot's own (``robot.limits.effort``),
  else `limits.EFFORT` (the largest effort the simulator accepts); its velocity is the robot's
  (``robot.limits.velocity``: what a planner or joint_trajectory_controller plans within; the
  model enforces none), else `limits.SPEED` (the largest speed the simulator accepts).
- Masses: the scene gives the base's mass M_pw and yaw inertia I_pw with the wheels included.
  Each wheel is a uniform disc of the scene's spin inertia I_w, so its mass is m_w = 2 I_w / r²
  (halved until the base's own share below stays physical); the base link carries the rest,
  M_pw − 2 m_w, at the centre of mass and with the yaw inertia that keep the robot's total
  (M_pw at G, I_pw about G) exactly the scene's. A wheel's inertia is m_w r²/4 (at least I_w/2)
  about its diameters and its spin inertia about y: I_w, or 0 when the scene's ``wheel_inertia``
  effect is off (the simulator then uses 0): the URDF is always the simulated model.
- ``base_link``'s roll and pitch inertia, which the planar model never uses, are those of a
  uniform box the size of its collision box, made equal and at least I_zz/2 so that the inertia
  is physically valid (the triangle inequalities hold).
- Collision shapes: a box for the base, cylinders for the wheels and the rods (the visual shapes).
- ``ros2_control`` (optional, `describe --ros2-control`): a ``<ros2_control>`` block for
  ros2_control's topic-based hardware interface (``joint_state_topic_hardware_interface``), which
  sends sensor_msgs/JointState commands on the node's joint-command topic and reads its joint
  states topic (`ros2_control_block`).
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

from ..scene import limits as bounds
from ..scene.coordinates import JOINTS, rod
from ..scene.effects import settings as effect_settings
from ..scene.loading import Scene
from .frames import BASE_LINK, FOOTPRINT, TIP, FrameTree
from .topics import JOINT_COMMANDS_TOPIC, ROBOT_JOINT_STATES_TOPIC, relative

# Command interfaces of the ros2_control block: the wheels' and the arm's.
WHEEL_INTERFACES = ("velocity", "effort")
ARM_INTERFACES = ("position", "velocity", "effort")
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
            rpy=(0.0, 0.0, 0.0), collision: bool = False, **size) -> None:
    """A ``<visual>`` and, if ``collision``, a ``<collision>`` of the same shape."""
    for tag in ("visual", "collision") if collision else ("visual",):
        element = ET.SubElement(link, tag)
        _origin(element, xyz, rpy)
        shape = ET.SubElement(ET.SubElement(element, "geometry"), geometry)
        for key, value in size.items():
            shape.set(key, _vec(value) if isinstance(value, (tuple, list)) else _num(value))
        if tag == "visual":
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


def _limit(joint: ET.Element, effort: float, velocity: float, lower=None, upper=None) -> None:
    limit = ET.SubElement(joint, "limit")
    if lower is not None:
        limit.set("lower", _num(lower))
        limit.set("upper", _num(upper))
    limit.set("effort", _num(effort))
    limit.set("velocity", _num(velocity))


def joint_limits(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(effort, velocity) (n_u each, joints indexed as u: τ_R, τ_L, τ_1, F_1, …) of the URDF's
    ``<limit>``s (module doc): the enforced effort limit, else the robot's, else `limits.EFFORT`;
    the robot's velocity limit, else `limits.SPEED`."""
    n_u = scene.robot.n_u
    effort, velocity = np.full(n_u, bounds.EFFORT), np.full(n_u, bounds.SPEED)
    declared = scene.limits
    for values, groups in ((effort, declared["effort"]), (velocity, declared["velocity"])):
        for group, where in (("wheels", slice(0, 2)), ("joints", slice(2, None))):
            if groups is not None and groups[group] is not None:
                values[where] = groups[group]
    enforced = effect_settings(scene).effort_limits
    if enforced is not None:
        effort = np.where(np.isinf(enforced), effort, enforced)
    return effort, velocity


def _damping(joint: ET.Element, damping) -> None:
    if damping:
        ET.SubElement(joint, "dynamics", damping=_num(damping))


def wheel_mass(base) -> float:
    """m_w: a uniform disc of spin inertia I_w (m r²/2 = I_w), halved until the base's own share
    (`base_share`) is physical."""
    mass = 2.0 * base.wheel_inertia / base.wheel_radius ** 2
    while mass > 0.0 and base_share(base, mass)[2] < 0.0:
        mass = 0.0 if mass < 1e-12 * base.mass else 0.5 * mass
    return mass


def wheel_tilt_inertia(base, m_w: float) -> float:
    """A wheel's inertia about its diameters: a disc's m_w r²/4, and at least I_w/2 so that its
    spin inertia I_w obeys the triangle inequality."""
    return max(m_w * base.wheel_radius ** 2 / 4.0, 0.5 * base.wheel_inertia)


def base_share(base, m_w: float) -> tuple[float, float, float]:
    """(mass, x of its centre of mass, yaw inertia about it) of the base without its two wheels
    of mass ``m_w`` (at x = 0, y = ±b; `wheel_tilt_inertia` about the vertical): what keeps the
    total the scene's M_pw at G = (d, 0, 0) and I_pw about G. Negative: not physical."""
    d, b = base.com_offset, base.half_track
    mass = base.mass - 2.0 * m_w
    if mass <= 0.0:
        return mass, d, -1.0
    x = base.mass * d / mass
    yaw = (base.yaw_inertia - mass * (x - d) ** 2
           - 2.0 * (wheel_tilt_inertia(base, m_w) + m_w * (d ** 2 + b ** 2)))
    return mass, x, yaw


def _base_inertia(mass: float, yaw: float, size) -> np.ndarray:
    """The base link's inertia: yaw from the scene, roll and pitch those of a uniform box of
    ``size`` (equal, and at least yaw/2 so that the triangle inequalities hold)."""
    length, width, height = size
    box = mass * (length ** 2 + width ** 2 + 2.0 * height ** 2) / 24.0   # mean of I_xx, I_yy
    tilt = max(box, 0.5 * yaw)
    return np.diag([tilt, tilt, yaw])


def robot_description(scene: Scene, root: str = FOOTPRINT, prefix: str = "",
                      ros2_control: dict | None = None) -> str:
    """The URDF (XML text) of `scene`'s robot with the scene's effects (payload, wheel inertia,
    damping, effort limits) applied as the simulator applies them; `root` names the link on the
    ground under the axle midpoint. The joints, their origins and axes are `frames.FrameTree`'s;
    every link name carries ``prefix`` (joint names stay those of /joint_states).
    ``ros2_control``: the keyword arguments of `ros2_control_block` to append one, or None."""
    model, effects = scene.robot, effect_settings(scene)
    tree = FrameTree(model, root, prefix)
    base = model.base
    d, r, b = base.com_offset, base.wheel_radius, base.half_track
    efforts, velocities = joint_limits(scene)   # one per joint: the joints are indexed as u
    damping = np.zeros(model.n_u) if effects.rate_damping is None else effects.rate_damping

    robot = ET.Element("robot", name=scene.name)
    for name, rgba in (("chassis", (0.3, 0.3, 0.35, 1.0)), ("wheel", (0.1, 0.1, 0.1, 1.0)),
                       ("rod", (0.85, 0.45, 0.1, 1.0)), ("payload", (0.2, 0.4, 0.8, 1.0))):
        ET.SubElement(ET.SubElement(robot, "material", name=name), "color", rgba=_vec(rgba))
    ET.SubElement(robot, "link", name=tree.frame(root))
    wheel_width = min(0.5 * r, b)
    I_w = base.wheel_inertia if effects.wheel_inertia else 0.0
    m_w = wheel_mass(base)
    base_mass, base_x, base_yaw = base_share(base, m_w)

    for joint in tree.joints:   # each child link, then the joint that carries it
        link = ET.SubElement(robot, "link", name=tree.frame(joint.child))
        if joint.child == BASE_LINK:
            # Base without its wheels: with them, mass M_pw at G = (d, 0, 0), I_pw about G.
            size = (2.0 * (abs(d) + r), 2.0 * b - wheel_width, r)
            _visual(link, "box", "chassis", xyz=(d, 0.0, 0.0), collision=True, size=size)
            _inertial(link, base_mass, (base_x, 0.0, 0.0),
                      _base_inertia(base_mass, base_yaw, size))
        elif joint.index is not None and joint.index < 2:
            # Wheels: a positive angle about +y rolls the robot forward (docs/model.md).
            _visual(link, "cylinder", "wheel", rpy=(math.pi / 2, 0.0, 0.0), collision=True,
                    radius=r, length=wheel_width)
            if m_w > 0.0 or I_w > 0.0:
                diameter = wheel_tilt_inertia(base, m_w)
                _inertial(link, m_w, (0.0, 0.0, 0.0), np.diag([diameter, I_w, diameter]))
        elif joint.kind == "prismatic":
            k = rod(joint.index) - 1
            L, mu = float(model.length[k]), float(model.mass_per_length[k])
            J = np.asarray(model.inertia_per_length[k], dtype=float)
            # A solid round rod has J_xx = μ ρ²/2 per unit length: draw it with that radius ρ.
            radius = math.sqrt(2.0 * J[0, 0] / mu) if J[0, 0] > 0.0 else DEFAULT_ROD_RADIUS
            _visual(link, "cylinder", "rod", xyz=(-0.5 * L, 0.0, 0.0),
                    rpy=(0.0, math.pi / 2, 0.0), collision=True, radius=min(radius, 0.25 * L),
                    length=L)
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
            _limit(element, efforts[joint.index], velocities[joint.index],
                   lower=model.stroke[k][0], upper=model.stroke[k][1])
        elif joint.index is not None:
            _limit(element, efforts[joint.index], velocities[joint.index])
        if joint.index is not None:
            _damping(element, damping[joint.index])
    if ros2_control is not None:
        robot.append(ros2_control_block(scene, **ros2_control))

    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def ros2_control_block(scene: Scene, wheels: str = "velocity", arm: str = "position",
                       name: str | None = None) -> ET.Element:
    """A ``<ros2_control>`` system for ros2_control's topic-based hardware interface
    (``joint_state_topic_hardware_interface/JointStateTopicSystem``): it publishes
    sensor_msgs/JointState commands on the node's joint-command topic and reads the node's joint
    states topic (both relative: they resolve in controller_manager's namespace, which should be
    the simulator's). The wheels take ``wheels`` commands (velocity for diff_drive_controller, or
    effort), the arm's joints ``arm`` commands (position for joint_trajectory_controller,
    velocity or effort); every joint offers position, velocity and effort states, the initial
    position being the scene's. The node must run in the matching modes (base_command,
    arm_controller; docs/ros.md)."""
    if wheels not in WHEEL_INTERFACES:
        raise ValueError(f"wheel command interface {wheels!r} is not one of "
                         f"{', '.join(WHEEL_INTERFACES)}")
    if arm not in ARM_INTERFACES:
        raise ValueError(f"arm command interface {arm!r} is not one of "
                         f"{', '.join(ARM_INTERFACES)}")
    model = scene.robot
    block = ET.Element("ros2_control", name=name or scene.name, type="system")
    hardware = ET.SubElement(block, "hardware")
    ET.SubElement(hardware, "plugin").text = \
        "joint_state_topic_hardware_interface/JointStateTopicSystem"
    for key, value in (("joint_commands_topic", relative(JOINT_COMMANDS_TOPIC)),
                       ("joint_states_topic", relative(ROBOT_JOINT_STATES_TOPIC)),
                       ("trigger_joint_command_threshold", "-1")):
        ET.SubElement(hardware, "param", name=key).text = value
    initial = np.asarray(scene.initial_q, dtype=float)[JOINTS]
    for j, joint_name in enumerate(model.joint_names()):
        joint = ET.SubElement(block, "joint", name=joint_name)
        ET.SubElement(joint, "command_interface", name=wheels if j < 2 else arm)
        for interface in ("position", "velocity", "effort"):
            state = ET.SubElement(joint, "state_interface", name=interface)
            if interface == "position":
                ET.SubElement(state, "param", name="initial_value").text = _num(initial[j])
    return block
