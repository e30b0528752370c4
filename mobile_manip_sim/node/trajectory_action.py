"""joint_trajectory_controller's interface for arm_controller joint_trajectory: the
`joint_trajectory` topic (trajectory_msgs/JointTrajectory), the `follow_joint_trajectory` action
(control_msgs/action/FollowJointTrajectory) and `controller_state`
(control_msgs/msg/JointTrajectoryControllerState). The goals' logic is ROS-free
(trajectory_goals.py); here only messages in and out.

Without control_msgs (PyPI has no wheel: tools/bootstrap.sh builds it into .venv) the topic
still works, the action and the state are off, and the node says so in one line.

Threads: a goal's execute callback (an executor thread) submits it and waits for its outcome;
the stepping thread applies goals at segment starts (`segment_start`), publishes the feedback
and the state, and ends goals; a cancel marks the goal for the next segment start.

Neither intake can starve the services (~/pause, ~/reset share the node's default group): the
topic has a callback group of its own and takes the message's bytes, read into arrays by
`trajectory_wire` (a 100,000-point message would otherwise hold the interpreter lock for seconds
while rclpy builds its Python objects); the action has its own group too, and accepts at most
MAX_GOALS goals at a time — one more is rejected at once, with a warning, rather than left to
wait for a thread.
"""
from __future__ import annotations

import threading

import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from ..ros.messages import time_msg
from ..ros.topics import (
    CONTROLLER_STATE_TOPIC,
    TRAJECTORY_ACTION,
    TRAJECTORY_TOPIC,
    command_qos,
    relative,
    state_qos,
)
from ..ros.trajectory_goals import Codes, Goal, JointTolerance, Point, TrajectoryGoals, errors
from ..ros.trajectory_wire import arrays, read_trajectory
from ..runtime.timeline import NS
from ..scene.coordinates import ARM_Q, ARM_U

WAIT_POLL = 0.5   # s: an execute callback checks this often that the node still runs
MAX_GOALS = 2     # action goals accepted and not yet answered (the active one and its successor)
# The action's goal, cancel and result services keep this many requests: rclpy's default (10)
# drops the rest of a burst unanswered, a client then waits for ever (a goal the node never saw
# cannot be rejected). Each request waiting costs one message.
REQUEST_DEPTH = 1000


def goal_of(trajectory: JointTrajectory, tolerances=None) -> Goal:
    """The plain `Goal` of a JointTrajectory (and of a FollowJointTrajectory goal's
    tolerances)."""
    points = []
    for point in trajectory.points:
        duration = point.time_from_start
        points.append(Point(duration.sec * NS + duration.nanosec, tuple(point.positions),
                            tuple(point.velocities), tuple(point.accelerations),
                            tuple(point.effort)))
    stamp = trajectory.header.stamp
    goal = Goal(tuple(trajectory.joint_names), tuple(points), stamp.sec * NS + stamp.nanosec)
    if tolerances is None:
        return goal

    def plain(given):
        return tuple(JointTolerance(t.name, t.position, t.velocity, t.acceleration)
                     for t in given)
    limit = tolerances.goal_time_tolerance
    return goal._replace(path_tolerance=plain(tolerances.path_tolerance),
                         goal_tolerance=plain(tolerances.goal_tolerance),
                         goal_time=limit.sec + limit.nanosec / NS)


def trajectory_point(positions, velocities=None, accelerations=None, efforts=None):
    point = JointTrajectoryPoint(positions=[float(v) for v in positions])
    for field, values in (("velocities", velocities), ("accelerations", accelerations),
                          ("effort", efforts)):
        if values is not None:
            setattr(point, field, [float(v) for v in values])
    return point


class TrajectoryInterface:
    """The topic, the action server and the state publisher of a node whose arm joints are
    ``names``; ``warn(key, text)`` a throttled warning, ``info`` a log line."""

    def __init__(self, node, names, warn, info):
        self.node, self.names, self._warn, self._info = node, list(names), warn, info
        try:
            from control_msgs.action import FollowJointTrajectory
            from control_msgs.msg import JointTrajectoryControllerState
        except ImportError:
            FollowJointTrajectory = JointTrajectoryControllerState = None
        self.available = FollowJointTrajectory is not None
        # Without control_msgs nothing can carry a result: the codes are their names.
        codes = Codes.of(FollowJointTrajectory.Result) if self.available else \
            Codes._make(name.upper() for name in Codes._fields)
        self.goals = TrajectoryGoals(self.names, codes)
        self._topic_requests = []   # the topic's trajectories not yet ended (for their log)
        self._lock = threading.Lock()
        node.create_subscription(JointTrajectory, relative(TRAJECTORY_TOPIC), self._on_topic,
                                 command_qos(), raw=True,
                                 callback_group=MutuallyExclusiveCallbackGroup())
        self._action = self._state_pub = None
        self._in_flight = 0   # action goals accepted and not yet answered
        if self.available:
            from rclpy.action import ActionServer, CancelResponse, GoalResponse
            self._type, self._state_type = FollowJointTrajectory, JointTrajectoryControllerState
            self._cancel_response = CancelResponse.ACCEPT
            from rclpy.qos import QoSProfile, ReliabilityPolicy
            self._responses = GoalResponse
            requests = QoSProfile(depth=REQUEST_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
            self._action = ActionServer(
                node, FollowJointTrajectory, relative(TRAJECTORY_ACTION),
                execute_callback=self._execute, goal_callback=self._on_goal,
                cancel_callback=self._on_cancel, callback_group=ReentrantCallbackGroup(),
                goal_service_qos_profile=requests, result_service_qos_profile=requests,
                cancel_service_qos_profile=requests)
            self._state_pub = node.create_publisher(JointTrajectoryControllerState,
                                                    relative(CONTROLLER_STATE_TOPIC), state_qos())
        self._requests = {}   # goal id → Request (cancel looks it up)

    # --- executor threads ------------------------------------------------------------------
    def _on_topic(self, data: bytes) -> None:
        """A JointTrajectory's CDR bytes: read into arrays, checked, submitted."""
        try:
            wire = read_trajectory(data)
        except ValueError as error:
            self._warn(("trajectory", "malformed"), f"{relative(TRAJECTORY_TOPIC)}: not a "
                                                    f"JointTrajectory ({error}); ignored")
            return
        arranged = arrays(wire, self.names, self.goals.codes)
        request = self.goals.submit(Goal(wire.joint_names, (), wire.start_ns), arranged=arranged)
        with self._lock:
            self._topic_requests.append(request)
        self._report_topic()

    def _on_goal(self, _request):
        """Accept a goal unless MAX_GOALS are in flight: then reject it, saying so."""
        with self._lock:
            accept = self._in_flight < MAX_GOALS
            if accept:
                self._in_flight += 1
        if not accept:
            self._warn(("goal", "rejected"), f"{relative(TRAJECTORY_ACTION)}: goal rejected: "
                                             f"{MAX_GOALS} goals are in flight (send the next "
                                             f"once one is answered)")
            return self._responses.REJECT
        return self._responses.ACCEPT

    def _execute(self, goal_handle):
        try:
            return self._answer(goal_handle)
        finally:
            with self._lock:
                self._in_flight -= 1

    def _answer(self, goal_handle):
        key = bytes(goal_handle.goal_id.uuid)
        goal = goal_handle.request
        request = self.goals.submit(goal_of(goal.trajectory, goal), goal_handle)
        self._requests[key] = request
        if goal_handle.is_cancel_requested:
            self.goals.cancel(request)
        if request.note:
            self._warn(("tolerances",), f"follow_joint_trajectory: {request.note}")
        while not request.finished.wait(WAIT_POLL):
            if not self.node.context.ok():
                break
        self._requests.pop(key, None)
        result = self._type.Result()
        outcome = request.outcome
        if outcome is None:
            self.goals.cancel(request)   # nothing is applied after the node stopped
            result.error_code = self.goals.codes.invalid_goal
            result.error_string = "the node is shutting down"
            end = goal_handle.abort
        elif outcome.code is None or outcome.canceled:
            result.error_code = outcome.code or 0   # a preempted goal: INVALID_GOAL, as jtc
            result.error_string = outcome.text
            if not goal_handle.is_cancel_requested:
                # Preempted: ends CANCELED as jtc's does. An action goal reaches CANCELED only
                # through CANCELING, which rclpy enters only for a client's cancel request.
                from rclpy.impl.implementation_singleton import rclpy_implementation
                goal_handle._update_state(rclpy_implementation.GoalEvent.CANCEL_GOAL)
            end = goal_handle.canceled
        else:
            result.error_code, result.error_string = outcome.code, outcome.text
            end = goal_handle.succeed if outcome.code == self.goals.codes.successful else \
                goal_handle.abort
        try:
            end()
        except Exception:   # RCLError: SIGINT/SIGTERM took the context (and the handle) away
            if self.node.context.ok():
                raise
        return result

    def _on_cancel(self, goal_handle):
        request = self._requests.get(bytes(goal_handle.goal_id.uuid))
        if request is not None:
            self.goals.cancel(request)
        return self._cancel_response

    # --- the stepping thread ---------------------------------------------------------------
    def segment_start(self, sim, now_ns: int, apply):
        """At a segment start: the goals' step (trajectory_goals.Step), feedback and state
        published; ``apply(trajectory)`` puts a trajectory into the engine."""
        q, u = sim.q[ARM_Q], sim.u[ARM_U]   # (not q[-n:]: an armless robot has n = 0)
        desired = sim.arm_reference()
        step = self.goals.segment_start(now_ns, desired, (q.copy(), u.copy()), apply)
        if step.feedback is not None and step.feedback[0].handle is not None and self.available:
            request, desired_now, actual, error = step.feedback
            feedback = self._type.Feedback(joint_names=self.names)
            feedback.header.stamp = time_msg(now_ns)
            feedback.desired = trajectory_point(*desired_now)
            feedback.actual = trajectory_point(*actual)
            feedback.error = trajectory_point(*error)
            try:
                request.handle.publish_feedback(feedback)
            except Exception:   # RCLError: the goal's handle went with a shutdown or its end
                if self.node.context.ok() and not request.finished.is_set():
                    raise
        if self._state_pub is not None:
            error = errors(desired, (q, u))
            state = self._state_type(joint_names=self.names)
            state.header.stamp = time_msg(now_ns)
            state.reference = trajectory_point(*desired)
            state.feedback = trajectory_point(q, u)
            state.error = trajectory_point(*error)
            state.output = trajectory_point([], efforts=np.asarray(sim.joint_efforts_applied()))
            self._state_pub.publish(state)
        if step.finished:
            self._report_topic()
        return step

    def _report_topic(self) -> None:
        """Say why a topic trajectory ended other than by reaching its goal (throttled)."""
        with self._lock:
            ended = [r for r in self._topic_requests if r.finished.is_set()]
            self._topic_requests = [r for r in self._topic_requests if not r.finished.is_set()]
        for request in ended:
            outcome = request.outcome
            if outcome.code != self.goals.codes.successful:
                self._warn(("trajectory", outcome.code),
                           f"{relative(TRAJECTORY_TOPIC)}: {outcome.text}")

    def destroy(self) -> None:
        """Destroy the action server (idempotent): rclpy's destroy_node leaves a node's
        waitables alone, and the server's handle kept the node's alive (and in the ROS graph,
        under its name) after destroy_node and the context's shutdown, until the garbage
        collector found the node object."""
        if self._action is not None:
            self._action.destroy()
            self._action = None

    def start(self) -> None:
        """After __init__'s log lines: say once when the action is off."""
        if not self.available:
            self._info("arm_controller joint_trajectory: control_msgs does not import (source a "
                       "ROS install, or run tools/bootstrap.sh, which builds it into .venv); no "
                       "follow_joint_trajectory action or controller_state, the "
                       "joint_trajectory topic works")
