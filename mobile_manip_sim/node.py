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

Timing: the run's time line is timeline.py's (the grid of publications, exact integer-ns
stamps, when a command takes effect, the node's start), the pacing pacing.py's; this module only
wires them to ROS. One stepping thread owns the engine: for each k it takes the latest valid
commands (zero-order hold: a command that arrives during a segment takes effect at the start of
the next one), advances the engine to t_{k+1}, waits until the wall clock reaches the pacer's
due time, then publishes. Computing before waiting keeps the compute time out of the
publication jitter. The first publication (k = 0) is the initial state. If the node falls
behind the wall clock it says so (throttled, with the measured real-time factor) and paces on
from there instead of bursting to catch up. Commands are not callbacks: the stepping thread
takes them from the subscriptions when it needs them, latest first, so a flood costs the
middleware (whose keep-last history drops the surplus), not the executor. The executor
(services, parameters) runs in the main thread and never waits for the engine: ~/pause and
~/reset set flags under a lock that also guards every publication, so once they have answered
nothing more of the old time line goes out (a segment computed across a pause is published after
the resume; one computed across a reset is dropped). Recording happens outside that lock, so a
bag rotation never delays a service. State topics are reliable, depth 100.
`real_time_factor` and `command_timeout` can be changed while running; the others are read-only.

The node starts with ZERO efforts, not the scene's `efforts:` (those are for headless runs): a
robot should not move before someone commands it. Commands older than `command_timeout` seconds
of simulated time fall to zero, one warning per timeout, re-armed by the next command.

Bad input never stops the node: a command of the wrong length or with NaN/Inf is rejected with a
throttled warning naming the topic and the problem, and the last valid command stays. If the
engine's state becomes non-finite the node logs the error and pauses; ~/reset recovers. A missing
or invalid scene or parameter at start-up is one line on stderr and exit status 2.

Recording (parameter `record` = a new bag directory): a rosbag2 MCAP bag of /joint_states, /odom
and /clock as published and of the command topics as applied (arm efforts, and wheel torques or
in velocity mode cmd_vel as a Twist: held from a segment start on, after timeout and limits, at
t = 0 and whenever they change), every record stamped with its simulated time; plus the scene,
the integrator settings, the base command mode and wheel-speed gains, and the impact log
(recording/recorder.py, rotation.py), so `replay --resimulate` reproduces the run bit for
bit. SIGINT/SIGTERM close it (summary, metadata.yaml); a SIGKILL loses at most the open chunk,
about a second of wall time. A bag holds one time line: after ~/reset it
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

import contextlib
import math
import re
import sys
import threading
import time
from typing import TYPE_CHECKING

import numpy as np
import rclpy
import rclpy.logging
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult
from rclpy.callback_groups import CallbackGroup
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import SingleThreadedExecutor
from rclpy.guard_condition import GuardCondition
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import SetBool, Trigger

from . import cli
from .engine.simulation import DEFAULT_WHEEL_SPEED_GAINS, Simulation, SimulationError
from .errors import UserError
from .memory import CompilerPages, release_compiler_pages
from .messages import NS, command_values, state_messages, transform
from .pacing import Pacer
from .recording.rotation import RotatingRecorder
from .scene import METHODS, load_scene, make_integrator
from .timeline import CommandSlot, Grid, apply_commands, format_ns, start_node_time_line
from .topics import (ARM_TOPIC, CLOCK_TOPIC, CMD_VEL_TOPIC, COMMAND_QOS_DEPTH, DESCRIPTION_TOPIC,
                     JOINT_STATES_TOPIC, ODOM_TOPIC, TF_TOPIC, WHEEL_TOPIC, command_qos,
                     latched_qos, relative, state_qos)
from .urdf import robot_description

if TYPE_CHECKING:   # imported when a bag is opened: mcap and the CDR tables only when recording
    from .recording.recorder import RunRecorder

NODE_NAME = "mobile_manip_sim"
WARN_EVERY = 5.0           # s of wall time between repeats of one kind of warning
BAG_FLUSH_INTERVAL = 1.0   # s of wall time: the most of a recording a SIGKILL may lose
MAX_TAKEN = 4 * COMMAND_QOS_DEPTH   # messages one drain takes from a command topic, at most
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


class _TakenByTheSteppingThread(CallbackGroup):
    """Subscriptions the executor neither waits on nor runs: the stepping thread takes their
    messages itself, latest first, when it needs a command. A flood then costs the middleware
    (whose keep-last history drops the surplus) rather than one Python callback per message."""

    def can_execute(self, entity) -> bool:
        return False

    def beginning_execution(self, entity) -> bool:
        return False

    def ending_execution(self, entity) -> None:
        pass


class _CommandInput:
    """One command topic: its subscription, how a message becomes values, and its slot (the
    latest valid command, `timeline.CommandSlot`)."""

    def __init__(self, topic: str, size: int, labels: str, what: str):
        self.topic, self.labels, self.what = topic, labels, what
        self.slot = CommandSlot(size)
        self.subscription = None

    def take(self, since_ns: int) -> list:
        """The messages waiting that arrived at or after ``since_ns`` (wall clock, ns), oldest
        first; at most MAX_TAKEN: a flood cannot hold us."""
        taken = []
        subscription = self.subscription
        with subscription.handle:
            for _ in range(MAX_TAKEN):
                message = subscription.handle.take_message(subscription.msg_type, False)
                if message is None:
                    break
                if message[1]["received_timestamp"] >= since_ns:
                    taken.append(message[0])
        return taken


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
        self.grid = Grid(p["publish_rate"])   # publication k at t_k, segment k → k + 1
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
        self.base_command = p["base_command"]
        self.velocity_mode = self.base_command == "velocity"
        self.gains = (p["wheel_speed.kp"], p["wheel_speed.ki"])
        self.sim.set_wheel_speed_gains(*self.gains)
        self._settings = settings
        self._recording: RotatingRecorder | None = None
        self._published: list[tuple[int, dict]] = []   # states not yet recorded

        arm_labels = ", ".join(f"tau_{i}, F_{i}" for i in range(1, n_joints // 2 + 1)) or "none"
        self._base = (_CommandInput(CMD_VEL_TOPIC, 2, "v, omega", "base velocity")
                      if self.velocity_mode else
                      _CommandInput(WHEEL_TOPIC, 2, "tau_R, tau_L", "wheel"))
        self._arm = _CommandInput(ARM_TOPIC, n_joints, arm_labels, "arm")
        self._inputs = (self._base, self._arm)
        self._command_lock = threading.Lock()      # guards the command slots
        # Wall time (ns, the middleware's reception clock) of the latest ~/reset: commands
        # received before it are dropped.
        self._commands_since = 0
        self._warned_at: dict[tuple, float] = {}    # throttle: (topic, kind) → wall time

        # Stepping state: the stepping thread owns the engine; services only set flags (_cv).
        self._cv = threading.Condition()
        self._k = 0                  # index of the latest published state
        self._now_ns = 0             # its stamp: simulated time at the start of the open segment
        self._pending = None         # (k + 1, messages) computed, waiting for its wall time
        self._compiler_pages = CompilerPages()   # given back after a segment loaded a kernel
        self._paused = False
        self._steps = 0              # ~/step requests not yet published
        self._failed: str | None = None
        self._reset_requested = False
        self._stopping = False
        self.pacer = Pacer(p["real_time_factor"], 1.0 / self.grid.hz)

        # Relative names: a namespace (__ns:=/robot1) or a remap moves every topic.
        self._state_pubs = {
            topic: self.create_publisher(kind, relative(topic), state_qos())
            for topic, kind in ((JOINT_STATES_TOPIC, JointState), (ODOM_TOPIC, Odometry),
                                (CLOCK_TOPIC, Clock))}
        self._tf_pub = self._tf_publisher() if p["publish_tf"] else None
        self._description_pub = self.create_publisher(String, relative(DESCRIPTION_TOPIC),
                                                      latched_qos())
        self._description = robot_description(scene, root=self.base_frame)
        taken = _TakenByTheSteppingThread()
        self._stamped = p["cmd_vel_stamped"]
        for command in self._inputs:
            kind = Float64MultiArray
            if command.topic == CMD_VEL_TOPIC:
                from geometry_msgs.msg import Twist, TwistStamped
                kind = TwistStamped if self._stamped else Twist
            command.subscription = self.create_subscription(
                kind, relative(command.topic), lambda _: None, command_qos(),
                callback_group=taken)
        # Wakes the stepping thread from waiting for commands (synchronous mode).
        self._wake_guard = GuardCondition(None, None, context=self.context)
        self.create_service(Trigger, "~/reset", self._on_reset)
        self.create_service(SetBool, "~/pause", self._on_pause)
        self.create_service(Trigger, "~/step", self._on_step)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        self._reset_state()
        self._thread = threading.Thread(target=self._run, name="stepping", daemon=True)
        if self.record:   # last: nothing after this may fail and leave an unfinished bag
            try:
                self._recording = RotatingRecorder(self.record, self._open_bag,
                                                   self.get_logger().info,
                                                   self.get_logger().error)
            except UserError as error:
                raise UserError("record", str(error)) from None
        self.get_logger().info(
            f"scene '{scene.name}', integrator {settings.method} "
            f"({'dt ' + str(settings.dt) if settings.fixed_step else f'rtol {settings.rtol}'}), "
            f"publishing at {self.grid.hz:g} Hz of simulated time, real-time factor "
            f"{self.pacer.real_time_factor:g}"
            f"{' (free-running)' if not self.pacer.paced else ''}")
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
                    self.pacer.set_real_time_factor(parameter.value, self._now_ns)
                elif parameter.name == "command_timeout":
                    self.command_timeout_ns = round(parameter.value * NS)
            self._cv.notify_all()

    # --- commands (stepping thread: taken when needed, latest first) ------------------------
    def _drain(self) -> None:
        """Take the waiting command messages (the middleware keeps the latest few of a flood);
        the latest valid one of each topic becomes its slot's command (received at the current
        segment start). Invalid ones are rejected with a throttled warning naming the topic and
        the problem; without a valid one the last valid command stays."""
        for command in self._inputs:
            latest = None
            for message in reversed(command.take(self._commands_since)):
                values = command_values(command.topic, message.twist if self._stamped
                                        and command.topic == CMD_VEL_TOPIC else message)
                problem = command_problem(values, command.slot.size, command.labels)
                if problem is None:
                    latest = values if latest is None else latest
                    continue
                kind, text = problem
                self._warn_throttled((command.topic, kind),
                                     f"{command.topic}: {text}; keeping the last valid command")
            if latest is not None:
                with self._command_lock:
                    command.slot.receive(latest, self._now_ns)

    def _held_commands(self, segment_start_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """The base command (wheel torques, or [v, ω] in velocity mode) and the arm efforts to
        hold from segment_start_ns on, after the command timeout (a stale cmd_vel is zero
        speed)."""
        self._drain()
        held = []
        with self._command_lock:
            for command in self._inputs:
                values, timed_out = command.slot.held(segment_start_ns, self.command_timeout_ns)
                held.append(values)
                if timed_out:
                    self.get_logger().warning(
                        f"{command.topic}: no command for {self.command_timeout_ns / NS:g} s of "
                        f"simulated time (command_timeout); {command.what} "
                        f"{'command' if command.topic == CMD_VEL_TOPIC else 'efforts'} set to "
                        f"zero until commands resume")
        return held[0], held[1]

    # --- services (executor thread): they set flags; the stepping thread acts on them --------
    def _on_reset(self, request, response):
        with self._command_lock:   # commands sent after this call are kept
            for command in self._inputs:
                command.slot.clear()
            # Those still waiting in the subscriptions are from before it: dropped when taken.
            self._commands_since = time.time_ns()
        with self._cv:
            self._reset_requested = True
            self._wake()
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
                    self.pacer.reanchor(self._now_ns)
                response.success = True
            self._wake()
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
            self._wake()
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
        self._record_published()
        if not self.synchronous:
            # The first segment loads the compiled kernels: compute it before pacing starts.
            computed = self._compute_next()
            with self._cv:
                if not self._reset_requested:
                    self._pending = computed
                self.pacer.reanchor(self._now_ns)
        return True

    def _peers_ready(self) -> bool:
        """Synchronous mode's start condition: someone listens, someone commands."""
        listening = any(pub.get_subscription_count() > 0 for pub in self._state_pubs.values())
        commanding = any(command.subscription.get_publisher_count() > 0
                         for command in self._inputs)
        return listening and commanding

    def _await_command(self) -> None:
        """Synchronous mode, before computing a segment: wait for a command newer than the
        latest published state on every command topic that has a publisher (so wheels and arm
        sent in reply to one state apply together), at most sync_timeout wall seconds. Sleeps
        in a wait set on the command subscriptions and the wake guard (pause, reset, step,
        stop), never holding _cv."""
        def answered() -> bool:
            self._drain()
            with self._command_lock:
                fresh = [command.slot.seq != command.slot.seq_published
                         for command in self._inputs]
            commanding = [command.subscription.get_publisher_count() > 0
                          for command in self._inputs]
            return any(fresh) and all(f or not c for f, c in zip(fresh, commanding))

        def interrupted() -> bool:
            with self._cv:
                return self._stopping or self._reset_requested or self._paused

        end = time.monotonic() + self.sync_timeout
        while not (answered() or interrupted()):
            remaining = end - time.monotonic()
            if remaining <= 0:
                self._warn_throttled(("sync",), f"synchronous: no command within sync_timeout "
                                                f"{self.sync_timeout:g} s after t = "
                                                f"{format_ns(self._now_ns)} s; holding the last "
                                                f"one")
                return
            self._wait_for_commands(remaining)

    def _wait_for_commands(self, timeout: float) -> None:
        """Until a command subscription has a message, _wake() is called, or timeout s."""
        subscriptions = [command.subscription for command in self._inputs]
        with contextlib.ExitStack() as stack:
            for entity in (*subscriptions, self._wake_guard):
                stack.enter_context(entity.handle)
            wait_set = _rclpy.WaitSet(len(subscriptions), 1, 0, 0, 0, 0, self.context.handle)
            wait_set.clear_entities()
            for subscription in subscriptions:
                wait_set.add_subscription(subscription.handle)
            wait_set.add_guard_condition(self._wake_guard.handle)
            wait_set.wait(max(1, round(timeout * NS)))

    def _wake(self) -> None:
        """Under _cv: a flag changed; wake the stepping thread wherever it waits."""
        self._cv.notify_all()
        self._wake_guard.trigger()

    def stop(self) -> None:
        """Stop the stepping thread (idempotent); nothing is published afterwards."""
        with self._cv:
            self._stopping = True
            self._wake()
        if self._thread.is_alive():
            self._thread.join(timeout=STOP_TIMEOUT)
        if self._thread.is_alive():   # inside a long segment: the bag is closed regardless
            rclpy.logging.get_logger(NODE_NAME).warning(
                f"the stepping thread did not stop within {STOP_TIMEOUT:g} s; exiting anyway")

    def _run(self) -> None:
        """The engine's only user once started. _cv guards the flags and every publication, and
        is never held while integrating or recording, so services answer even during a long
        segment (such as one that compiles a kernel) or a bag rotation; a segment computed
        across a pause is kept for the resume, one computed across a reset is dropped."""
        try:
            if not self._begin():
                return
            while self._step():
                self._record_published()
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
            stamp = self.grid.stamp(k)
            delay = self.pacer.delay(stamp)
            if delay > 0:
                self._cv.wait(delay)   # woken early by pause, reset, parameters or stop
                return True
            self._report_lag(stamp, -delay)
            self._publish(k, messages)
            self._pending = None
        return True

    def _compute_next(self):
        """Advance the engine over segment k → k + 1; (k + 1, messages), or None on failure."""
        k = self._k
        start_ns = self._now_ns
        base, joints = self._held_commands(start_ns)
        try:
            applied = apply_commands(self.sim, base, joints, self.velocity_mode)
            if self._recording is not None:
                self._recording.commands(start_ns, *applied)
            self.sim.advance_to(self.grid.time(k + 1))
            self._compiler_pages.release_if_used()
        except (SimulationError, UserError) as error:
            with self._cv:
                self._failed = f"t = {format_ns(start_ns)} s: {error}"
            self.get_logger().error(f"simulation failed in the segment after t = "
                                    f"{format_ns(start_ns)} s: {error}; paused, call ~/reset "
                                    f"to start again")
            return None
        return k + 1, self._messages(k + 1)

    def _report_lag(self, stamp: int, late: float) -> None:
        """Publishing `late` s behind the wall clock: beyond the pacer's tolerance, warn
        (throttled, with the measured real-time factor); the pacer paces on from here."""
        measured = self.pacer.late(stamp, late)
        if measured is None:
            return
        since = format_ns(self.pacer.window[1])
        if self._warn_throttled(("lag",), f"cannot keep up with real_time_factor "
                                          f"{self.pacer.real_time_factor:g}: {late:.3f} s behind "
                                          f"the wall clock, measured real-time factor "
                                          f"{measured:.2f} since {since} s; simulated time runs "
                                          f"slower"):
            self.pacer.restart_window()

    def _reset_state(self) -> None:
        """Initial state, t = 0, zero efforts. Commands were cleared when the reset was asked
        for; any that arrived since count as received at t = 0."""
        start_node_time_line(self.sim)
        with self._command_lock:
            for command in self._inputs:
                if command.slot.received_ns is not None:
                    command.slot.received_ns = 0
        self._k, self._now_ns, self._pending = 0, 0, None
        self._failed = None
        self._reset_requested = False
        self._steps = 0
        self.pacer.reanchor(0)

    # --- messages --------------------------------------------------------------------------
    def _messages(self, k: int) -> dict:
        """/joint_states, /odom and /clock for the engine's current state, stamped t_k."""
        return state_messages(self.sim, self.grid.stamp(k), self.joint_names,
                              self.odom_frame, self.base_frame)

    def _publish(self, k: int, messages: dict) -> None:
        """Under _cv. What went out is recorded after _cv is released (_record_published)."""
        if self.synchronous:
            self._drain()   # commands sent before this state are not replies to it
        with self._command_lock:   # before publishing: a reply to this state counts as new
            for command in self._inputs:
                command.slot.seq_published = command.slot.seq
        stamp = self.grid.stamp(k)
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
                self._published.append((stamp, published))
        self._k, self._now_ns = k, stamp

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

    # --- recording (stepping thread, outside _cv; _on_close after it stopped) ---------------
    def _open_bag(self, path: str) -> RunRecorder:
        from .recording.recorder import RunRecorder
        metadata = {"source": "node", "publish_rate": repr(self.grid.hz),
                    "base_command": self.base_command}
        if self.velocity_mode:
            metadata.update(wheel_speed_kp=repr(float(self.gains[0])),
                            wheel_speed_ki=repr(float(self.gains[1])))
        return RunRecorder(path, self.scene, self._settings, metadata,
                           flush_interval=BAG_FLUSH_INTERVAL)

    def _record_published(self) -> None:
        """Record the states published since the last call. The engine is still at the last
        one's stamp, so its impact list is the run's up to there."""
        published, self._published = self._published, []
        if self._recording is not None:
            for stamp, messages in published:
                self._recording.states(stamp, messages, self.sim.impacts)

    def _on_close(self) -> None:
        """After the stepping thread has stopped, before the node is destroyed (SIGINT,
        SIGTERM, normal exit): the bag gets its impacts, summary and metadata.yaml."""
        if self._recording is not None:
            self._record_published()
            logger = self._closing_logger()
            self._recording.close(logger.info, logger.error)

    def _closing_logger(self):
        """The node's logger while its context is up; after SIGINT/SIGTERM shut it down, a
        logger without /rosout (the node's would fail to publish and say so)."""
        if rclpy.ok(context=self.context):
            return self.get_logger()
        return rclpy.logging.get_logger(f"{NODE_NAME}_recording")


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
    release_compiler_pages()   # those numba's import touched; loading the kernels needs few
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
