"""The one place where simulator state becomes ROS messages (the node publishes them, the
recorder stores them, replay rebuilds them to compare): equal states give equal messages.

Topics, types and QoS: topics.py (meaning: docs/node.md).

Stamps are integer nanoseconds of simulated time. ``state`` is anything with the engine's state
interface (``q``, ``u``, ``qdot()``, ``wheel_efforts``, ``joint_efforts``): a ``Simulation``.
"""
from __future__ import annotations

import math

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Quaternion, Twist
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64MultiArray, String

# Stamps come from the time line (timeline.py); topic names, types and QoS live in topics.py,
# re-exported here for the message builders' users.
from ..runtime.timeline import NS  # noqa: F401
from ..scene.coordinates import JOINTS, OMEGA, YAW, V, X, Y
from ..scene.errors import UserError
from .cdr import tf_message_cdr
from .frames import FOOTPRINT, ODOM
from .topics import (  # noqa: F401
    ARM_TOPIC,
    CLOCK_TOPIC,
    CMD_VEL_TOPIC,
    COMMAND_QOS_DEPTH,
    COMMAND_TOPICS,
    JOINT_STATES_TOPIC,
    ODOM_TOPIC,
    STATE_QOS_DEPTH,
    STATE_TOPICS,
    TOPIC_TYPES,
    WHEEL_TOPIC,
)

# Ground truth from the model: a planar model knows z, roll and pitch exactly (all zero), so all
# six pose and twist dimensions are known. A small positive diagonal rather than 0 keeps the
# matrices invertible for filters (robot_localization rejects all-zero covariances).
GROUND_TRUTH_VARIANCE = 1e-9
GROUND_TRUTH_COVARIANCE = [GROUND_TRUTH_VARIANCE if i % 7 == 0 else 0.0 for i in range(36)]


def time_msg(ns: int) -> Time:
    return Time(sec=ns // NS, nanosec=ns % NS)


def yaw_quaternion(yaw: float) -> Quaternion:
    return Quaternion(x=0.0, y=0.0, z=math.sin(0.5 * yaw), w=math.cos(0.5 * yaw))


def quaternion_yaw(quaternion) -> float:
    """The yaw of a rotation about z (the inverse of ``yaw_quaternion``, up to 2π)."""
    return 2.0 * math.atan2(quaternion.z, quaternion.w)


def applied_efforts(state) -> list[float]:
    """[τ_R, τ_L, τ_1, F_1, …]: the efforts the engine holds (after effort limits); in
    velocity mode the wheel torques the speed loop applies now."""
    wheels = state.wheel_torques() if hasattr(state, "wheel_torques") else state.wheel_efforts
    joints = (state.joint_efforts_applied() if hasattr(state, "joint_efforts_applied")
              else state.joint_efforts)   # an arm controller's output, or the commanded efforts
    return list(map(float, wheels)) + [float(v) for v in joints]


def joint_state(state, stamp: int, names, efforts=None) -> JointState:
    """Wheels and arm joints: positions (θ_R, θ_L, q_i, l_i), their rates, and the efforts
    (default: the ones the engine holds, i.e. those of the segment that ended at ``stamp``)."""
    message = JointState()
    message.header.stamp = time_msg(stamp)
    message.name = list(names)
    message.position = state.q[JOINTS].tolist()
    message.velocity = state.qdot()[JOINTS].tolist()
    message.effort = [float(v) for v in (applied_efforts(state) if efforts is None else efforts)]
    return message


def odometry(state, stamp: int, odom_frame: str = ODOM,
             base_frame: str = FOOTPRINT) -> Odometry:
    """Pose of ``base_frame`` (x, y, yaw) in ``odom_frame``; twist in ``base_frame``
    (linear.x = v, angular.z = ω)."""
    q, u = state.q, state.u
    message = Odometry()
    message.header.stamp = time_msg(stamp)
    message.header.frame_id = odom_frame
    message.child_frame_id = base_frame
    message.pose.pose.position.x = float(q[X])
    message.pose.pose.position.y = float(q[Y])
    message.pose.pose.orientation = yaw_quaternion(float(q[YAW]))
    message.pose.covariance = GROUND_TRUTH_COVARIANCE
    message.twist.twist.linear.x = float(u[V])
    message.twist.twist.angular.z = float(u[OMEGA])
    message.twist.covariance = GROUND_TRUTH_COVARIANCE
    return message


def clock(stamp: int) -> Clock:
    return Clock(clock=time_msg(stamp))


def float64_array(values) -> Float64MultiArray:
    """An effort command as the effort controllers take it."""
    return Float64MultiArray(data=[float(v) for v in values])


def twist(values) -> Twist:
    """A base velocity command (v m/s, ω rad/s) as cmd_vel carries it."""
    message = Twist()
    message.linear.x, message.angular.z = float(values[0]), float(values[1])
    return message


def command_message(topic: str, values):
    """The message of a command topic carrying ``values`` (as applied)."""
    return twist(values) if topic == CMD_VEL_TOPIC else float64_array(values)


def command_values(topic: str, message) -> list[float]:
    """The values of a command message (the inverse of ``command_message``)."""
    if topic == CMD_VEL_TOPIC:
        return [message.linear.x, message.angular.z]
    return list(message.data)


def state_messages(state, stamp: int, names, odom_frame: str = ODOM,
                   base_frame: str = FOOTPRINT) -> dict:
    """Topic → message for /joint_states, /odom and /clock, all stamped ``stamp``."""
    return {JOINT_STATES_TOPIC: joint_state(state, stamp, names),
            ODOM_TOPIC: odometry(state, stamp, odom_frame, base_frame),
            CLOCK_TOPIC: clock(stamp)}


# --- what a viewer draws (frames.py's tree) and the IMU ----------------------------------------

def tf_cdr(tree, q, stamp: int, odom_frame: str = ODOM, moving: bool = True) -> bytes:
    """/tf at configuration ``q``: odom_frame → the tree's root, then (``moving``) every moving
    joint, all stamped ``stamp``; the exact CDR of the TFMessage (`cdr.tf_message_cdr`)."""
    transforms = [tree.base_transform(q, odom_frame)]
    if moving:
        transforms += tree.moving_transforms(q)
    return tf_message_cdr(stamp, transforms)


def tf_static_cdr(tree, stamp: int) -> bytes:
    """/tf_static: every fixed joint in ONE message (a late joiner gets only the last one)."""
    return tf_message_cdr(stamp, tree.static_transforms())


def description(urdf: str) -> String:
    return String(data=urdf)


def imu(reading, stamp: int, frame_id: str, noise) -> Imu:
    """sensor_msgs/Imu of an `imu.ImuReading`; covariances: the noise settings' σ² per axis
    (at least GROUND_TRUTH_VARIANCE, as for every exactly known quantity), orientation exact."""
    message = Imu()
    message.header.stamp = time_msg(stamp)
    message.header.frame_id = frame_id
    x, y, z, w = reading.orientation
    message.orientation.x, message.orientation.y = x, y
    message.orientation.z, message.orientation.w = z, w
    message.orientation_covariance = _diagonal((0.0, 0.0, 0.0))
    for field in ("angular_velocity", "linear_acceleration"):
        vector = getattr(message, field)
        vector.x, vector.y, vector.z = getattr(reading, field)
        setattr(message, f"{field}_covariance", _diagonal(noise.variances(field)))
    return message


def _diagonal(variances) -> list[float]:
    values = [0.0] * 9
    for i, variance in enumerate(variances):
        values[4 * i] = max(float(variance), GROUND_TRUTH_VARIANCE)
    return values


def energy(state) -> Float64MultiArray:
    """[T, V, T + V] in J at the state (``state.dynamics.energy``)."""
    T, V = state.dynamics.energy(state.q, state.u)
    return float64_array([T, V, T + V])


# --- the arm controllers' commands as a bag records them (topics.ARM_COMMAND_TOPICS) -----------

def joint_trajectory(trajectory, names, stamp: int):
    """trajectory_msgs/JointTrajectory of a `trajectory_goals.Trajectory` (joints ``names``, the
    node's order; times in ns, exact as Durations), stamped ``stamp`` (when it applied)."""
    from builtin_interfaces.msg import Duration
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    message = JointTrajectory(joint_names=list(names))
    message.header.stamp = time_msg(stamp)
    for i, t in enumerate(trajectory.times):
        point = JointTrajectoryPoint(positions=trajectory.positions[i].tolist())
        for field in ("velocities", "accelerations"):
            rows = getattr(trajectory, field)
            if rows is not None:
                setattr(point, field, rows[i].tolist())
        point.time_from_start = Duration(sec=int(t) // NS, nanosec=int(t) % NS)
        message.points.append(point)
    return message


def trajectory_values(message):
    """The `trajectory_goals.Trajectory` of a recorded JointTrajectory (the inverse of
    ``joint_trajectory``): columns in the message's joint order."""
    import numpy as np

    from .trajectory_goals import Trajectory

    points, n = message.points, len(message.joint_names)
    times = np.array([p.time_from_start.sec * NS + p.time_from_start.nanosec for p in points],
                     dtype=np.int64)

    def rows(field):
        values = [list(getattr(p, field)) for p in points]
        if points and field != "positions" and not any(values):
            return None
        for i, row in enumerate(values):   # a damaged bag: one line, not numpy's error
            if len(row) != n:
                raise UserError(f"recorded trajectory point {i}",
                                f"{len(row)} {field} for {n} joints")
        return np.array(values, dtype=float).reshape(-1, n)
    return Trajectory(times, rows("positions"), rows("velocities"), rows("accelerations"))


def arm_command_message(mode: str, command, names, stamp: int):
    """The recorded message of an arm controller's command (`timeline.apply_arm_command`)."""
    from ..scene.arm_controller import MODES
    return float64_array(command) if MODES[mode].array else joint_trajectory(command, names, stamp)


def arm_command_values(mode: str, message):
    """The command of a recorded arm message (the inverse of ``arm_command_message``)."""
    from ..scene.arm_controller import MODES
    return list(message.data) if MODES[mode].array else trajectory_values(message)
