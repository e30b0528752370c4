"""`simulator`: the ROS 2 node — effort commands in, joint states, odometry and /clock out.

    ros2 run mobile_manip_sim simulator [--ros-args --params-file config/simulator.params.yaml]

A thin adapter around `Simulation` (no physics here). Interface (node name `mobile_manip_sim`):

Subscriptions (ros2_control effort-controller convention, ``std_msgs/Float64MultiArray``)
  /wheel_effort_controller/commands  [tau_R, tau_L] (N·m)
  /arm_effort_controller/commands    [tau_1, F_1, ..., tau_n, F_n] (N·m revolute, N prismatic)
Publications, stamped with the simulated time of the state they carry
  /joint_states        sensor_msgs/JointState: right_wheel_joint, left_wheel_joint,
                       arm_revolute_i, arm_prismatic_i; position (θ_R, θ_L, q_i, l_i), velocity
                       (their time derivatives), effort = the efforts applied during the segment
                       that ended at the stamp (after the scene's effort limits, if any)
  /odom                nav_msgs/Odometry: pose of base_link (x, y, yaw) in odom; twist in
                       base_link (linear.x = v, angular.z = ω; the wheel axis does not slip, so
                       linear.y = 0); covariances: see messages.GROUND_TRUTH_VARIANCE
  /clock               rosgraph_msgs/Clock, for nodes running with use_sim_time
  /robot_description   std_msgs/String (URDF), transient local, depth 1: at start and on reset
  /tf                  tf2_msgs/TFMessage: odom_frame → base_frame (base_footprint, on the
                       ground under the axle midpoint) at every publication, when tf2_msgs imports
Every topic name above is RELATIVE (topics.py): __ns:=/robot1 puts them all under /robot1.
base_command velocity: /cmd_vel (geometry_msgs/Twist, or TwistStamped with cmd_vel_stamped)
replaces the wheel topic; the engine's wheel-speed PI loop turns it into wheel torques.
Services
  ~/reset  std_srvs/Trigger   back to the scene's initial state, t = 0, efforts zero
  ~/pause  std_srvs/SetBool   true: time and /clock stand still; false: resume
  ~/step   std_srvs/Trigger   while paused: compute and publish the next state, then answer
Synchronous mode (parameter synchronous): the first state waits for a state subscriber and a
command publisher; segment k is computed only once a new command has arrived on every command
topic with a publisher after state k went out (or sync_timeout wall seconds passed).

Timing. Publication k carries the state at simulated time t_k = k / publish_rate; its stamp is
computed from the integer k in integer nanoseconds (exactly k·10⁹/rate when that is an integer,
otherwise rounded to the nearest ns without accumulating), so stamps never drift, skip or repeat.
One stepping thread owns the engine: for each k it takes the latest valid commands (zero-order
hold: a command that arrives during a segment takes effect at the start of the next one),
advances the engine to t_{k+1}, waits until the wall clock reaches
start_wall + t_{k+1} / real_time_factor, then publishes. Computing before waiting keeps the
compute time out of the publication jitter. The first publication (k = 0) is the initial state.
If the node falls behind the wall clock it says so (throttled, with the measured real-time
factor) and re-anchors its pacing instead of bursting to catch up. The executor (subscriptions,
services, parameters) runs in the main thread and never waits for the engine: ~/pause and
~/reset set flags under a lock that also guards every publication, so once they have answered
nothing more of the old time line goes out (a segment computed across a pause is published after
the resume; one computed across a reset is dropped). State topics are reliable, depth 100.
`real_time_factor` and `command_timeout` can be changed while running; the others are read-only.

The node starts with ZERO efforts, not the scene's `efforts:` (those are for headless runs): a
robot should not move before someone commands it. Commands older than `command_timeout` seconds
of simulated time fall to zero, one warning per timeout, re-armed by the next command.

Bad input never stops the node: a command of the wrong length or with NaN/Inf is rejected with a
throttled warning naming the topic and the problem, and the last valid command stays. If the
engine's state becomes non-finite the node logs the error and pauses; ~/reset recovers. A missing
or invalid scene or parameter at start-up is one line on stderr and exit status 2.

Recording (parameter `record` = a new bag directory): a rosbag2 MCAP bag of /joint_states, /odom
and /clock as published and of both command topics as applied (the efforts held from a segment
start on, after timeout and limits: at t = 0 and whenever they change), every record stamped
with its simulated time; plus the scene, the integrator settings and the impact log
(recording/recorder.py). SIGINT/SIGTERM close it (summary, metadata.yaml); a SIGKILL loses at
most the open chunk, about a second of wall time. A bag holds one time line: after ~/reset it
is closed and recording goes on in `<record>_1`, `<record>_2`, ... An unusable `record` path at
start-up is a one-line error and exit status 2; a write failure while running (a full disk) is
one error line, recording stops, the simulation goes on.

Odometry covariances: this is ground truth from the model, and a planar model knows z, roll and
pitch exactly (all zero), so every one of the six dimensions is "known": the diagonals of
pose.covariance and twist.covariance are GROUND_TRUTH_VARIANCE (1e-9 in m², rad², (m/s)²,
(rad/s)²) and every off-diagonal entry is 0. A small positive diagonal rather than 0 keeps the
matrices invertible for filters (robot_localization rejects all-zero covariances).
"""
from __future__ import annotations

import math
import re
import sys
import threading
import time
from fractions import Fraction
from typing import TYPE_CHECKING

import numpy as np
import rclpy
import rclpy.logging
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import SetBool, Trigger

from . import cli
from .engine.simulation import DEFAULT_WHEEL_SPEED_GAINS, Simulation, SimulationError
from .errors import UserError
from .messages import NS, stamp_ns, state_messages, transform
from .scene import METHODS, load_scene, make_integrator
from .topics import (ARM_TOPIC, CLOCK_TOPIC, CMD_VEL_TOPIC, DESCRIPTION_TOPIC, JOINT_STATES_TOPIC, ODOM_TOPIC,
                     TF_TOPIC, WHEEL_TOPIC, command_qos, latched_qos, relative, state_qos)
from .urdf import robot_description

if TYPE_CHECKING:   # imported when a bag is opened: mcap and the CDR tables only when recording
    from .recording.recorder import RunRecorder

NODE_NAME = "mobile_manip_sim"
WARN_EVERY = 5.0           # s of wall time between repeats of one kind of warning
LAG_TOLERANCE = 0.1        # s behind the wall clock before the node says it cannot keep up
BAG_FLUSH_INTERVAL = 1.0   # s of wall time: the most of a recording a SIGKILL may lose
SHUTDOWN_POLL = 0.2        # s: how often the executor checks for an external shutdown
STEP_TIMEOUT = 30.0        # s of wall time a ~/step call waits for its state
STOP_TIMEOUT = 2.0         # s of wall time shutdown waits for the stepping thread
MAX_PARAMS_FILE = 1 << 20  # bytes: a parameters file larger than this is refused
PEER_POLL = 0.01           # s: synchronous start-up checks for peers this often


def _float_range(low: float, high: float) -> list[FloatingPointRange]:
    return [FloatingPointRange(from_value=low, to_value=high, step=0.0)]


# name: (default, description, range or None, changeable at run time)
PARAMETERS = {
    "scene": ("", "Scene YAML file; empty = the embedded paper scene.", None, False),
    "publish_rate": (100.0, "Publications per second of SIMULATED time (Hz).",
                     _float_range(0.001, 100000.0), False),
    "real_time_factor": (1.0, "Simulated seconds per wall second; 0 = as fast as possible.",
                         _float_range(0.0, 10000.0), True),
    "command_timeout": (0.5, "Seconds of SIMULATED time after the last command of a group "
                             "(wheels, arm) before its efforts fall to zero; 0 disables.",
                        _float_range(0.0, 1.0e6), True),
    "odom_frame": ("odom", "frame_id of /odom and parent frame of /tf.", None, False),
    "base_frame": ("base_footprint", "child_frame_id of /odom and /tf, and the URDF's root: the "
                                     "frame on the ground under the axle midpoint (base_link "
                                     "is fixed at wheel-radius height above it).", None, False),
    "publish_tf": (True, "Publish odom_frame → base_frame on tf at the publication rate "
                         "(needs tf2_msgs).", None, False),
    "record": ("", "Record a rosbag2 (MCAP) bag to this new directory; empty = off.", None,
               False),
    "synchronous": (False, "Lockstep: after publishing state k, compute segment k only once a "
                           "new command has arrived (or sync_timeout has passed); the first "
                           "state waits for a state subscriber and a command publisher.", None,
                    False),
    "base_command": ("effort", "effort: the wheels take torques from wheel_effort_controller/"
                               "commands; velocity: the base takes cmd_vel, turned into wheel "
                               "torques by a wheel-speed PI loop inside the simulated system.",
                     None, False),
    "cmd_vel_stamped": (False, "Velocity mode: cmd_vel is geometry_msgs/TwistStamped (as Jazzy's "
                               "diff_drive_controller takes it) rather than Twist.", None, False),
    "wheel_speed.kp": (DEFAULT_WHEEL_SPEED_GAINS[0], "Velocity mode: proportional gain of the "
                       "wheel-speed loop (N·m·s/rad).", _float_range(0.0, 1.0e6), False),
    "wheel_speed.ki": (DEFAULT_WHEEL_SPEED_GAINS[1], "Velocity mode: integral gain of the "
                       "wheel-speed loop (N·m/rad).", _float_range(0.0, 1.0e6), False),
    "sync_timeout": (1.0, "Synchronous mode: wall seconds to wait for a command before holding "
                          "the last one (and saying so).", _float_range(0.001, 3600.0), False),
    "integrator.method": ("", f"Integrator overriding the scene's ({', '.join(METHODS)}); "
                              "empty = the scene's.", None, False),
    "integrator.dt": (0.0, "Fixed step (s) overriding the scene's; 0 = the scene's.",
                      _float_range(0.0, 1.0), False),
    "integrator.rtol": (0.0, "Relative tolerance overriding the scene's; 0 = the scene's.",
                        _float_range(0.0, 1.0), False),
    "integrator.atol": (0.0, "Absolute tolerance overriding the scene's; 0 = the scene's.",
                        _float_range(0.0, 1.0), False),
}


# --- pure helpers (no rclpy state: testable on their own) ---------------------------------

def command_problem(values, expected: int, labels: str) -> tuple[str, str] | None:
    """(kind, explanation) of why `values` is not a valid command of `expected` numbers, or
    None when it is one. `kind` ("length", "NaN", "Inf", "NaN and Inf") keys the throttling."""
    if len(values) != expected:
        return "length", f"expected {expected} values ({labels}), got {len(values)}"
    bad = [(i, v) for i, v in enumerate(values) if not math.isfinite(v)]
    if bad:
        kind = " and ".join(sorted({"NaN" if math.isnan(v) else "Inf" for _, v in bad},
                                   reverse=True))
        where = ", ".join(f"[{i}] = {v}" for i, v in bad)
        return kind, f"contains {kind} ({where})"
    return None


def format_ns(ns: int) -> str:
    return f"{'-' if ns < 0 else ''}{abs(ns) // NS}.{abs(ns) % NS:09d}"


class _CommandGroup:
    """The latest valid command of one topic and when it arrived (simulated ns)."""

    def __init__(self, topic: str, size: int, labels: str, what: str):
        self.topic, self.size, self.labels, self.what = topic, size, labels, what
        self.seq = 0             # valid commands received, ever (synchronous mode)
        self.seq_published = 0   # seq when the latest state went out
        self.clear()

    def clear(self) -> None:
        self.values = np.zeros(self.size)
        self.received_ns: int | None = None
        self.timed_out = False


class SimulatorNode(Node):
    """The scene's simulation behind ROS topics; see the module docstring for the interface."""

    def __init__(self, **node_options):
        super().__init__(NODE_NAME, **node_options)
        self._declare_parameters()
        self._reject_unknown_parameters()
        p = self._read_parameters()
        scene = load_scene(p["scene"] or None)
        settings = make_integrator(scene.integrator, p["integrator.method"] or None,
                                   p["integrator.dt"] or None, p["integrator.rtol"] or None,
                                   p["integrator.atol"] or None, prefix="integrator")
        self.scene = scene
        self.sim = Simulation(scene, settings)
        self.joint_names = scene.robot.joint_names()
        n_joints = len(self.joint_names) - 2
        self.rate = Fraction(p["publish_rate"])
        self.real_time_factor = p["real_time_factor"]
        self.command_timeout_ns = round(p["command_timeout"] * NS)
        self.odom_frame, self.base_frame = p["odom_frame"], p["base_frame"]
        for name in ("odom_frame", "base_frame"):
            if not p[name] or p[name] == "base_link" or p["odom_frame"] == p["base_frame"]:
                raise UserError(name, f"{p[name]!r}: frame names must be non-empty, distinct, "
                                      f"and not base_link (the URDF's body frame)")
        self.record = p["record"]
        self.synchronous, self.sync_timeout = p["synchronous"], p["sync_timeout"]
        if p["base_command"] not in ("effort", "velocity"):
            raise UserError("base_command", f"{p['base_command']!r} is not effort or velocity")
        self.velocity_mode = p["base_command"] == "velocity"
        self.sim.set_wheel_speed_gains(p["wheel_speed.kp"], p["wheel_speed.ki"])
        self._settings = settings
        self._recorder: RunRecorder | None = None
        self._recorded_stamp: int | None = None   # last state stamp in the open bag
        self._bag_count = 0

        arm_labels = ", ".join(f"tau_{i}, F_{i}" for i in range(1, n_joints // 2 + 1)) or "none"
        self._wheels = _CommandGroup(WHEEL_TOPIC, 2, "tau_R, tau_L", "wheel")
        self._arm = _CommandGroup(ARM_TOPIC, n_joints, arm_labels, "arm")
        self._cmd_vel = _CommandGroup(CMD_VEL_TOPIC, 2, "v, omega", "base velocity")
        self._command_lock = threading.Lock()      # guards the two _CommandGroup
        self._warned_at: dict[tuple, float] = {}    # throttle: (topic, kind) → wall time

        # Stepping state: the stepping thread owns the engine; services only set flags (_cv).
        self._cv = threading.Condition()
        self._k = 0                  # index of the latest published state
        self._now_ns = 0             # its stamp: simulated time at the start of the open segment
        self._pending = None         # (k + 1, messages) computed, waiting for its wall time
        self._paused = False
        self._steps = 0              # ~/step requests not yet published
        self._failed: str | None = None
        self._reset_requested = False
        self._stopping = False
        self._anchor = (time.monotonic(), 0)   # (wall s, simulated ns) pacing origin
        self._window = self._anchor            # start of the real-time-factor measurement

        # Relative names: a namespace (__ns:=/robot1) or a remap moves every topic.
        self._state_pubs = {
            topic: self.create_publisher(kind, relative(topic), state_qos())
            for topic, kind in ((JOINT_STATES_TOPIC, JointState), (ODOM_TOPIC, Odometry),
                                (CLOCK_TOPIC, Clock))}
        self._tf_pub = self._tf_publisher() if p["publish_tf"] else None
        self._description_pub = self.create_publisher(String, relative(DESCRIPTION_TOPIC),
                                                      latched_qos())
        self._description = robot_description(scene, root=self.base_frame)
        self._command_subs = [
            self.create_subscription(Float64MultiArray, relative(topic),
                                     lambda msg, group=group: self._on_command(group, msg),
                                     command_qos())
            for topic, group in ((WHEEL_TOPIC, self._wheels), (ARM_TOPIC, self._arm))
            if not (self.velocity_mode and topic == WHEEL_TOPIC)]
        if self.velocity_mode:
            self._command_subs.insert(0, self._cmd_vel_subscription(p["cmd_vel_stamped"]))
        # in _command_groups() order: answered() pairs them up
        self.create_service(Trigger, "~/reset", self._on_reset)
        self.create_service(SetBool, "~/pause", self._on_pause)
        self.create_service(Trigger, "~/step", self._on_step)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        self._reset_state()
        self._thread = threading.Thread(target=self._run, name="stepping", daemon=True)
        if self.record:   # last: nothing after this may fail and leave an unfinished bag
            try:
                self._recorder = self._open_bag(self.record)
            except UserError as error:
                raise UserError("record", str(error)) from None
        self.get_logger().info(
            f"scene '{scene.name}', integrator {settings.method} "
            f"({'dt ' + str(settings.dt) if settings.fixed_step else f'rtol {settings.rtol}'}), "
            f"publishing at {float(self.rate):g} Hz of simulated time, real-time factor "
            f"{self.real_time_factor:g}{' (free-running)' if self.real_time_factor == 0 else ''}")
        if p["publish_tf"] and self._tf_pub is None:
            self.get_logger().warning(
                "publish_tf: tf2_msgs does not import (source a ROS install, or build it with "
                "tools/build_tf2_msgs.sh); no /tf")

    # --- parameters ------------------------------------------------------------------------
    def _declare_parameters(self) -> None:
        for name, (default, description, floats, dynamic) in PARAMETERS.items():
            descriptor = ParameterDescriptor(description=description, read_only=not dynamic)
            if floats:
                descriptor.floating_point_range = floats
            try:
                self.declare_parameter(name, default, descriptor)
            except InvalidParameterTypeException:
                kind = ("true or false" if isinstance(default, bool)
                        else "a floating-point number (write 1.0, not 1)"
                        if isinstance(default, float) else "a string")
                raise UserError(name, f"expected {kind}") from None
            except InvalidParameterValueException:
                override = self._parameter_overrides.get(name)
                value = override.value if override is not None else default
                raise UserError(name, f"{value} is outside [{floats[0].from_value:g}, "
                                      f"{floats[0].to_value:g}]") from None

    def _reject_unknown_parameters(self) -> None:
        """A parameter given for this node that it does not declare is a mistake (a typo such
        as real_time_facter would otherwise be silently ignored)."""
        unknown = sorted(set(self._parameter_overrides) - set(self._parameters))
        if unknown:
            raise UserError(unknown[0], f"unknown parameter of {NODE_NAME} (known: "
                                        f"{', '.join(PARAMETERS)})")

    def _read_parameters(self) -> dict:
        values = {name: self.get_parameter(name).value for name in PARAMETERS}
        for name, value in values.items():
            if isinstance(value, float) and not math.isfinite(value):
                raise UserError(name, f"must be finite, got {value}")
        return values

    def _validate_parameters(self, parameters) -> SetParametersResult:
        for parameter in parameters:
            if isinstance(parameter.value, float) and not math.isfinite(parameter.value):
                return SetParametersResult(successful=False,
                                           reason=f"{parameter.name} must be finite")
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters) -> None:
        with self._cv:
            for parameter in parameters:
                if parameter.name == "real_time_factor":
                    self.real_time_factor = parameter.value
                    self._reanchor()
                elif parameter.name == "command_timeout":
                    self.command_timeout_ns = round(parameter.value * NS)
            self._cv.notify_all()

    # --- commands (executor thread) --------------------------------------------------------
    def _on_command(self, group: _CommandGroup, msg: Float64MultiArray) -> None:
        values = msg.data
        problem = command_problem(values, group.size, group.labels)
        if problem:
            kind, text = problem
            self._warn_throttled((group.topic, kind),
                                 f"{group.topic}: {text}; keeping the last valid command")
            return
        with self._command_lock:
            group.values = np.array(values, dtype=float)
            group.received_ns = self._now_ns
            group.timed_out = False
            group.seq += 1
        if self.synchronous:
            with self._cv:
                self._cv.notify_all()

    def _cmd_vel_subscription(self, stamped: bool):
        from geometry_msgs.msg import Twist, TwistStamped

        def on_twist(msg):
            twist = msg.twist if stamped else msg
            self._on_command(self._cmd_vel, Float64MultiArray(
                data=[twist.linear.x, twist.angular.z]))
        return self.create_subscription(TwistStamped if stamped else Twist,
                                        relative(CMD_VEL_TOPIC), on_twist, command_qos())

    def _command_groups(self) -> tuple:
        """The groups that command the run: wheels or cmd_vel, then the arm."""
        return (self._cmd_vel if self.velocity_mode else self._wheels, self._arm)

    def _held_efforts(self, segment_start_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """The base command (wheel torques, or [v, ω] in velocity mode) and the arm efforts to
        hold from segment_start_ns on, after the command timeout (a stale cmd_vel is zero
        speed)."""
        with self._command_lock:
            for group in self._command_groups():
                stale = (self.command_timeout_ns > 0 and group.received_ns is not None
                         and not group.timed_out
                         and segment_start_ns - group.received_ns >= self.command_timeout_ns)
                if stale:
                    group.values = np.zeros(group.size)
                    group.timed_out = True
                    self.get_logger().warning(
                        f"{group.topic}: no command for {self.command_timeout_ns / NS:g} s of "
                        f"simulated time (command_timeout); {group.what} efforts set to zero "
                        f"until commands resume")
            base, arm = self._command_groups()
            return base.values.copy(), arm.values.copy()

    # --- services (executor thread): they set flags; the stepping thread acts on them --------
    def _on_reset(self, request, response):
        with self._command_lock:   # commands sent after this call are kept
            for group in (self._wheels, self._cmd_vel, self._arm):
                group.clear()
        with self._cv:
            self._reset_requested = True
            self._cv.notify_all()
        # From here on nothing of the old run is published: the next state out is t = 0.
        self.get_logger().info("reset to the initial state, t = 0")
        response.success, response.message = True, "reset to the initial state at t = 0"
        return response

    def _on_pause(self, request, response):
        with self._cv:
            now = format_ns(self._now_ns)
            if request.data:
                response.message = f"{'already ' if self._paused else ''}paused at t = {now} s"
                self._paused = True
                response.success = True
            elif self._failed:
                response.success = False
                response.message = (f"cannot resume: the simulation failed ({self._failed}); "
                                    f"call ~/reset")
            else:
                response.message = f"{'resumed' if self._paused else 'running'} at t = {now} s"
                if self._paused:
                    self._paused = False
                    self._steps = 0
                    self._reanchor()
                response.success = True
            self._cv.notify_all()
        self.get_logger().info(response.message)
        return response

    def _on_step(self, request, response):
        """While paused: publish the next state (one period on), then answer."""
        with self._cv:
            if not self._paused or self._failed:
                response.success = False
                response.message = (f"cannot step: the simulation failed ({self._failed}); call "
                                    f"~/reset" if self._failed else
                                    "not paused: call ~/pause (true) first, then ~/step")
                return response
            self._steps += 1
            target = self._k + self._steps
            self._cv.notify_all()
            done = self._cv.wait_for(lambda: self._k >= target or self._failed or self._stopping
                                     or self._reset_requested or not self._paused,
                                     timeout=STEP_TIMEOUT)
            response.success = bool(done) and self._k >= target
            response.message = (f"stepped to t = {format_ns(self._now_ns)} s" if response.success
                                else f"step not completed (t = {format_ns(self._now_ns)} s)")
        return response

    def _tf_publisher(self):
        try:
            from tf2_msgs.msg import TFMessage
        except ImportError:
            return None   # said once the node has started (__init__'s last line)
        return self.create_publisher(TFMessage, relative(TF_TOPIC), state_qos())

    # --- stepping thread -------------------------------------------------------------------
    def start(self) -> None:
        """Start the stepping thread: it publishes the description and the initial state (in
        synchronous mode once a state subscriber and a command publisher are there), then
        steps. Nothing is computed here, before the executor spins."""
        self._thread.start()

    def _begin(self) -> bool:
        """The stepping thread's start; False when stopped before it began."""
        if self.synchronous:
            with self._cv:   # graph changes do not notify: poll, woken early by stop()
                while not self._stopping and not self._peers_ready():
                    self._cv.wait(PEER_POLL)
        with self._cv:
            if self._stopping:
                return False
            self._publish_description()
            self._publish(0, self._messages(0))
        if not self.synchronous:
            # The first segment loads the compiled kernels: compute it before pacing starts.
            computed = self._compute_next()
            with self._cv:
                if not self._reset_requested:
                    self._pending = computed
                self._reanchor()
        return True

    def _peers_ready(self) -> bool:
        """Synchronous mode's start condition: someone listens, someone commands."""
        listening = any(pub.get_subscription_count() > 0 for pub in self._state_pubs.values())
        commanding = any(sub.get_publisher_count() > 0 for sub in self._command_subs)
        return listening and commanding

    def _await_command(self) -> None:
        """Synchronous mode, before computing a segment: wait (not holding _cv afterwards) for
        a command newer than the latest published state on every command topic that has a
        publisher (so wheels and arm sent in reply to one state apply together), at most
        sync_timeout wall seconds."""
        def answered() -> bool:
            with self._command_lock:
                fresh = [group.seq != group.seq_published for group in self._command_groups()]
            commanding = [sub.get_publisher_count() > 0 for sub in self._command_subs]
            return any(fresh) and all(f or not c for f, c in zip(fresh, commanding))

        with self._cv:
            arrived = self._cv.wait_for(
                lambda: answered() or self._stopping or self._reset_requested or self._paused,
                timeout=self.sync_timeout)
        if not arrived:
            self._warn_throttled(("sync",), f"synchronous: no command within sync_timeout "
                                            f"{self.sync_timeout:g} s after t = "
                                            f"{format_ns(self._now_ns)} s; holding the last one")

    def stop(self) -> None:
        """Stop the stepping thread (idempotent); nothing is published afterwards."""
        with self._cv:
            self._stopping = True
            self._cv.notify_all()
        if self._thread.is_alive():
            self._thread.join(timeout=STOP_TIMEOUT)
        if self._thread.is_alive():   # inside a long segment: the bag is closed regardless
            rclpy.logging.get_logger(NODE_NAME).warning(
                f"the stepping thread did not stop within {STOP_TIMEOUT:g} s; exiting anyway")

    def _run(self) -> None:
        """The engine's only user once started. _cv guards the flags and every publication, and
        is never held while integrating, so services answer even during a long segment (such
        as one that compiles a kernel); a segment computed across a pause is kept for the
        resume, one computed across a reset is dropped."""
        try:
            if not self._begin():
                return
            while self._step():
                pass
        except Exception:
            if self._stopping or not rclpy.ok(context=self.context):
                return   # the context went down under a publication: shutting down
            raise

    def _step(self) -> bool:
        with self._cv:
            if self._stopping:
                return False
            if self._reset_requested:
                self._reset_state()
                self._publish_description()
                self._publish(0, self._messages(0))
                return True
            if (self._paused and not self._steps) or self._failed:
                self._cv.wait()
                return True
            pending = self._pending
        if pending is None:
            if self.synchronous:
                self._await_command()
                with self._cv:
                    if self._stopping or self._reset_requested or (
                            self._paused and not self._steps):
                        return True
            computed = self._compute_next()   # outside the lock
            with self._cv:
                if not self._reset_requested:
                    self._pending = computed
            return True
        with self._cv:
            if (self._stopping or self._reset_requested or self._failed
                    or (self._paused and not self._steps)):
                return True
            k, messages = pending
            if self._paused:   # a ~/step: publish now, no pacing
                self._steps -= 1
                self._publish(k, messages)
                self._pending = None
                self._cv.notify_all()
                return True
            paced = self.real_time_factor > 0
            delay = self._due(stamp_ns(k, self.rate)) - time.monotonic() if paced else 0.0
            if delay > 0:
                self._cv.wait(delay)   # woken early by pause, reset, parameters or stop
                return True
            if paced:
                self._check_lag(-delay, k)
            self._publish(k, messages)
            self._pending = None
        return True

    def _compute_next(self):
        """Advance the engine over segment k → k + 1; (k + 1, messages), or None on failure."""
        k = self._k
        start_ns = self._now_ns
        base, joints = self._held_efforts(start_ns)
        try:
            if self.velocity_mode:
                self.sim.set_base_velocity(*base)
                self.sim.set_efforts(joints=joints)
            else:
                self.sim.set_efforts(base, joints)
            self._on_command_applied(start_ns, self.sim.wheel_efforts, self.sim.joint_efforts)
            self.sim.advance_to((k + 1) / float(self.rate))
        except (SimulationError, UserError) as error:
            with self._cv:
                self._failed = f"t = {format_ns(start_ns)} s: {error}"
            self.get_logger().error(f"simulation failed in the segment after t = "
                                    f"{format_ns(start_ns)} s: {error}; paused, call ~/reset "
                                    f"to start again")
            return None
        return k + 1, self._messages(k + 1)

    def _due(self, target_ns: int) -> float:
        wall0, ns0 = self._anchor
        return wall0 + (target_ns - ns0) / NS / self.real_time_factor

    def _reanchor(self) -> None:
        self._anchor = (time.monotonic(), self._now_ns)
        self._window = self._anchor

    def _check_lag(self, late: float, k: int) -> None:
        """Behind the wall clock by `late` s: warn (throttled) and pace from here on."""
        period = 1.0 / float(self.rate) / self.real_time_factor
        if late <= max(LAG_TOLERANCE, 5.0 * period):
            return
        wall, ns = time.monotonic(), stamp_ns(k, self.rate)
        wall0, ns0 = self._window
        measured = (ns - ns0) / NS / (wall - wall0) if wall > wall0 else float("nan")
        if self._warn_throttled(("lag",), f"cannot keep up with real_time_factor "
                                          f"{self.real_time_factor:g}: {late:.3f} s behind the "
                                          f"wall clock, measured real-time factor {measured:.2f} "
                                          f"since {format_ns(ns0)} s; simulated time runs slower"):
            self._window = (wall, ns)
        self._anchor = (wall, ns)   # pace on from here rather than burst to catch up

    def _reset_state(self) -> None:
        """Initial state, t = 0, zero efforts. Commands were cleared when the reset was asked
        for; any that arrived since count as received at t = 0."""
        self.sim.reset()
        self.sim.set_efforts(np.zeros(2), np.zeros(self.sim.nu - 2))
        with self._command_lock:
            for group in (self._wheels, self._cmd_vel, self._arm):
                if group.received_ns is not None:
                    group.received_ns = 0
        self._k, self._now_ns, self._pending = 0, 0, None
        self._failed = None
        self._reset_requested = False
        self._steps = 0
        self._reanchor()

    # --- messages --------------------------------------------------------------------------
    def _messages(self, k: int) -> dict:
        """/joint_states, /odom and /clock for the engine's current state, stamped t_k."""
        return state_messages(self.sim, stamp_ns(k, self.rate), self.joint_names,
                              self.odom_frame, self.base_frame)

    def _publish(self, k: int, messages: dict) -> None:
        with self._command_lock:   # before publishing: a reply to this state counts as new
            for group in self._command_groups():
                group.seq_published = group.seq
        published = {}
        try:
            for topic, publisher in self._state_pubs.items():
                publisher.publish(messages[topic])
                published[topic] = messages[topic]
            if self._tf_pub is not None:
                self._tf_pub.publish(transform(messages[ODOM_TOPIC]))
        finally:
            # What went out is recorded, even when a shutdown fails the rest of the group.
            if published:
                self._on_state_published(stamp_ns(k, self.rate), published)
        self._k, self._now_ns = k, stamp_ns(k, self.rate)

    def _publish_description(self) -> None:
        self._description_pub.publish(String(data=self._description))

    def _warn_throttled(self, key: tuple, text: str) -> bool:
        now = time.monotonic()
        last = self._warned_at.get(key)
        if last is not None and now - last < WARN_EVERY:
            return False
        self._warned_at[key] = now
        self.get_logger().warning(text)
        return True

    # --- recording (hooks called by the stepping thread, and _on_close after it stopped) ----
    def _open_bag(self, path: str) -> RunRecorder:
        from .recording.recorder import RunRecorder
        self._bag_count += 1
        self._recorded_stamp = None
        return RunRecorder(path, self.scene, self._settings,
                           {"source": "node", "publish_rate": repr(float(self.rate))},
                           flush_interval=BAG_FLUSH_INTERVAL)

    def _on_state_published(self, stamp_ns: int, messages: dict) -> None:
        """After each publication (stamp 0: the initial state, or the first after a reset).
        A bag holds one time line: after a reset the bag is closed and recording goes on in
        ``<record>_<n>``. The engine is at stamp_ns here, so its impact list is the run's."""
        if self._recorder is None:
            return
        if self._recorded_stamp is not None and stamp_ns <= self._recorded_stamp:
            previous = self._recorder.path
            self._recording(lambda recorder: recorder.close())
            if self._recorder is None:
                return
            self._recorder = None
            try:
                self._recorder = self._open_bag(f"{self.record}_{self._bag_count}")
            except Exception as error:
                self.get_logger().error(f"recording stopped at the reset: {error}")
                return
            self.get_logger().info(f"reset: bag {previous} closed, recording on in "
                                   f"{self._recorder.path}")
        self._recorded_stamp = stamp_ns

        def record(recorder):
            recorder.states(stamp_ns, messages)
            recorder.impacts(self.sim.impacts)
        self._recording(record)

    def _on_command_applied(self, stamp_ns: int, wheels: np.ndarray, joints: np.ndarray) -> None:
        """At the start of each segment: the efforts held from stamp_ns to the next stamp
        (after timeout and effort limits); the recorder keeps the changes."""
        self._recording(lambda recorder: recorder.commands(stamp_ns, wheels, joints))

    def _on_close(self) -> None:
        """After the stepping thread has stopped, before the node is destroyed (SIGINT,
        SIGTERM, normal exit): the bag gets its impacts, summary and metadata.yaml."""
        if self._recorder is not None:
            path = self._recorder.path
            self._recording(lambda recorder: recorder.close(), self._closing_logger())
            if self._recorder is not None:
                self._recorder = None
                self._closing_logger().info(f"bag {path} closed")

    def _closing_logger(self):
        """The node's logger while its context is up; after SIGINT/SIGTERM shut it down, a
        logger without /rosout (the node's would fail to publish and say so)."""
        if rclpy.ok(context=self.context):
            return self.get_logger()
        return rclpy.logging.get_logger(f"{NODE_NAME}_recording")

    def _recording(self, action, logger=None) -> None:
        """Run ``action(recorder)``; a failure (full disk, ...) is one error line and the end of
        recording, never of the simulation."""
        if self._recorder is None:
            return
        try:
            action(self._recorder)
        except Exception as error:
            recorder, self._recorder = self._recorder, None
            recorder.abandon()
            (logger or self.get_logger()).error(f"recording stopped: {error}; the simulation "
                                                f"goes on without it")


def _check_params_files(argv) -> None:
    """Each --params-file read first by the schema's YAML loader (a regular UTF-8 file within its
    size, nesting, alias-expansion and duplicate-key limits) and refused here in one line: rcl
    would block on a FIFO, expand an alias bomb without end, silently take the last of two
    duplicate keys, or fail with its own multi-line error."""
    from . import schema

    args = list(sys.argv[1:] if argv is None else argv)
    for flag, path in zip(args, args[1:]):
        if flag != "--params-file":
            continue
        what = schema.label(path, 160)
        try:
            text = schema.read_text_file(path, what, limit=MAX_PARAMS_FILE, kind="parameters file")
            schema.load_yaml(text, what=what)
        except UserError as error:
            text = str(error) if error.key == what else f"{what}: {error}"
            raise UserError("--params-file", text) from None


def _init(argv) -> None:
    """rclpy.init; bad --ros-args (a missing or unparsable --params-file, ...) is a UserError."""
    _check_params_files(argv)
    try:
        rclpy.init(args=argv)
    except Exception as error:   # RCLError, whose text names rcl's source lines
        text = re.sub(r",? at /\S+:\d+", "", str(error)).replace("failed to initialize rcl: ", "")
        key = "--params-file" if "params file" in text else "--ros-args"
        raise UserError(key, text.strip()) from None


def _main(argv) -> int:
    _init(argv)
    node = None
    try:
        node = SimulatorNode()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        node.start()
        # spin_once with a timeout rather than spin(): a signal that shuts the context down
        # while the executor is between waits could otherwise leave it waiting forever.
        while rclpy.ok(context=node.context):
            executor.spin_once(timeout_sec=SHUTDOWN_POLL)
    except KeyboardInterrupt:
        pass
    except Exception:
        # ExternalShutdownException, or an RCLError from a wait set or a publication that the
        # context vanished under: SIGINT/SIGTERM (at start-up too) is a normal exit.
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.stop()
            node._on_close()
            try:
                node.destroy_node()
            except Exception:
                if rclpy.ok():
                    raise
        rclpy.try_shutdown()
    return 0


def main(args=None) -> int:
    return cli.run(_main, args)


if __name__ == "__main__":
    raise SystemExit(main())
