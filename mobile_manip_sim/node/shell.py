"""`SimulatorNode`: the ROS side of the node — its publishers, command subscriptions, services
and parameters around a `Simulation`, stepped by a `SteppingLoop` — and `main`. The interface is
documented in docs/node.md; topic names, types and QoS are topics.py's."""
from __future__ import annotations

import re
import sys
import threading
import time

import rclpy
import rclpy.logging
from nav_msgs.msg import Odometry
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, Trigger

from ..engine.arm_control import for_robot
from ..engine.simulation import Simulation
from ..ros.messages import state_messages
from ..ros.topics import (
    CLOCK_TOPIC,
    JOINT_STATES_TOPIC,
    ODOM_TOPIC,
    ROBOT_JOINT_STATES_TOPIC,
    state_qos,
)
from ..runtime import cli
from ..runtime.headless import hold_ledger
from ..runtime.memory import return_large_buffers
from ..runtime.pacing import Pacer
from ..runtime.timeline import Grid, apply_commands, start_node_time_line
from ..scene.coordinates import ARM_Q, ARM_U, arm_size
from ..scene.errors import UserError
from ..scene.loading import load_scene, make_integrator
from . import arguments, declare, parameters, qos
from .arm import ArmDriver, arm_array_topic
from .commands import CommandIntake
from .lockstep import ClockFollower, Lockstep
from .loop import Abandoned, SteppingLoop
from .parameters import NODE_NAME
from .recording import BAG_FLUSH_INTERVAL, NodeRecording
from .throttle import Throttle
from .view import NodeView

SHUTDOWN_POLL = 0.2        # s: how often the executor checks for an external shutdown
STEP_TIMEOUT = 30.0        # s of wall time a ~/step call waits for its state
STOP_TIMEOUT = 2.0         # s of wall time shutdown waits for the stepping thread
EXECUTOR_THREADS = 6       # two goals' execute callbacks, the trajectory topic, the services,
#                            the timers: none waits for another
WATCH_PERIOD = 1.0         # s: the watchdog and the check for a namesake node run this often
STATE_TYPES = {JOINT_STATES_TOPIC: JointState, ODOM_TOPIC: Odometry, CLOCK_TOPIC: Clock}


class SimulatorNode(Node):
    """The scene's simulation behind ROS topics; `start` starts stepping."""

    def __init__(self, **node_options):
        super().__init__(NODE_NAME, **node_options)
        self.params = p = parameters.read(declare.declare(self))
        self.scene = load_scene(p.scene or None)
        self._settings = make_integrator(self.scene.integrator, p.method, p.dt, p.rtol, p.atol,
                                         prefix="integrator")
        # UserError: arm_gains.*
        self.arm_controller = for_robot(p.arm_controller, self.scene.robot)
        self.joint_names = self.scene.robot.joint_names()
        self.grid = Grid(p.publish_rate)   # publication k at t_k, segment k → k + 1
        self._recording: NodeRecording | None = None
        log = self.get_logger()
        throttle = Throttle(log.warning)

        # Relative names: a namespace (__ns:=/robot1) or a remap moves every topic but /clock,
        # which use_sim_time clients read at /clock whatever their namespace (publish_clock).
        # ros2_control: joint_state_broadcaster publishes joint_states; ours go to the topic the
        # hardware interface reads (recorded as /joint_states all the same).
        self._state_pubs = {topic: qos.publisher(self, kind, topic, state_qos(),
                                                 absolute=topic == CLOCK_TOPIC)
                            for topic, kind in STATE_TYPES.items()
                            if (p.publish_clock or topic != CLOCK_TOPIC)
                            and not (p.ros2_control and topic == JOINT_STATES_TOPIC)}
        self._hardware_states = None if not p.ros2_control else qos.publisher(
            self, JointState, ROBOT_JOINT_STATES_TOPIC, state_qos())
        self.view = NodeView(self, self.scene, p)
        qos.check_unknown(self)
        self.commands = CommandIntake(self, p.velocity_mode, p.cmd_vel_stamped,
                                      arm_size(self.scene.robot.n_links), p.command_timeout,
                                      throttle, log.warning,
                                      arm_topic=arm_array_topic(self.arm_controller),
                                      joint_commands=self._joint_commands())
        # An arm controller's commands (arm.py); None in effort mode.
        self.arm = ArmDriver(self, self.arm_controller.mode, self.joint_names[ARM_U],
                             throttle.warn, log.warning,
                             source=self.commands.joints.name if self.commands.joints else None
                             ) if self.arm_controller.active else None
        lockstep = None
        if p.synchronous:
            lockstep = Lockstep(self.commands, self._listening, p.sync_timeout, throttle)
        # publish_clock false: another simulator's /clock paces us (lockstep.ClockFollower).
        pacer = (Pacer if p.publish_clock else ClockFollower)(p.real_time_factor,
                                                              1.0 / self.grid.hz)
        self.loop = SteppingLoop(
            self.grid, pacer, restart=self._restart,
            compute=self._compute, publish=self._publish, record=self._record,
            failed=self._failed, warn=throttle.warn, lockstep=lockstep, wake=self.commands.wake,
            alive=lambda: rclpy.ok(context=self.context), progress=self._progress,
            replace=self._replace_engine, report=log.warning)
        self._generation = 0   # engines replaced by the watchdog so far (`_owned`)
        self._clock_subscription = None
        if not p.publish_clock:
            pacer.notify, pacer.warn = self.loop.notify, throttle.warn
            self._clock_subscription = self.create_subscription(
                Clock, CLOCK_TOPIC, self._on_clock, state_qos(),
                callback_group=MutuallyExclusiveCallbackGroup())
        self._warn = throttle.warn
        self.create_service(Trigger, "~/reset", self._on_reset)
        self.create_service(SetBool, "~/pause", self._on_pause)
        # ~/step waits for its state: in a group of its own, ~/pause and ~/reset answer meanwhile
        self.create_service(Trigger, "~/step", self._on_step,
                            callback_group=MutuallyExclusiveCallbackGroup())
        self._namesakes = False   # another node has our name and namespace (said once)
        self.create_timer(WATCH_PERIOD, self._every_second)
        self.add_on_set_parameters_callback(declare.validate)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._thread = threading.Thread(target=self.loop.run, name="stepping", daemon=True)
        self.sim = self._new_engine()
        if p.record:   # last: nothing after this may fail and leave an unfinished bag
            self._recording = NodeRecording(p.record, self.sim, self._settings, p, log.info,
                                            log.error)
            # A paused or failed node records nothing: the open chunk goes to disk on a timer.
            self.create_timer(BAG_FLUSH_INTERVAL, self._recording.flush,
                              callback_group=MutuallyExclusiveCallbackGroup())
        s = self._settings
        log.info(f"scene '{self.scene.name}', integrator {s.method} "
                 f"({'dt ' + str(s.dt) if s.fixed_step else f'rtol {s.rtol}'}), publishing at "
                 f"{self.grid.hz:g} Hz of simulated time, real-time factor "
                 f"{p.real_time_factor:g}{' (free-running)' if not p.real_time_factor else ''}; "
                 f"{self._mode()}")
        if self.arm is not None and self.arm.trajectories is not None:
            self.arm.trajectories.start()   # says so if the action is off
        for warning in self.view.warnings:
            log.warning(warning)
        if self.view.live is not None:
            log.info(f"live view: {self.view.live.url} (Foxglove: open connection, Foxglove "
                     f"WebSocket)")
        if self.view.browser is not None:
            log.info(f"view: {self.view.browser.url}")

    def _mode(self) -> str:
        """The start-up line's account of how the node is driven and paced."""
        p = self.params
        inputs = ("ros2_control hardware (joint commands on topic_based_joint_commands)"
                  if p.ros2_control else f"base {p.base_command}, "
                       f"arm_controller {self.arm_controller.mode}")
        pacing = (f"synchronous: waits for a state subscriber and a command publisher, then "
                  f"steps once per command (or after {p.sync_timeout:g} s without one)"
                  if p.synchronous else "paced by the wall clock")
        if not p.publish_clock:
            pacing = (f"{pacing} and " if p.synchronous else "") + \
                "following the /clock it hears (publish_clock false)"
        return f"mode: {inputs}; {pacing}"

    def _joint_commands(self) -> dict | None:
        """The command intake's settings for ros2_control's joint commands, or None."""
        if not self.params.ros2_control:
            return None
        base = self.scene.robot.base
        return dict(names=self.joint_names, arm_interface=self.arm_controller.mode,
                    wheel_radius=base.wheel_radius, half_track=base.half_track,
                    arm_initial=self.scene.initial_q[ARM_Q])

    # --- parameters (declared and validated by declare.py) ---------------------------------
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

    def _on_clock(self, message) -> None:
        self.loop.pacer.heard_message(message.clock.sec, message.clock.nanosec)

    def _on_step(self, request, response):
        response.success, response.message = self.loop.step(STEP_TIMEOUT)
        return response

    # --- the loop's callables (stepping thread) ---------------------------------------------
    def _messages(self, k: int, sim=None) -> dict:
        """/joint_states, /odom, /clock and the view's (view.py) for the state of ``sim`` (the
        engine by default), stamped t_k."""
        sim = self.sim if sim is None else sim
        stamp = self.grid.stamp(k)
        messages = state_messages(sim, stamp, self.joint_names, self.view.odom_frame,
                                  self.view.base_frame)
        messages.update(self.view.messages(sim, k, stamp))
        return messages

    def _restart(self) -> dict:
        """t = 0: the scene's initial state, zero efforts."""
        start_node_time_line(self.sim)
        self.commands.restart()
        if self.arm is not None:
            self.arm.restart(self.commands.arm_received())
        return self._messages(0)

    def _compute(self, k: int, start_ns: int) -> dict:
        # The engine of this segment, once: a thread the watchdog abandoned goes on with its
        # own engine and never reaches the one that replaced it; `_owned` before each step
        # that touches what the two share (goals, the bag) ends it instead.
        sim, generation = self.sim, self._generation
        base, joints = self.commands.held(start_ns)
        efforts = None if self.arm is not None else joints   # the arm's, in effort mode
        applied = apply_commands(sim, base, efforts, self.params.velocity_mode)
        self._owned(generation)
        arm = None if self.arm is None else self.arm.segment_start(
            sim, start_ns, joints, self.commands.arm_received())
        self._owned(generation)
        if self._recording is not None:
            self._recording.commands(start_ns, applied[0], None if efforts is None else applied[1])
            if arm is not None:
                self._recording.arm_command(start_ns, arm())
        sim.advance_to(self.grid.time(k + 1))
        self._owned(generation)
        return self._messages(k + 1, sim)

    def _owned(self, generation: int) -> None:
        """Abandoned (loop.py) when the watchdog replaced the engine since ``generation``."""
        if generation != self._generation:
            raise Abandoned

    def _progress(self) -> tuple:
        """What the watchdog watches: the engine's own counters (its time and its accepted
        steps, which the compiled code advances as it goes)."""
        sim = self.sim
        return sim.t, sim.steps

    def _failed(self, text: str) -> None:
        """A segment failed (the loop's one line): the active goal is answered at once."""
        self.get_logger().error(text)
        if self.arm is not None and self.arm.trajectories is not None:
            self.arm.trajectories.goals.forget(text)

    def _publish(self, k: int, messages: dict) -> None:
        published = {}
        try:   # at k = 0 the latched ones (robot description) lead
            self.view.publish_latched(messages, published)
            for topic in STATE_TYPES:   # recorded whether published (publish_clock) or not
                if topic in self._state_pubs:
                    self._state_pubs[topic].publish(self.view.wire(topic, messages[topic]))
                published[topic] = messages[topic]
            if self._hardware_states is not None:
                self._hardware_states.publish(self.view.wire(JOINT_STATES_TOPIC,
                                                             messages[JOINT_STATES_TOPIC]))
            self.view.publish(self.grid.stamp(k), messages, published)
        finally:
            # What went out is recorded, even when a shutdown fails the rest of the group.
            if published and self._recording is not None:
                self._recording.published(self.grid.stamp(k), published)

    def _record(self) -> None:
        if self._recording is not None:
            self._recording.record()

    def _listening(self) -> bool:
        publishers = [*self._state_pubs.values(), self._hardware_states]
        return any(pub.get_subscription_count() > 0 for pub in publishers if pub is not None)

    def _new_engine(self) -> Simulation:
        sim = Simulation(self.scene, self._settings, arm_controller=self.arm_controller,
                         control_rate=self.params.controller_rate)
        sim.set_wheel_speed_gains(*self.params.wheel_speed_gains)
        sim.hold_warning = self.get_logger().warning   # a hold over its bound: one line
        return sim

    def _replace_engine(self) -> None:
        """The watchdog gave up on a stuck segment: a new engine (the old one is left to it)."""
        self._generation += 1
        self.sim = self._new_engine()
        if self._recording is not None:
            self._recording.sim = self.sim

    def _every_second(self) -> None:
        self.loop.watch()
        clocks = self._clock_subscription and self._clock_subscription.get_publisher_count()
        if clocks and clocks > 1:   # two time lines interleaved: followed to and fro
            self._warn(("clock", "publishers"), f"{clocks} nodes publish {CLOCK_TOPIC}: this "
                       f"node follows whichever it heard last (publish_clock false); give "
                       f"/clock one publisher")
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
        """After `stop`, before the node is destroyed (SIGINT, SIGTERM, normal exit): the bag
        first (its summary and metadata.yaml), then the live view, whose stop waits on no
        client (live_view.CLOSE_WAIT)."""
        if self.sim.holds:   # the energy the engine removed beyond the impact law, said once
            rclpy.logging.get_logger(NODE_NAME).info(f"end stops: {hold_ledger(self.sim)} "
                                                     f"beyond the impact law")
        if self._recording is not None:
            # While the context is up the node's logger; after SIGINT/SIGTERM shut it down, one
            # without /rosout (the node's would fail to publish and say so).
            logger = (self.get_logger() if rclpy.ok(context=self.context)
                      else rclpy.logging.get_logger(f"{NODE_NAME}_recording"))
            self._recording.close(logger.info, logger.error)
        self.view.close()


    def destroy_node(self) -> None:
        """The action server first (`TrajectoryInterface.destroy`), then what rclpy destroys."""
        if self.arm is not None and self.arm.trajectories is not None:
            self.arm.trajectories.destroy()
        super().destroy_node()


def _init(argv) -> None:
    """rclpy.init; bad --ros-args (a missing or unparsable --params-file, ...) is a UserError,
    and the line rcl logs itself then ("Failed to parse global arguments") is left out."""
    arguments.check(argv)
    with cli.held_stderr() as said:
        try:
            rclpy.init(args=argv)
            failed = None
        except Exception as error:   # RCLError, whose text names rcl's source lines
            failed = error
    if failed is None:
        sys.stderr.buffer.write(said[0])   # rcl's words on a start that goes on: passed on
        sys.stderr.flush()
        return
    text = re.sub(r",? at /\S+:\d+", "", str(failed)).replace("failed to initialize rcl: ", "")
    key = "--params-file" if "params file" in text else "--ros-args"
    raise UserError(key, text.strip()) from None


def _main(argv) -> int:
    if arguments.wants_help(argv):
        print(arguments.help_text())
        return 0
    return_large_buffers()     # trajectories of megabytes come and go for as long as it runs
    _init(argv)
    node = None
    try:
        node = SimulatorNode()
        # A FollowJointTrajectory goal's execute callback waits in a thread for its outcome;
        # at most two do (trajectory_action.MAX_GOALS), and the others stay for the services,
        # the trajectory topic and the timers.
        executor = MultiThreadedExecutor(num_threads=EXECUTOR_THREADS)
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
