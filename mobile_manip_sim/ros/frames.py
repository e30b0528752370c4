"""The robot's frames: the one owner of every link frame, its parent and the transform between
them. The URDF (urdf.py) is written from this tree, and /tf, /tf_static, bags and the live view
publish its transforms, so a viewer always draws the multibody the dynamics integrates. No ROS.

The tree (docs/model.md's kinematics, REP-105 names; `RobotModel.joint_names()` for the moving
joints):

    base_footprint                 on the floor under A (the root: the node's ``base_frame``)
    └─ base_footprint_joint   fixed, z = r                                     → base_link (A)
       ├─ right_wheel_joint   continuous about +y, at y = −b, value θ_R         → right_wheel
       ├─ left_wheel_joint    continuous about +y, at y = +b, value θ_L         → left_wheel
       └─ arm_revolute_1      continuous about +z, origin (m, R0_1), value q_1  → arm_link_1
          └─ arm_prismatic_1  prismatic along +x, value l_1                    → arm_rod_1
             └─ arm_revolute_2 … (origin: the distal end of rod 1, R0_2)       → arm_link_2 …
                └─ tip_joint  fixed, at the distal end of rod n (the mount when n = 0) → tip

A joint's transform parent → child is its origin (xyz, R0 = Rz(yaw)·Ry(pitch)·Rx(roll), the URDF
convention `model.rpy_matrix` uses) followed by its motion: a turn about the axis by the value, or
a slide along it. Composed from the root, joint frame k is R_k = R_{k−1}·R0_k·Rz(q_k) at
O_{k+1} = O_k + l_k x_k: the dynamics' position pass (core/include/mms/dynamics.hpp `frames`),
lifted by r.

``prefix`` (the node's ``frame_prefix``, e.g. ``robot1/``) is prepended to every frame name here
and nowhere else: two robots then make one tree without a shared frame. Joint names stay bare
(they name /joint_states entries, not frames).
"""
from __future__ import annotations

import math
from typing import NamedTuple

from ..scene.coordinates import JOINTS, YAW, X, Y, u_slide, u_turn
from ..scene.model import RobotModel

ODOM = "odom"                   # the odometry frame (REP-105): the default parent of the root
FOOTPRINT = "base_footprint"
BASE_LINK = "base_link"
TIP = "tip"
WHEELS = (("right", -1.0), ("left", 1.0))   # side, sign of y


class Joint(NamedTuple):
    """One joint of the tree, with bare frame names; ``index`` is its value's position in
    /joint_states (q[JOINTS][index] in the state), None for a fixed joint."""

    name: str
    kind: str                       # fixed | continuous | prismatic
    parent: str
    child: str
    xyz: tuple                      # origin translation in the parent frame, m
    rpy: tuple                      # origin rotation (roll, pitch, yaw), rad
    axis: tuple | None              # unit axis in the child frame (None when fixed)
    index: int | None


class Transform(NamedTuple):
    """parent → child: the child frame's origin (m) and orientation (unit quaternion x, y, z, w)
    expressed in the parent frame, as geometry_msgs/TransformStamped carries them."""

    parent: str
    child: str
    translation: tuple
    rotation: tuple


def quaternion_multiply(a, b) -> tuple:
    """The Hamilton product a ⊗ b of (x, y, z, w) quaternions (the rotation a then b, in a's
    frame: R(a ⊗ b) = R(a) R(b))."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


def axis_quaternion(axis, angle: float) -> tuple:
    """The turn by ``angle`` (rad) about the unit ``axis``."""
    s = math.sin(0.5 * angle)
    return (axis[0] * s, axis[1] * s, axis[2] * s, math.cos(0.5 * angle))


def rpy_quaternion(roll: float, pitch: float, yaw: float) -> tuple:
    """The URDF rotation Rz(yaw)·Ry(pitch)·Rx(roll) (`model.rpy_matrix`) as a quaternion."""
    return quaternion_multiply(quaternion_multiply(axis_quaternion((0.0, 0.0, 1.0), yaw),
                                                   axis_quaternion((0.0, 1.0, 0.0), pitch)),
                               axis_quaternion((1.0, 0.0, 0.0), roll))


def _joints(model: RobotModel, root: str) -> list[Joint]:
    base = model.base
    names = model.joint_names()
    zero = (0.0, 0.0, 0.0)
    joints = [Joint("base_footprint_joint", "fixed", root, BASE_LINK,
                    (0.0, 0.0, float(base.wheel_radius)), zero, None, None)]
    for index, (side, sign) in enumerate(WHEELS):
        joints.append(Joint(names[index], "continuous", BASE_LINK, f"{side}_wheel",
                            (0.0, sign * float(base.half_track), 0.0), zero, (0.0, 1.0, 0.0),
                            index))
    parent, xyz = BASE_LINK, tuple(map(float, model.mount))
    for k in range(1, model.n_links + 1):   # the arm's joints are indexed as u
        link, rod, turn, slide = f"arm_link_{k}", f"arm_rod_{k}", u_turn(k), u_slide(k)
        joints.append(Joint(names[turn], "continuous", parent, link, xyz,
                            tuple(map(float, model.joint_rpy[k - 1])), (0.0, 0.0, 1.0), turn))
        joints.append(Joint(names[slide], "prismatic", link, rod, zero, zero,
                            (1.0, 0.0, 0.0), slide))
        parent, xyz = rod, zero
    joints.append(Joint("tip_joint", "fixed", parent, TIP, xyz, zero, None, None))
    return joints


class FrameTree:
    """The frames of one robot (see the module docstring): ``joints`` in URDF order, parents
    before children; transforms at a configuration q = (x, y, yaw, θ_R, θ_L, q_1, l_1, …)."""

    def __init__(self, model: RobotModel, root: str = FOOTPRINT, prefix: str = ""):
        self.prefix = prefix
        self.root = root
        self.joints = _joints(model, root)
        self.fixed = [joint for joint in self.joints if joint.index is None]
        self.moving = [joint for joint in self.joints if joint.index is not None]
        self._origins = {joint.name: rpy_quaternion(*joint.rpy) for joint in self.joints}

    def frame(self, name: str) -> str:
        """The published name of frame ``name`` (the one place the prefix is applied)."""
        return self.prefix + name

    @property
    def links(self) -> list[str]:
        """Every frame of the robot (bare names), the root first."""
        return [self.root] + [joint.child for joint in self.joints]

    def transform(self, joint: Joint, value: float = 0.0) -> Transform:
        """parent → child of ``joint`` at ``value`` (rad or m; ignored for a fixed joint)."""
        rotation, translation = self._origins[joint.name], joint.xyz
        if joint.kind == "continuous":
            rotation = quaternion_multiply(rotation, axis_quaternion(joint.axis, value))
        elif joint.kind == "prismatic":   # origin rotations of the slides are identities
            translation = tuple(t + a * value for t, a in zip(translation, joint.axis, strict=True))
        return Transform(self.frame(joint.parent), self.frame(joint.child), translation, rotation)

    def static_transforms(self) -> list[Transform]:
        """Every fixed joint (what /tf_static carries, in one message)."""
        return [self.transform(joint) for joint in self.fixed]

    def moving_transforms(self, q) -> list[Transform]:
        """Every moving joint at configuration ``q`` (what /tf carries besides the base)."""
        positions = q[JOINTS]
        return [self.transform(joint, float(positions[joint.index])) for joint in self.moving]

    def base_transform(self, q, odom: str = ODOM) -> Transform:
        """``odom`` → root: the base's planar pose (x, y, yaw) on the floor."""
        return Transform(self.frame(odom), self.frame(self.root), (float(q[X]), float(q[Y]), 0.0),
                         axis_quaternion((0.0, 0.0, 1.0), float(q[YAW])))
