"""`SimulatorNode`: the ROS side of the node — its publishers, command subscriptions, services
and parameters around a `Simulation`, stepped by a `SteppingLoop` — and `main`. The interface is
documented in the README ("The ROS 2 node"); topic names, types and QoS are topics.py's."""
from __future__ import annotations

import re
import threading
import time

import rclpy
import rclpy.logging
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, Trigger

from ..engine.simulation import Simulation
from ..ros.messages import state_messages
from ..ros.topics import CLOCK_TOPIC, JOINT_STATES_TOPIC, ODOM_TOPIC, state_qos
from ..runtime import cli
from ..runtime.headless import hold_ledger
from ..runtime.memory import CompilerPages, release_compiler_pages
from ..runtime.pacing import Pacer
from ..runtime.timeline import Grid, apply_commands, start_node_time_line
from ..scene.coordinates import ARM_U
from ..scene.errors import UserError
from ..scene.loading import load_scene, make_integrator
from . import arguments, parameters, qos
from .arm import ArmDriver, arm_array_topic
from .commands import CommandIntake
from .lockstep import Lockstep
from .loop import SteppingLoop
from .parameters import ARM_GAIN_PARAMETERS, NODE_NAME, PARAMETERS
from .recording import NodeRecording
from .throttle import Throttle
from .view import NodeView

SHUTDOWN_POLL = 0.2        # s: how often the executor checks for an external shutdown
STEP_TIMEOUT = 30.0        # s of wall time a ~/step call waits for its state
STOP_TIMEOUT = 2.0         # s of wall time shutdown waits for the stepping thread
WATCH_PERIOD = 1.0         # s: the watchdog and the check for a namesake node run this often
STATE_TYPES = {JOINT_STATES_TOPIC: JointState, ODOM_TOPIC: Odometry, CLOCK_TOPIC: Clock}


class SimulatorNode(Node):
    """The scene's simulation behind ROS topics; `start` starts stepping."""

    def __init__(self, **node_options):
        super().__init__(NODE_NAME, **node_options)
        self.params = p = parameters.read(self._declared_parameters())
        self.scene = load_scene(p.scene or None)
        self._settings = make_integrator(self.scene.integrator, p.method, p.dt, p.rtol, p.atol,
                                         prefix="integrator")
        self.arm_control = p.arm_control.for_robot(self.scene.robot)   # UserError: arm_gains.*
        self.sim = Simulation(self.scene, self._settings, arm_control=self.arm_control)
        self.sim.set_wheel_speed_gains(*p.wheel_speed_gains)
        self.sim.hold_warning = self.get_logger().warning   # a hold over its bound: one line
        self.joint_names = self.scene.robot.joint_names()
        self.grid = Grid(p.publish_rate)   # publication k at t_k, segment k → k + 1
        self._compiler_pages = CompilerPages()   # given back after a segment loaded a kernel
        self._recording: NodeRecording | None = None
        log = self.get_logger()
        throttle = Throttle(log.warning)

        # Relative names: a namespace (__ns:=/robot1) or a remap moves every topic but /clock,
        # which use_sim_time clients read at /clock whatever their namespace (publish_clock).
        self._state_pubs = {topic: qos.publisher(self, kind, topic, state_qos(),
                                                 absolute=topic == CLOCK_TOPIC)
                            for topic, kind in STATE_TYPES.items()
                            if p.publish_clock or topic != CLOCK_TOPIC}
        self.view = NodeView(self, self.scene, p)
        qos.check_unknown(self)
        self.commands = CommandIntake(self, p.velocity_mode, p.cmd_vel_stamped,
                                      len(self.joint_names) - 2, p.command_timeout, throttle,
                                      log.warning, arm_topic=arm_array_topic(self.arm_control))
        # An arm controller's commands (arm.py); None in effort mode.
        self.arm = ArmDriver(self, self.arm_control.mode, self.joint_names[ARM_U], throttle.warn,
                             log.warning) if self.arm_control.active else None
        lockstep = None
        if p.synchronous:
            lockstep = Lockstep(self.commands, self._listening, p.sync_timeout, throttle)
        self.loop = SteppingLoop(
            self.grid, Pacer(p.real_time_factor, 1.0 / self.grid.hz), restart=self._restart,
            compute=self._compute, publish=self._publish, record=self._record,
            failed=log.error, warn=throttle.warn, lockstep=lockstep, wake=self.commands.wake,
            alive=lambda: rclpy.ok(context=self.context), progress=lambda: self.sim.t,
            replace=self._replace_engine, report=log.warning)
        self.create_service(Trigger, "~/reset", self._on_reset)
        self.create_service(SetBool, "~/pause", self._on_pause)
        # ~/step waits for its state: in a group of its own, ~/pause and ~/reset answer meanwhile
        self.create_service(Trigger, "~/step", self._on_step,
                            callback_group=MutuallyExclusiveCallbackGroup())
        self._namesakes = False   # another node has our name and namespace (said once)
        self.create_timer(WATCH_PERIOD, self._every_second)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._thread = threading.Thread(target=self.loop.run, name="stepping", daemon=True)
        if p.record:   # last: nothing after this may fail and leave an unfinished bag
            self._recording = NodeRecording(p.record, self.sim, self._settings, p, log.info,
                                            log.error)
        s = self._settings
        log.info(f"scene '{self.scene.name}', integrator {s.method} "
                 f"({'dt ' + str(s.dt) if s.fixed_step else f'rtol {s.rtol}'}), publishing at "
                 f"{self.grid.hz:g} Hz of simulated time, real-time factor "
                 f"{p.real_time_factor:g}{' (free-running)' if not p.real_time_factor else ''}")
        if self.arm is not None and self.arm.trajectories is not None:
            self.arm.trajectories.start()   # says so if the action is off
        for warning in self.view.warnings:
            log.warning(warning)
        if self.view.live is not None:
            log.info(f"live view: {self.view.live.url} (Foxglove: open connection, Foxglove "
                     f"WebSocket)")

    # --- parameters ------------------------------------------------------------------------
    def _declared_parameters(self) -> dict:
        """Declare PARAMETERS; their values (rclpy checks types and ranges: UserError)."""
        for name, spec in PARAMETERS.items():
            descriptor = ParameterDescriptor(description=spec.description,
                                             read_only=not spec.dynamic,
                                             dynamic_typing=name in ARM_GAIN_PARAMETERS)
            if spec.range and isinstance(spec.default, int):
                descriptor.integer_range = [IntegerRange(
                    from_value=spec.range[0], to_value=spec.range[1], step=1)]
            elif spec.range:
                descriptor.floating_point_range = [FloatingPointRange(
                    from_value=spec.range[0], to_value=spec.range[1], step=0.0)]
            try:
                self.declare_parameter(name, spec.default, descriptor)
            except InvalidParameterTypeException:
                raise UserError(name, f"expected {parameters.expected_kind(name)}") from None
            except InvalidParameterValueException:
                override = self._parameter_overrides.get(name)
                value = override.value if override is not None else spec.default
                raise UserError(name, f"{value} is outside {parameters.bounds(name)}"
                                ) from None
        # A parameter given for this node that it does not declare is a mistake (a typo such
        # as real_time_facter would otherwise be silently ignored). QoS overrides: qos.py's.
        unknown = sorted(name for name in set(self._parameter_overrides) - set(self._parameters)
                         if not name.startswith(qos.QOS_OVERRIDES))
        if unknown:
            raise UserError(unknown[0], f"unknown parameter of {NODE_NAME} (known: "
                                        f"{', '.join(PARAMETERS)})")
        return {name: self.get_parameter(name).value for name in PARAMETERS}

    def _validate_parameters(self, changes) -> SetParametersResult:
        for change in changes:
            problem = parameters.value_problem(change.name, change.value)
            if problem is not None:
                return SetParametersResult(successful=False, reason=f"{change.name} {problem}")
        return SetParametersResult(successful=True)

    def _apply_parameters(self, changes) -> None:
        for change in changes:
            if change.name == "real_time_factor":
                self.loop.set_real_time_factor(change.value)
            elif change.name == "command_timeout":
                self.commands.set_timeout(change.value)

    # --- services (executor thread): the loop acts on them ----------------------------------
    def _on_reset(self, request, response):
        self.commands.forget(time.time_ns())   # commands sent after this call are kept
        self.loop.reset()
        self.get_logger().info("reset to the initial state, t = 0")
        response.success, response.message = True, "reset to the initial state at t = 0"
        return response

    def _on_pause(self, request, response):
        response.success, response.message = self.loop.pause(request.data)
        self.get_logger().info(response.message)
        return response

    def _on_step(self, request, response):
        response.success, response.message = self.loop.step(STEP_TIMEOUT)
        return response

    # --- the loop's callables (stepping thread) ---------------------------------------------
    def _messages(self, k: int) -> dict:
        """/joint_states, /odom, /clock and the view's (view.py) for the engine's current
        state, stamped t_k."""
        stamp = self.grid.stamp(k)
        messages = state_messages(self.sim, stamp, self.joint_names, self.view.odom_frame,
                                  self.view.base_frame)
        messages.update(self.view.messages(self.sim, k, stamp))
        return messages

    def _restart(self) -> dict:
        """t = 0: the scene's initial state, zero efforts."""
        start_node_time_line(self.sim)
        self.commands.restart()
        if self.arm is not None:
            self.arm.restart(self.commands.arm_received())
        return self._messages(0)

    def _compute(self, k: int, start_ns: int) -> dict:
        base, joints = self.commands.held(start_ns)
        efforts = None if self.arm is not None else joints   # the arm's, in effort mode
        applied = apply_commands(self.sim, base, efforts, self.params.velocity_mode)
        arm = None if self.arm is None else self.arm.segment_start(
            self.sim, start_ns, joints, self.commands.arm_received())
        if self._recording is not None:
            self._recording.commands(start_ns, applied[0], None if efforts is None else applied[1])
            if arm is not None:
                self._recording.arm_command(start_ns, arm)
        self.sim.advance_to(self.grid.time(k + 1))
        self._compiler_pages.release_if_used()
        return self._messages(k + 1)

    def _publish(self, k: int, messages: dict) -> None:
        published = {}
        try:   # at k = 0 the latched ones (robot description) lead
            self.view.publish_latched(messages, published)
            for topic in STATE_TYPES:   # recorded whether published (publish_clock) or not
                if topic in self._state_pubs:
                    self._state_pubs[topic].publish(self.view.wire(topic, messages[topic]))
                published[topic] = messages[topic]
            self.view.publish(self.grid.stamp(k), messages, published)
        finally:
            # What went out is recorded, even when a shutdown fails the rest of the group.
            if published and self._recording is not None:
                self._recording.published(self.grid.stamp(k), published)

    def _record(self) -> None:
        if self._recording is not None:
            self._recording.record()

    def _listening(self) -> bool:
        return any(pub.get_subscription_count() > 0 for pub in self._state_pubs.values())

    def _replace_engine(self) -> None:
        """The watchdog gave up on a stuck segment: a new engine (the old one is left to it)."""
        self.sim = Simulation(self.scene, self._settings, arm_control=self.arm_control)
        self.sim.set_wheel_speed_gains(*self.params.wheel_speed_gains)
        self.sim.hold_warning = self.get_logger().warning
        if self._recording is not None:
            self._recording.sim = self.sim

    def _every_second(self) -> None:
        self.loop.watch()
        name, namespace = self.get_name(), self.get_namespace()
        count = self.get_node_names_and_namespaces().count((name, namespace))
        if count > 1 and not self._namesakes:
            full = f"{namespace.rstrip('/')}/{name}"
            self.get_logger().warning(
                f"another node named {full} is running: ~/reset, ~/pause and ~/step reach "
                f"both, and their topics mix; give each its own name (-r __node:=NAME) or "
                f"namespace (-r __ns:=/NAME)")
        self._namesakes = count > 1

    # --- life cycle --------------------------------------------------------------------------
    def start(self) -> None:
        """Start the stepping thread. Nothing is computed here, before the executor spins."""
        self._thread.start()

    def stop(self) -> None:
        """Stop the stepping thread (idempotent); nothing is published afterwards."""
        self.loop.stop()
        if self._thread.is_alive():
            self._thread.join(timeout=STOP_TIMEOUT)
        if self._thread.is_alive():   # inside a long segment: the bag is closed regardless
            rclpy.logging.get_logger(NODE_NAME).warning(
                f"the stepping thread did not stop within {STOP_TIMEOUT:g} s; exiting anyway")

    def close(self) -> None:
        """After `stop`, before the node is destroyed (SIGINT, SIGTERM, normal exit)."""
        if self.sim.holds:   # the energy the engine removed beyond the impact law, said once
            rclpy.logging.get_logger(NODE_NAME).info(f"end stops: {hold_ledger(self.sim)} "
                                                     f"beyond the impact law")
        self.view.close()
        if self._recording is not None:
            # While the context is up the node's logger; after SIGINT/SIGTERM shut it down, one
            # without /rosout (the node's would fail to publish and say so).
            logger = (self.get_logger() if rclpy.ok(context=self.context)
                      else rclpy.logging.get_logger(f"{NODE_NAME}_recording"))
            self._recording.close(logger.info, logger.error)


def _init(argv) -> None:
    """rclpy.init; bad --ros-args (a missing or unparsable --params-file, ...) is a UserError."""
    arguments.check(argv)
    try:
        rclpy.init(args=argv)
    except Exception as error:   # RCLError, whose text names rcl's source lines
        text = re.sub(r",? at /\S+:\d+", "", str(error)).replace("failed to initialize rcl: ", "")
        key = "--params-file" if "params file" in text else "--ros-args"
        raise UserError(key, text.strip()) from None


def _main(argv) -> int:
    if arguments.wants_help(argv):
        print(arguments.help_text())
        return 0
    release_compiler_pages()   # those numba's import touched; loading the kernels needs few
    _init(argv)
    node = None
    try:
        node = SimulatorNode()
        # 4: a FollowJointTrajectory goal's execute callback waits in a thread for its outcome;
        # at most two do (the active goal and the one that will preempt it, e.g. while paused),
        # and two threads stay for the services.
        executor = MultiThreadedExecutor(num_threads=4)
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
            node.close()
            try:
                node.destroy_node()
            except Exception:
                if rclpy.ok():
                    raise
        rclpy.try_shutdown()
    return 0


def main(args=None) -> int:
    return cli.run(_main, args)
