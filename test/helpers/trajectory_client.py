"""A FollowJointTrajectory client as a ROS user writes one (rclpy.action.ActionClient), run in
its own process by test_arm_node.py with control_msgs on its paths. Each scenario named on the
command line prints one JSON line: the results, feedback counts and errors the test checks.

    python trajectory_client.py follow wrong_joints out_of_stroke old_header path_tolerance \
        goal_tolerance preempt cancel paused reset huge_revolute flood failed_segment
"""
import json
import sys
import time

import rclpy
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointTolerance
from rclpy.action import ActionClient
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectoryPoint

ACTION = "/joint_trajectory_controller/follow_joint_trajectory"
NAMES = ["arm_revolute_1", "arm_prismatic_1", "arm_revolute_2", "arm_prismatic_2"]
TIMEOUT = 60.0   # s of wall time for any one wait
GOAL_TOLERANCE = 0.01


def duration(seconds: float) -> Duration:
    return Duration(sec=int(seconds), nanosec=round((seconds - int(seconds)) * 1e9))


def goal(points, names=NAMES, tolerance=GOAL_TOLERANCE):
    """A goal through ``points`` ((time_from_start, positions), ...), joints ``names``."""
    message = FollowJointTrajectory.Goal()
    message.trajectory.joint_names = list(names)
    for seconds, positions in points:
        message.trajectory.points.append(JointTrajectoryPoint(
            positions=[float(v) for v in positions], time_from_start=duration(seconds)))
    message.goal_tolerance = [JointTolerance(name=name, position=tolerance) for name in names]
    return message


class Client:
    def __init__(self):
        self.node = rclpy.create_node("trajectory_test_client")
        self.action = ActionClient(self.node, FollowJointTrajectory, ACTION)
        self.feedback = []
        self.state = None
        self.node.create_subscription(JointState, "/joint_states", self._on_state, 10)

    def _on_state(self, message):
        self.state = message

    def spin_until(self, done, what):
        end = time.monotonic() + TIMEOUT
        while not done():
            if time.monotonic() > end:
                raise TimeoutError(what)
            rclpy.spin_once(self.node, timeout_sec=0.05)

    def send(self, message):
        """The accepted goal's handle (its feedback is appended to self.feedback)."""
        future = self.action.send_goal_async(message, feedback_callback=self.feedback.append)
        self.spin_until(future.done, "the goal's acceptance")
        handle = future.result()
        assert handle.accepted
        return handle

    def result(self, handle):
        future = handle.get_result_async()
        self.spin_until(future.done, "the goal's result")
        response = future.result()
        return {"status": response.status, "code": response.result.error_code,
                "text": response.result.error_string}

    def wait_simulated(self, seconds: float) -> None:
        """Spin until /joint_states is ``seconds`` of simulated time further on."""
        def now():
            return self.state.header.stamp.sec + self.state.header.stamp.nanosec * 1e-9
        start = now()
        self.spin_until(lambda: now() >= start + seconds, f"{seconds} s of simulated time")

    def arm_positions(self):
        index = {name: i for i, name in enumerate(self.state.name)}
        return [self.state.position[index[name]] for name in NAMES]


def follow(client):
    """Three points, then the result, the feedback and the final error."""
    client.feedback.clear()
    points = [(1.0, [0.5, 0.4, -0.1, 0.6]), (2.0, [0.7, 0.3, 0.1, 0.7]),
              (3.0, [0.6, 0.45, 0.2, 0.55])]
    outcome = client.result(client.send(goal(points)))
    client.spin_until(lambda: client.state is not None, "a joint state")
    last = client.feedback[-1].feedback
    return {**outcome, "feedback": len(client.feedback),
            "feedback_names": list(last.joint_names), "last_error": list(last.error.positions),
            "final": client.arm_positions(), "target": points[-1][1]}


def wrong_joints(client):
    return client.result(client.send(goal([(1.0, [0.0] * 4)],
                                          names=NAMES[:3] + ["arm_elbow"])))


def out_of_stroke(client):
    return client.result(client.send(goal([(1.0, [0.3, 0.5, -0.2, 0.5]),
                                           (2.0, [0.3, 1.5, -0.2, 0.5])])))


def old_header(client):
    """A trajectory stamped 1 ns after t = 0 that ended 0.5 s later: long past by now."""
    message = goal([(0.5, [0.3, 0.5, -0.2, 0.5])])
    message.trajectory.header.stamp.nanosec = 1
    return client.result(client.send(message))


def path_tolerance(client):
    """A fast swing with a tight path tolerance on rod 2: aborted, the arm held."""
    message = goal([(0.2, [0.9, 0.5, 0.6, 0.5])])
    message.path_tolerance = [JointTolerance(name="arm_revolute_2", position=1e-4)]
    return client.result(client.send(message))


def goal_tolerance(client):
    """A goal tolerance of 1e-9 m, 0.1 s of goal_time_tolerance: not reached in time."""
    message = goal([(0.5, [0.3, 0.5, -0.2, 0.5])], tolerance=1e-9)
    message.goal_time_tolerance = duration(0.1)
    return client.result(client.send(message))


def preempt(client):
    """A slow goal, preempted by a quick one once it has given feedback."""
    client.feedback.clear()
    first = client.send(goal([(5.0, [0.0, 0.3, 0.0, 0.3])]))
    client.spin_until(lambda: len(client.feedback) >= 5, "the first goal's feedback")
    second = client.send(goal([(1.0, [0.3, 0.5, -0.2, 0.5])]))
    return {"first": client.result(first), "second": client.result(second)}


def cancel(client):
    """A slow goal canceled mid-way; then where the arm is: right after, 1 s and 1.5 s later."""
    client.feedback.clear()
    handle = client.send(goal([(4.0, [0.8, 0.2, 0.4, 0.8])]))
    client.spin_until(lambda: len(client.feedback) >= 30, "feedback before the cancel")
    future = handle.cancel_goal_async()
    client.spin_until(future.done, "the cancel's answer")
    outcome = client.result(handle)
    after = client.arm_positions()
    client.wait_simulated(1.0)
    later = client.arm_positions()
    client.wait_simulated(0.5)
    return {**outcome, "canceling": len(future.result().goals_canceling), "after": after,
            "later": later, "rest": client.arm_positions(), "goal": [0.8, 0.2, 0.4, 0.8]}


def reset(client):
    """A slow goal, then ~/reset: the goal ends (INVALID_GOAL) and the arm is back at t = 0."""
    from std_srvs.srv import Trigger
    service = client.node.create_client(Trigger, "/mobile_manip_sim/reset")
    handle = client.send(goal([(5.0, [0.0, 0.3, 0.0, 0.3])]))
    client.feedback.clear()
    client.spin_until(lambda: len(client.feedback) >= 5, "feedback before the reset")
    future = service.call_async(Trigger.Request())
    client.spin_until(future.done, "the reset's answer")
    return client.result(handle)


def paused(client):
    """A goal active and another waiting to preempt it while the node is paused: both execute
    callbacks wait, and the services still answer (the resume does; then the second wins)."""
    from std_srvs.srv import SetBool
    service = client.node.create_client(SetBool, "/mobile_manip_sim/pause")
    client.feedback.clear()
    first = client.send(goal([(5.0, [0.0, 0.3, 0.0, 0.3])]))
    client.spin_until(lambda: len(client.feedback) >= 5, "the first goal's feedback")
    answers = []
    for data in (True, False):
        if not data:
            second = client.send(goal([(1.0, [0.3, 0.5, -0.2, 0.5])]))
        future = service.call_async(SetBool.Request(data=data))
        client.spin_until(future.done, "the pause service's answer")
        answers.append(future.result().success)
    return {"answers": answers, "first": client.result(first), "second": client.result(second)}


def huge_revolute(client):
    """Revolute targets no integrator can follow (1e6 rad up to the largest doubles, both
    signs): each answered at once."""
    return {"results": [client.result(client.send(goal([(1.0, [value, 0.5, 0.0, 0.5])])))
                        for value in (1e6, 1e300, 1e308, -1e308)]}


def failed_segment(client):
    """A 30 s goal running when 1e300 N·m on the wheels (finite, so taken) overflow the state:
    the goal's result, then ~/reset (the node runs again, efforts zero)."""
    from std_msgs.msg import Float64MultiArray
    from std_srvs.srv import Trigger
    wheels = client.node.create_publisher(Float64MultiArray, "/wheel_effort_controller/commands",
                                          10)
    service = client.node.create_client(Trigger, "/mobile_manip_sim/reset")
    client.feedback.clear()
    handle = client.send(goal([(30.0, [0.0, 0.3, 0.0, 0.3])]))
    client.spin_until(lambda: len(client.feedback) >= 3 and wheels.get_subscription_count() > 0,
                      "the goal's feedback and the wheel command subscription")
    wheels.publish(Float64MultiArray(data=[1e300, 1e300]))
    outcome = client.result(handle)
    future = service.call_async(Trigger.Request())
    client.spin_until(future.done, "the reset's answer")
    return {**outcome, "reset": future.result().success}


def flood(client, count: int = 40):
    """``count`` goals sent at once, none awaited: each is rejected or gets its result. The
    client keeps every answer (rclpy's default depth of 10 would drop its own)."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    deep = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    action = ActionClient(client.node, FollowJointTrajectory, ACTION,
                          goal_service_qos_profile=deep, result_service_qos_profile=deep)
    client.spin_until(lambda: action.server_is_ready(), "the server, for the flood")
    futures = [action.send_goal_async(goal([(0.2, [0.1 * (i % 3), 0.4, 0.0, 0.4])]))
               for i in range(count)]
    client.spin_until(lambda: all(f.done() for f in futures), "every goal's acceptance")
    handles = [f.result() for f in futures]
    results = [h.get_result_async() for h in handles if h.accepted]
    client.spin_until(lambda: all(r.done() for r in results), "every accepted goal's result")
    return {"rejected": sum(not h.accepted for h in handles), "accepted": len(results),
            "statuses": sorted({r.result().status for r in results})}


def paced_flood(client, count: int = 500, rate: float = 100.0, wait: float = 30.0):
    """``count`` goals sent ``rate`` per second, none awaited: how many got an answer
    (accepted or rejected) within ``wait`` s after the last, and each answer's delay."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    deep = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    action = ActionClient(client.node, FollowJointTrajectory, ACTION,
                          goal_service_qos_profile=deep, result_service_qos_profile=deep)
    client.spin_until(lambda: action.server_is_ready(), "the server, for the paced flood")
    futures, sent = [], []
    due = time.monotonic()
    for i in range(count):
        futures.append(action.send_goal_async(goal([(0.2, [0.1 * (i % 3), 0.4, 0.0, 0.4])])))
        sent.append(time.monotonic())
        due += 1.0 / rate
        while time.monotonic() < due:
            rclpy.spin_once(client.node, timeout_sec=max(0.0, due - time.monotonic()))
    end = time.monotonic() + wait
    while not all(f.done() for f in futures) and time.monotonic() < end:
        rclpy.spin_once(client.node, timeout_sec=0.05)
    handles = [f.result() for f in futures if f.done()]
    return {"sent": count, "answered": len(handles),
            "accepted": sum(h.accepted for h in handles),
            "rejected": sum(not h.accepted for h in handles)}


def main(scenarios) -> int:
    rclpy.init()
    client = Client()
    if not client.action.wait_for_server(timeout_sec=TIMEOUT):
        raise TimeoutError("the follow_joint_trajectory server")
    for name in scenarios:
        print(json.dumps({"scenario": name, **globals()[name](client)}), flush=True)
    client.node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
