"""The node's arm controllers as a ROS user drives them: the `simulator` executable in
its own process, real DDS, a real rclpy ActionClient in another (trajectory_client.py), with
control_msgs built from its definitions (the session fixture `interfaces_prefix`). Runs are
recorded and `replay --resimulate` must reproduce them bit for bit."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from std_msgs.msg import Float64MultiArray

import interfaces_build
from executables import executable
from ros_harness import NodeProcess, child_env, on_domain, private_domain, spinning
from test_node import FAST, Probe, wait_for

DOMAIN_ID = private_domain(200, 232)   # test_node.py 100-199; 232 is the highest Fast DDS takes
CLIENT = os.path.join(os.path.dirname(__file__), "..", "helpers", "trajectory_client.py")
NAMES = ["arm_revolute_1", "arm_prismatic_1", "arm_revolute_2", "arm_prismatic_2"]
STARTUP_TIMEOUT = 90.0
SUCCEEDED, CANCELED, ABORTED = 4, 5, 6   # action_msgs/GoalStatus


@pytest.fixture(scope="module")
def probe():
    with on_domain(DOMAIN_ID), spinning(Probe, DOMAIN_ID) as probe:
        yield probe


def start(tmp_path, env, *args, probe=None) -> NodeProcess:
    """A node with ``args``, up and running; ``probe`` forgets what earlier nodes published."""
    if probe is not None:
        with probe.lock:
            probe.joints.clear()
    node = NodeProcess(tmp_path, *FAST, *args, env=env)
    wait_for(lambda: not node.running() or "publishing at" in node.output(),
             "the node's start-up line", STARTUP_TIMEOUT)
    assert node.running(), node.output()
    return node


def resimulate(bag) -> str:
    result = subprocess.run([executable("replay"), str(bag), "--resimulate"],
                            env=child_env(DOMAIN_ID), capture_output=True, text=True, timeout=300)
    assert result.returncode == 0 and "IDENTICAL" in result.stdout, result.stdout + result.stderr
    return result.stdout


def test_a_follow_joint_trajectory_client_gets_jtcs_answers_and_the_run_resimulates(
        interfaces_prefix, tmp_path):
    env = child_env(DOMAIN_ID)
    bag = tmp_path / "trajectory_run"
    node = start(tmp_path, env, "-p", "arm_controller:=joint_trajectory", "-p", f"record:={bag}")
    try:
        client = subprocess.run([sys.executable, CLIENT, "follow", "wrong_joints",
                                 "out_of_stroke", "old_header", "path_tolerance",
                                 "goal_tolerance", "preempt", "cancel", "paused", "reset"],
                                env=env,
                                capture_output=True, text=True, timeout=600)
    finally:
        code = node.stop()
    assert client.returncode == 0, client.stderr + node.output()
    assert code == 0, node.output()
    results = {r.pop("scenario"): r for r in map(json.loads, client.stdout.splitlines())}
    print(json.dumps(results))

    follow = results["follow"]
    assert (follow["status"], follow["code"]) == (SUCCEEDED, 0), follow
    assert follow["feedback"] >= 100 and follow["feedback_names"] == NAMES   # 3 s at 100 Hz
    for final, target in zip(follow["final"], follow["target"], strict=True):
        assert abs(final - target) <= 0.01   # the goal tolerance the client set

    wrong = results["wrong_joints"]
    assert (wrong["status"], wrong["code"]) == (ABORTED, -2), wrong   # INVALID_JOINTS
    assert "arm_elbow" in wrong["text"]
    stroke = results["out_of_stroke"]
    assert (stroke["status"], stroke["code"]) == (ABORTED, -1), stroke   # INVALID_GOAL
    assert stroke["text"].startswith("arm_prismatic_1: 1.5 m is outside the stroke"), stroke
    assert "\n" not in stroke["text"]

    old = results["old_header"]
    assert (old["status"], old["code"]) == (ABORTED, -3), old   # OLD_HEADER_TIMESTAMP
    path = results["path_tolerance"]
    assert (path["status"], path["code"]) == (ABORTED, -4), path   # PATH_TOLERANCE_VIOLATED
    assert "arm_revolute_2 position error" in path["text"], path

    late = results["goal_tolerance"]
    assert (late["status"], late["code"]) == (ABORTED, -5), late   # GOAL_TOLERANCE_VIOLATED
    assert "(goal_time 0.1 s)" in late["text"], late

    preempt = results["preempt"]
    # canceled with INVALID_GOAL, as joint_trajectory_controller ends a preempted goal
    assert (preempt["first"]["status"], preempt["first"]["code"]) == (CANCELED, -1), preempt
    assert preempt["first"]["text"] == "preempted by a new goal"
    assert (preempt["second"]["status"], preempt["second"]["code"]) == (SUCCEEDED, 0), preempt

    cancel = results["cancel"]
    assert cancel["status"] == CANCELED and cancel["canceling"] == 1, cancel
    # Held where it was: it had moved; it comes to rest within a brake's distance of where the
    # cancel found it, far from the canceled goal.
    def apart(a, b):
        return max(abs(x - y) for x, y in zip(a, b, strict=True))
    assert apart(cancel["after"], [0.3, 0.5, -0.2, 0.5]) > 0.01
    assert apart(cancel["later"], cancel["rest"]) < 1e-4
    assert apart(cancel["after"], cancel["rest"]) < 0.02
    assert apart(cancel["rest"], cancel["goal"]) > 0.1

    paused = results["paused"]
    assert paused["answers"] == [True, True], paused
    assert paused["first"]["text"] == "preempted by a new goal", paused
    assert (paused["second"]["status"], paused["second"]["code"]) == (SUCCEEDED, 0), paused

    reset = results["reset"]
    assert (reset["status"], reset["code"], reset["text"]) == (
        ABORTED, -1, "the simulation was reset"), reset

    # The time line up to the reset (the bag goes on in trajectory_run_1 after it).
    assert "IDENTICAL" in resimulate(bag)


def test_a_position_mode_run_holds_its_set_point_and_resimulates(probe, tmp_path):
    """Position set-points on arm_position_controller/commands: the arm goes there and holds
    against gravity (/joint_states carries the controller's efforts); one beyond a stroke is
    refused in one line and the last kept; the bag re-simulates."""
    bag = tmp_path / "position_run"
    publisher = probe.node.create_publisher(Float64MultiArray,
                                            "/arm_position_controller/commands", 10)
    node = start(tmp_path, child_env(DOMAIN_ID), "-p", "arm_controller:=position",
                 "-p", f"record:={bag}", "-r", "__node:=position_sim", probe=probe)
    target = [0.5, 0.4, 0.1, 0.6]
    try:
        wait_for(lambda: publisher.get_subscription_count() > 0, "the position subscription")
        publisher.publish(Float64MultiArray(data=[0.4, 0.45, 0.0, 0.55]))
        stamp = wait_for(lambda: probe.snapshot("joints"), "a joint state")[-1][0]
        wait_for(lambda: probe.snapshot("joints")[-1][0] > stamp + 10 ** 8, "0.1 s more")
        publisher.publish(Float64MultiArray(data=[0.5, 1.5, 0.1, 0.6]))   # beyond rod 1's stroke
        wait_for(lambda: "outside the stroke" in node.output(), "the refusal")
        publisher.publish(Float64MultiArray(data=target))

        def settled():
            joints = probe.snapshot("joints")
            if not joints:
                return False
            stamp, positions, _, efforts, names = joints[-1]
            index = {name: i for i, name in enumerate(names)}
            arm = [positions[index[name]] for name in NAMES]
            return all(abs(a - b) < 1e-3 for a, b in zip(arm, target, strict=True)) and \
                abs(efforts[index["arm_prismatic_1"]]) > 1.0   # holding the rods up
        wait_for(settled, "the arm at its set-point", 60.0)
    finally:
        probe.node.destroy_publisher(publisher)
        assert node.stop() == 0, node.output()
    refusals = [line for line in node.output().splitlines() if "outside the stroke" in line]
    assert len(refusals) == 1 and "arm_position_controller/commands: arm_prismatic_1: 1.5 m is " \
        "outside the stroke [0, 1]" in refusals[0] and "keeping the last set-point" in refusals[0]
    assert "IDENTICAL" in resimulate(bag)


def test_a_velocity_mode_run_moves_at_its_rates_stops_and_resimulates(probe, tmp_path):
    """Rates on arm_velocity_controller/commands, then zero: the arm moves, stops where it got
    to, and the bag (each array as applied, the gains in its metadata) re-simulates."""
    bag = tmp_path / "velocity_run"
    publisher = probe.node.create_publisher(Float64MultiArray,
                                            "/arm_velocity_controller/commands", 10)
    node = start(tmp_path, child_env(DOMAIN_ID), "-p", "arm_controller:=velocity",
                 "-p", f"record:={bag}", "-p", "arm_feedforward:=computed_torque",
                 "-p", "arm_gains.ki:=0.0", "-r", "__node:=velocity_arm_sim", probe=probe)
    try:
        wait_for(lambda: publisher.get_subscription_count() > 0, "the velocity subscription")
        start_stamp = wait_for(lambda: probe.snapshot("joints"), "a joint state")[-1][0]
        publisher.publish(Float64MultiArray(data=[0.2, 0.0, -0.2, 0.1]))
        wait_for(lambda: probe.snapshot("joints")[-1][0] > start_stamp + 10 ** 9,
                 "1 s of simulated time")
        publisher.publish(Float64MultiArray(data=[0.0] * 4))
        stopped = probe.snapshot("joints")[-1][0]
        wait_for(lambda: probe.snapshot("joints")[-1][0] > stopped + 10 ** 9, "1 s more")
        _, positions, velocities, _, names = probe.snapshot("joints")[-1]
        index = {name: i for i, name in enumerate(names)}
        assert positions[index["arm_revolute_1"]] > 0.3 + 0.1   # it moved up from 0.3 rad
        assert max(abs(velocities[index[name]]) for name in NAMES) < 1e-3   # and stopped
    finally:
        probe.node.destroy_publisher(publisher)
        assert node.stop() == 0, node.output()
    assert "IDENTICAL" in resimulate(bag)


def test_the_default_node_holds_the_initial_pose_then_follows_a_trajectory(probe, tmp_path):
    """No arm_controller parameter: joint_trajectory, the arm holding its initial pose from the
    first state on (the gravity feed-forward holds it exactly up to rounding: 1e-9 over 0.5 s),
    then following a trajectory from the topic; the start-up line names the mode."""
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
    publisher = probe.node.create_publisher(JointTrajectory,
                                            "/joint_trajectory_controller/joint_trajectory", 10)
    node = start(tmp_path, child_env(DOMAIN_ID), "-r", "__node:=default_arm_sim", probe=probe)
    target = [0.2, 0.6, -0.3, 0.4]
    try:
        first = wait_for(lambda: probe.snapshot("joints"), "a joint state")[0]
        wait_for(lambda: probe.snapshot("joints")[-1][0] >= first[0] + 5 * 10 ** 8,
                 "0.5 s of states")
        held = probe.snapshot("joints")
        wait_for(lambda: publisher.get_subscription_count() > 0, "the trajectory subscription")
        message = JointTrajectory(joint_names=NAMES)
        point = JointTrajectoryPoint(positions=target)
        point.time_from_start.sec = 1
        message.points.append(point)
        publisher.publish(message)
        wait_for(lambda: _ended(probe, target), "the arm at the trajectory's end", 60.0)
    finally:
        probe.node.destroy_publisher(publisher)
        assert node.stop() == 0, node.output()

    def arm(state):
        index = {name: i for i, name in enumerate(state[4])}
        return [state[1][index[name]] for name in NAMES]
    assert arm(first) == [0.3, 0.5, -0.2, 0.5]   # the paper scene's initial pose
    drift = max(abs(a - b) for state in held for a, b in zip(arm(state), arm(first), strict=True))
    assert drift < 1e-9 and len(held) >= 50
    output = node.output()
    assert "arm_controller joint_trajectory" in next(
        line for line in output.splitlines() if "publishing at" in line)


def test_an_armless_robot_runs_under_the_trajectory_controller_with_control_msgs(
        interfaces_prefix, probe, tmp_path):
    """A robot without an arm, arm_controller joint_trajectory (the default), control_msgs
    installed: the base steps on, and the controller's state names no joint (the arm's slice
    taken as q[-n:] was the whole q for n = 0: the simulation paused at t = 0)."""
    import yaml
    from control_msgs.msg import JointTrajectoryControllerState

    from engine_cases import base_only_doc
    states = []
    subscription = probe.node.create_subscription(
        JointTrajectoryControllerState, "/joint_trajectory_controller/controller_state",
        states.append, 10)
    path = tmp_path / "base.yaml"
    path.write_text(yaml.safe_dump(base_only_doc()))
    node = start(tmp_path, child_env(DOMAIN_ID), "-p", f"scene:={path}", "-r",
                 "__node:=armless_sim", probe=probe)
    try:
        first = wait_for(lambda: probe.snapshot("joints"), "a joint state")[0]
        wait_for(lambda: probe.snapshot("joints")[-1][0] >= first[0] + 2 * 10 ** 8,
                 "0.2 s of states")
        wait_for(lambda: states, "a controller state")
    finally:
        probe.node.destroy_subscription(subscription)
        assert node.stop() == 0, node.output()
    assert "simulation failed" not in node.output(), node.output()
    assert list(states[0].joint_names) == [] and list(states[0].feedback.positions) == []


def test_without_control_msgs_the_topic_works_and_the_node_says_so_once(probe, tmp_path):
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
    publisher = probe.node.create_publisher(JointTrajectory,
                                            "/joint_trajectory_controller/joint_trajectory", 10)
    node = start(tmp_path, interfaces_build.without(child_env(DOMAIN_ID)),
                 "-p", "arm_controller:=joint_trajectory", "-r", "__node:=topic_sim", probe=probe)
    target = [0.2, 0.6, -0.3, 0.4]
    try:
        wait_for(lambda: publisher.get_subscription_count() > 0, "the trajectory subscription")
        message = JointTrajectory(joint_names=[NAMES[i] for i in (3, 2, 1, 0)])
        point = JointTrajectoryPoint(positions=[target[i] for i in (3, 2, 1, 0)])
        point.time_from_start.sec = 1
        message.points.append(point)
        publisher.publish(message)

        wait_for(lambda: _ended(probe, target), "the arm at the trajectory's end", 60.0)
    finally:
        probe.node.destroy_publisher(publisher)
        assert node.stop() == 0, node.output()
    lines = [line for line in node.output().splitlines() if "control_msgs does not import" in line]
    assert len(lines) == 1, node.output()


def test_a_headless_scene_with_a_trajectory_gives_the_samples_of_the_node_driven_by_it(
        probe, tmp_path):
    """The paper robot at rest, no efforts. The node takes a trajectory on its topic and records
    when it applied (t_a); a headless Simulation of the same scene with the trajectory in its
    `controller:` section (applied at t = 0) gives, at s, the state the node published at
    t_a + s. Before t_a the node holds the initial pose, which the gravity feed-forward holds
    exactly up to rounding: hence a tolerance of 1e-9 rather than bit equality. Both at the
    default control rate: the node applies the command it received at an update instant before
    that update, as the headless scene takes its command at t = 0 at the first."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    from mobile_manip_sim.engine.simulation import Simulation
    from mobile_manip_sim.scene.loading import load_scene

    text = (Path(__file__).resolve().parents[2] / "config" / "paper_two_link.yaml").read_text()
    for old, new in (("efforts: {wheels: [0.1, 0.2], joints: [4.5, 7.0, 0.0, 1.0]}",
                      "efforts: {wheels: [0.0, 0.0], joints: [0.0, 0.0, 0.0, 0.0]}"),
                     ("integrator: {method: dop853, rtol: 1.0e-10, atol: 1.0e-12}",
                      "integrator: {method: rk4, dt: 0.001}")):
        assert old in text
        text = text.replace(old, new)
    points = [(1, [0.5, 0.4, -0.1, 0.6]), (2, [0.6, 0.45, 0.2, 0.55])]
    node_scene, headless_scene = tmp_path / "node.yaml", tmp_path / "headless.yaml"
    node_scene.write_text(text)
    headless_scene.write_text(text + "controller:\n  arm: joint_trajectory\n  trajectory:\n"
                              "    points:\n" + "".join(
                                  f"      - {{time_from_start: {t}.0, positions: {p}}}\n"
                                  for t, p in points))
    bag = tmp_path / "node_run"
    publisher = probe.node.create_publisher(JointTrajectory,
                                            "/joint_trajectory_controller/joint_trajectory", 10)
    node = start(tmp_path, child_env(DOMAIN_ID), "-p", f"scene:={node_scene}",
                 "-p", "arm_controller:=joint_trajectory", "-p", f"record:={bag}",
                 "-r", "__node:=headless_twin", probe=probe)
    try:
        wait_for(lambda: publisher.get_subscription_count() > 0, "the trajectory subscription")
        message = JointTrajectory(joint_names=NAMES)
        for seconds, positions in points:
            point = JointTrajectoryPoint(positions=[float(v) for v in positions])
            point.time_from_start.sec = seconds
            message.points.append(point)
        publisher.publish(message)
        wait_for(lambda: _ended(probe, points[-1][1]), "the arm at the trajectory's end", 60.0)
    finally:
        probe.node.destroy_publisher(publisher)
        assert node.stop() == 0, node.output()
    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as reader:
        applied = [stamp for connection, stamp, _ in reader.messages()
                   if connection.topic == "/joint_trajectory_controller/joint_trajectory"]
        states = [store.deserialize_cdr(data, "sensor_msgs/msg/JointState")
                  for connection, _, data in reader.messages()
                  if connection.topic == "/joint_states"]
    assert len(applied) == 1, applied
    sim = Simulation(load_scene(str(headless_scene)))
    compared, largest = 0, 0.0
    for state in states:
        stamp = state.header.stamp.sec * 10 ** 9 + state.header.stamp.nanosec
        if stamp < applied[0]:
            continue
        sim.advance_to((stamp - applied[0]) / 1e9)
        difference = max(abs(a - b) for a, b in zip(state.position, sim.q[3:], strict=True))
        assert difference < 1e-9, (stamp, list(state.position), sim.q[3:].tolist())
        largest = max(largest, difference)
        compared += 1
    assert compared >= 200   # 2 s of the trajectory at 100 Hz
    print(f"{compared} states from t_a = {applied[0]} ns: largest difference {largest:.3g}")


def _ended(probe, target) -> bool:
    """The latest /joint_states has the arm within 2 mm or mrad of ``target``."""
    joints = probe.snapshot("joints")
    if not joints:
        return False
    _, positions, _, _, names = joints[-1]
    index = {name: i for i, name in enumerate(names)}
    return all(abs(positions[index[n]] - t) < 2e-3 for n, t in zip(NAMES, target, strict=True))


def test_the_arm_command_message_is_built_only_for_a_bag(monkeypatch):
    """The node builds an applied command's message for its bag only: a 100,000-point
    trajectory's took the stepping thread about a second, /clock stopped meanwhile, without
    any bag to write it to."""
    from mobile_manip_sim.engine.simulation import Simulation
    from mobile_manip_sim.node import arm as arm_module
    from mobile_manip_sim.scene.arm_controller import ArmController
    from mobile_manip_sim.scene.loading import load_scene
    built = []
    monkeypatch.setattr(arm_module, "arm_command_message",
                        lambda *args: built.append(args) or "the message")
    driver = arm_module.ArmDriver(None, "position", NAMES, warn=lambda *args: None, info=print)
    sim = Simulation(load_scene(), arm_controller=ArmController("position"))
    made = driver.segment_start(sim, 0, sim.q[-len(NAMES):] + 0.01, received=1)
    assert built == []
    assert made() == "the message" and len(built) == 1
