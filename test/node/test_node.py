"""The `simulator` node as users run it: the installed executable in its own process, real DDS,
and a probe node in this process that publishes efforts, calls the services and records what
comes back. Every wait is on a condition with a timeout; a random ROS_DOMAIN_ID (and localhost
discovery) keeps concurrent runs apart."""
import itertools
import math
import os
import re
import signal
import subprocess
import threading
import time

import numpy as np
import pytest
import rclpy
from nav_msgs.msg import Odometry
from rclpy.context import Context
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import SetBool, Trigger

from executables import executable
from hostile_yaml import ALIAS_BOMB
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.ros.messages import yaw_quaternion
from mobile_manip_sim.scene.loading import load_scene, make_integrator
from ros_harness import NodeProcess, on_domain, private_domain, spinning
from ros_harness import child_env as ros_child_env
from ros_harness import cpu_seconds as process_cpu_seconds
from ros_harness import wait_for as harness_wait_for

DOMAIN_ID = private_domain(100, 199)
HELPERS = os.path.join(os.path.dirname(__file__), "..", "helpers")
SIMULATOR = executable("simulator")
RATE = 100                       # publish_rate (Hz) of the shared node
PERIOD_NS = 10 ** 9 // RATE
FAST = ["-p", "integrator.method:=rk4", "-p", "integrator.dt:=0.001",
        "-p", "real_time_factor:=5.0"]
# The arm takes efforts where a test sends them: the node's default arm controller holds the
# initial pose (joint_trajectory, test_arm_node.py) and takes no efforts.
EFFORT_ARM = ["-p", "arm_controller:=effort"]
TIMEOUT = 20.0                   # s of wall time for any one condition
STARTUP_TIMEOUT = 60.0           # a net for a loaded machine, not a figure
RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)

def ns(stamp) -> int:
    return stamp.sec * 10 ** 9 + stamp.nanosec


def child_env() -> dict:
    return ros_child_env(DOMAIN_ID)


def wait_for(predicate, what: str, timeout: float = TIMEOUT):
    """Poll `predicate` until it returns something other than None, False or an empty sequence
    (an index 0 counts as found); fail naming `what` after `timeout`. Returns that value."""
    return harness_wait_for(predicate, what, timeout)


class Probe:
    """A test node: records every /joint_states, /odom and /clock, publishes efforts, calls the
    services. Records are appended in arrival order (one writer per topic keeps them ordered)."""

    def __init__(self, context: Context):
        self.node = rclpy.create_node("node_test_probe", context=context)
        self.lock = threading.Lock()
        self.joints, self.odom, self.clock = [], [], []
        self.node.create_subscription(JointState, "/joint_states", self._on_joints, RELIABLE)
        self.node.create_subscription(Odometry, "/odom", self._on_odom, RELIABLE)
        self.node.create_subscription(Clock, "/clock", self._on_clock, RELIABLE)
        self.wheels = self.node.create_publisher(Float64MultiArray,
                                                 "/wheel_effort_controller/commands", 10)
        self.arm = self.node.create_publisher(Float64MultiArray,
                                              "/arm_effort_controller/commands", 10)
        self.reset_client = self.node.create_client(Trigger, "/mobile_manip_sim/reset")
        self.pause_client = self.node.create_client(SetBool, "/mobile_manip_sim/pause")

    def _on_joints(self, msg):
        with self.lock:
            self.joints.append((ns(msg.header.stamp), tuple(msg.position), tuple(msg.velocity),
                                tuple(msg.effort), tuple(msg.name)))

    def _on_odom(self, msg):
        pose, twist = msg.pose.pose, msg.twist.twist
        with self.lock:
            self.odom.append((ns(msg.header.stamp), pose.position.x, pose.position.y,
                              pose.orientation.z, pose.orientation.w, twist.linear.x,
                              twist.angular.z, msg))

    def _on_clock(self, msg):
        with self.lock:
            self.clock.append(ns(msg.clock))

    def snapshot(self, name: str) -> list:
        with self.lock:
            return list(getattr(self, name))

    def connected(self) -> bool:
        return (self.wheels.get_subscription_count() > 0 and self.arm.get_subscription_count() > 0
                and self.reset_client.service_is_ready() and self.pause_client.service_is_ready())

    def send(self, wheels=None, arm=None) -> None:
        if wheels is not None:
            self.wheels.publish(Float64MultiArray(data=[float(v) for v in wheels]))
        if arm is not None:
            self.arm.publish(Float64MultiArray(data=[float(v) for v in arm]))

    def call(self, client, request):
        future = client.call_async(request)
        wait_for(future.done, f"a response from {client.srv_name}")
        return future.result()

    def pause(self, paused: bool):
        return self.call(self.pause_client, SetBool.Request(data=paused))

    def marks(self) -> dict:
        return {name: len(self.snapshot(name)) for name in ("joints", "odom")}

    def await_start(self, marks: dict) -> None:
        """Wait for the t = 0 messages that follow `marks`; run() starts there from now on."""
        self.starts = {}
        for name, mark in marks.items():
            self.starts[name] = wait_for(lambda name=name, mark=mark: index_of(
                self.snapshot(name), lambda record: record[0] == 0, mark), f"/{name} at t = 0")

    def reset(self) -> None:
        marks = self.marks()
        assert self.call(self.reset_client, Trigger.Request()).success
        self.await_start(marks)

    def run(self, name: str) -> list:
        """Records of `name` (joints or odom) since the last start or reset."""
        return self.snapshot(name)[self.starts[name]:]

    def wait_run(self, name: str, predicate, what: str, timeout: float = TIMEOUT):
        return wait_for(lambda: predicate(self.run(name)), what, timeout)


def SimulatorProcess(tmp_path, *args) -> NodeProcess:
    """The installed `simulator` executable on this module's domain, started as `ros2 run` does."""
    return NodeProcess(tmp_path, *args, env=child_env())


@pytest.fixture(scope="module")
def probe():
    with on_domain(DOMAIN_ID), spinning(Probe, DOMAIN_ID) as probe:
        yield probe


def start_simulator(probe, tmp_path, *args) -> SimulatorProcess:
    """Start a node; wait until it is connected and publishing. probe.run() then holds what
    arrived since the start (other nodes on the domain must be paused); the first messages may
    have gone out before discovery, so the run need not begin at t = 0. The arm takes efforts
    (EFFORT_ARM) unless ``args`` choose its controller: these tests drive the node by efforts
    and wait for its arm effort subscription (the default controller is test_arm_node's)."""
    if not any(str(arg).startswith("arm_controller:=") for arg in args):
        args = (*args, *EFFORT_ARM)
    marks = probe.marks()
    # Other nodes' counts are for nothing here: wait for this node's own subscriptions, to the
    # wheel efforts too unless its base takes velocity commands (it then has none)
    readers = [(probe.arm, probe.arm.get_subscription_count())]
    if "base_command:=velocity" not in args:
        readers.append((probe.wheels, probe.wheels.get_subscription_count()))
    simulator = SimulatorProcess(tmp_path, *args)
    try:
        wait_for(lambda: simulator.process.poll() is not None or (
            probe.connected()
            and all(publisher.get_subscription_count() > count for publisher, count in readers)
            and all(len(probe.snapshot(name)) > mark for name, mark in marks.items())),
            "the simulator's topics, services and first messages", STARTUP_TIMEOUT)
        assert simulator.process.poll() is None, simulator.output()
    except BaseException:
        simulator.stop()
        raise
    probe.starts = marks
    return simulator


@pytest.fixture(scope="module")
def simulator(probe, tmp_path_factory):
    """One node for most tests (command timeout off); each test starts with a reset."""
    simulator = start_simulator(probe, tmp_path_factory.mktemp("node"), *FAST, *EFFORT_ARM,
                                "-p", "command_timeout:=0.0")
    yield simulator
    code = simulator.stop()
    assert code == 0, f"exit status {code} after SIGTERM:\n{simulator.output()}"


@pytest.fixture
def fresh(probe, simulator):
    """A reset, running node; paused again afterwards so it idles between tests."""
    probe.pause(True)
    probe.reset()
    assert probe.pause(False).success
    yield probe
    assert simulator.process.poll() is None, simulator.output()
    probe.pause(True)


def efforts_equal(target):
    target = tuple(float(v) for v in target)
    return lambda record: record[3] == target


def index_of(records, predicate, start=0):
    return next((i for i in range(start, len(records)) if predicate(records[i])), None)


# --- timing -----------------------------------------------------------------------------------

def test_stamps_are_exact_multiples_of_the_period_with_no_gaps(fresh):
    for name in ("joints", "odom"):
        fresh.wait_run(name, lambda run: len(run) >= 150, f"150 /{name} messages")
    for name in ("joints", "odom"):
        stamps = [record[0] for record in fresh.run(name)]
        assert stamps == [k * PERIOD_NS for k in range(len(stamps))], f"/{name} stamps"
    clock = fresh.snapshot("clock")
    start = len(clock) - 1 - clock[::-1].index(0)
    ticks = clock[start:]
    assert ticks == [k * PERIOD_NS for k in range(len(ticks))]
    names = fresh.run("joints")[0][4]
    assert names == ("right_wheel_joint", "left_wheel_joint", "arm_revolute_1",
                     "arm_prismatic_1", "arm_revolute_2", "arm_prismatic_2")
    odom = fresh.run("odom")[0][7]
    assert (odom.header.frame_id, odom.child_frame_id) == ("odom", "base_footprint")
    covariance = np.array(odom.pose.covariance).reshape(6, 6)
    assert np.array_equal(covariance, np.diag(np.diag(covariance))) \
        and np.all(np.diag(covariance) > 0)


# --- motion -----------------------------------------------------------------------------------

def drive(probe, wheels, seconds):
    """Hold `wheels` from the start of a fresh run; the odometry records once `seconds` of
    simulated time have passed with them applied."""
    probe.send(wheels=wheels)
    applied = probe.wait_run("joints",
                             lambda run: index_of(run, lambda r: r[3][:2] == tuple(wheels)),
                             f"efforts {wheels} in /joint_states")
    t0 = probe.run("joints")[applied][0]
    probe.wait_run("odom", lambda run: run and run[-1][0] >= t0 + seconds * 1e9,
                   f"{seconds} s of driving")
    return [record for record in probe.run("odom") if record[0] >= t0]


def yaw(record):
    return 2.0 * math.atan2(record[3], record[4])


def test_equal_wheel_torques_drive_straight_ahead(fresh):
    odom = drive(fresh, [0.3, 0.3], 1.5)
    assert max(abs(yaw(r)) for r in odom) < 1e-9
    assert max(abs(r[2]) for r in odom) < 1e-9
    assert odom[-1][1] > odom[0][1] + 0.2 and odom[-1][5] > 0.0
    joints = [r for r in fresh.run("joints") if r[0] >= odom[0][0]]
    assert max(abs(r[1][0] - r[1][1]) for r in joints) < 1e-9   # θ_R = θ_L


def test_stronger_right_wheel_turns_left(fresh):
    odom = drive(fresh, [0.3, 0.1], 1.5)
    yaws = [yaw(r) for r in odom]
    assert yaws[-1] > yaws[0] + 0.1 and odom[-1][6] > 0.0
    assert all(later >= earlier - 1e-12 for earlier, later in itertools.pairwise(yaws))


# --- the node is an adapter: same numbers as the engine run headless --------------------------

def test_published_state_matches_a_headless_run_of_the_same_commands(fresh):
    commands = [([0.2, 0.1], [4.5, 7.0, 0.0, 1.0]), ([-0.1, 0.3], [0.0, 0.0, 0.5, -1.0]),
                ([0.0, 0.0], [1.0, 2.0, 0.0, 0.0])]
    for wheels, arm in commands:
        fresh.send(wheels=wheels, arm=arm)
        efforts = tuple(wheels + arm)
        fresh.wait_run("joints", lambda run, efforts=efforts: run and run[-1][3] == efforts,
                       f"efforts {wheels + arm}")
        segments = len(fresh.run("joints"))
        fresh.wait_run("joints", lambda run, n=segments: len(run) >= n + 20,
                       "20 more segments")
    fresh.pause(True)
    joints, odom = fresh.run("joints"), fresh.run("odom")
    count = min(len(joints), len(odom))
    assert [r[0] for r in joints[:count]] == [r[0] for r in odom[:count]] == \
        [k * PERIOD_NS for k in range(count)]
    assert len({r[3] for r in joints}) >= 4   # zero, then the three commands

    scene = load_scene(None)
    sim = Simulation(scene, make_integrator(scene.integrator, "rk4", 0.001))
    sim.set_efforts([0.0, 0.0], [0.0] * 4)
    for k in range(count):
        if k > 0:   # message k carries the efforts held during (t_{k-1}, t_k]
            sim.set_efforts(joints[k][3][:2], joints[k][3][2:])
            sim.advance_to(k / RATE)
        assert joints[k][1] == tuple(sim.q[3:].tolist()), f"positions at k = {k}"
        assert joints[k][2] == tuple(sim.qdot()[3:].tolist()), f"velocities at k = {k}"
        quaternion = yaw_quaternion(float(sim.q[2]))
        assert odom[k][1:7] == (sim.q[0], sim.q[1], quaternion.z, quaternion.w,
                                sim.u[0], sim.u[1]), f"odometry at k = {k}"


# --- services and timeout ---------------------------------------------------------------------

def test_reset_returns_to_the_initial_state_with_zero_efforts(fresh):
    drive(fresh, [0.3, 0.3], 0.5)
    fresh.reset()
    scene = load_scene(None)
    first = fresh.run("joints")[0]
    assert first[0] == 0
    assert first[1] == tuple(scene.initial_q[3:].tolist())
    assert first[2] == (0.0,) * 6 and first[3] == (0.0,) * 6
    odom = fresh.run("odom")[0]
    assert odom[1:7] == (0.0, 0.0, 0.0, 1.0, 0.0, 0.0)
    # The held command was cleared: efforts stay zero, and time runs on from 0.
    run = fresh.wait_run("joints", lambda run: len(run) >= 30 and run, "30 segments after reset")
    assert [r[0] for r in run] == [k * PERIOD_NS for k in range(len(run))]
    assert all(r[3] == (0.0,) * 6 for r in run)


def paused_at(response) -> int:
    seconds, nanos = re.search(r"t = (\d+)\.(\d{9}) s", response.message).groups()
    return int(seconds) * 10 ** 9 + int(nanos)


def test_pause_stops_time_and_resume_continues_without_a_gap(fresh):
    fresh.wait_run("joints", lambda run: len(run) >= 20, "20 segments")
    response = fresh.pause(True)
    assert response.success
    stop = paused_at(response)
    wait_for(lambda: fresh.snapshot("clock")[-1] == stop, "/clock to reach the pause time")
    count = len(fresh.snapshot("clock"))
    # While paused the node's time stands: a second ~/pause and the resume both report it, and
    # nothing arrived in between; after the resume /clock goes on from it without a gap.
    again = fresh.pause(True)
    assert "already paused" in again.message and paused_at(again) == stop
    quiet = fresh.snapshot("clock")[count - 1:]
    resumed = fresh.pause(False)
    assert resumed.success and "resumed" in resumed.message and paused_at(resumed) == stop
    assert quiet == [stop]
    wait_for(lambda: len(fresh.snapshot("clock")) > count + 5, "/clock to run again")
    assert fresh.snapshot("clock")[count - 1:count + 5] == [stop + k * PERIOD_NS for k in range(6)]


def test_command_timeout_zeroes_efforts_once_per_silence(probe, simulator, tmp_path):
    # The shared node idles (paused: it publishes nothing) while this one, under another node
    # name so that the services do not clash, runs on the same topics.
    probe.pause(True)
    node = start_simulator(probe, tmp_path, *FAST, *EFFORT_ARM, "-p", "command_timeout:=0.2",
                           "-r", "__node:=timeout_sim")
    try:
        wheels, arm = (0.3, 0.3), (1.0, 2.0, 3.0, 4.0)
        probe.send(wheels=wheels, arm=arm)
        on = probe.wait_run("joints", lambda run: index_of(run, efforts_equal(wheels + arm)),
                            "the commanded efforts")
        off = probe.wait_run("joints", lambda run: index_of(run, efforts_equal((0.0,) * 6), on),
                             "the efforts to time out")
        run = probe.run("joints")
        held = (run[off][0] - run[on][0]) / 1e9
        assert 0.2 - 2 / RATE <= held <= 0.2 + 2 / RATE
        warning = "no command for 0.2 s of simulated time"
        wait_for(lambda: node.output().count(warning) == 2, "one timeout warning per group")
        # A new command re-arms the timeout: efforts come back, then time out again.
        probe.send(wheels=wheels)
        again = probe.wait_run("joints",
                               lambda run: index_of(run, lambda r: r[3][:2] == wheels, off),
                               "the wheel efforts again")
        probe.wait_run("joints", lambda run: index_of(run, efforts_equal((0.0,) * 6), again),
                       "the second timeout")
        wait_for(lambda: node.output().count(warning) == 3, "a second wheel timeout warning")
        assert node.output().count(f"/wheel_effort_controller/commands: {warning}") == 2
    finally:
        code = node.stop()
    assert code == 0, node.output()


# --- bad input --------------------------------------------------------------------------------

def test_bad_commands_are_rejected_and_the_last_valid_one_kept(fresh, simulator):
    good, marker = (0.25, 0.25), (0.2, 0.2)
    fresh.send(wheels=good)
    first = fresh.wait_run("joints", lambda run: index_of(run, lambda r: r[3][:2] == good),
                           "the valid command")
    fresh.send(wheels=[1.0])
    fresh.send(wheels=[math.nan, 0.0])
    fresh.send(wheels=[0.0, math.inf])
    fresh.send(arm=[1.0, 2.0, 3.0])
    fresh.send(arm=[0.0, -math.inf, 0.0, math.nan])
    fresh.send(wheels=marker)   # same topic, so it arrives after the bad ones
    last = fresh.wait_run("joints", lambda run: index_of(run, lambda r: r[3][:2] == marker, first),
                          "the marker command")
    run = fresh.run("joints")
    assert all(r[3] == good + (0.0,) * 4 for r in run[first:last])
    for line in ("/wheel_effort_controller/commands: expected 2 values (tau_R, tau_L), got 1; "
                 "keeping the last valid command",
                 "/wheel_effort_controller/commands: contains NaN ([0] = nan)",
                 "/wheel_effort_controller/commands: contains Inf ([1] = inf)",
                 "/arm_effort_controller/commands: expected 4 values (tau_1, F_1, tau_2, F_2), "
                 "got 3",
                 "/arm_effort_controller/commands: contains NaN and Inf"):
        wait_for(lambda line=line: line in simulator.output(), f"the warning {line!r}")
    fresh.wait_run("joints", lambda run: len(run) > last + 20, "publishing to go on")
    assert simulator.process.poll() is None


def test_a_non_finite_state_pauses_the_node_until_reset(fresh, simulator):
    fresh.send(wheels=[1e300, 1e300])   # finite, so accepted; the state overflows
    wait_for(lambda: "simulation failed" in simulator.output(), "the engine's error in the log")
    stop = paused_at(fresh.pause(True))   # already stopped: this only reports where
    wait_for(lambda: fresh.snapshot("clock")[-1] == stop, "/clock to reach the failure time")
    count = len(fresh.snapshot("clock"))
    response = fresh.pause(False)
    assert not response.success and "call ~/reset" in response.message
    # The failed node's time stands: ~/pause reports the failure time again after the refused
    # resume, and no /clock arrived in between.
    assert paused_at(fresh.pause(True)) == stop
    assert len(fresh.snapshot("clock")) == count
    assert all(math.isfinite(v) for r in fresh.run("joints") for v in r[1] + r[2])
    fresh.reset()
    assert fresh.pause(False).success
    fresh.wait_run("joints", lambda run: len(run) >= 20, "publishing after the reset")
    assert simulator.process.poll() is None


# (method, command topic, values, the key its one failure line names). Each came right after
# ~/reset: radau/bdf crawled towards ulp(0) for good (1e30) or lost their stepping thread to a
# lu_factor traceback (1e300); dop853/rk45 spun at 90 % CPU on [1e308, 1e308], /clock at 0.
HUGE_COMMANDS = [("radau", "wheels", [1e30, 1e30], "integrator.rtol"),
                 ("bdf", "wheels", [1e30, 1e30], "integrator.rtol"),
                 ("radau", "wheels", [1e300, 1e300], "integrator.rtol"),
                 ("bdf", "cmd_vel", [1e300, 0.0], "integrator.rtol"),
                 ("dop853", "wheels", [1e308, 1e308], "efforts.wheels"),
                 ("rk45", "cmd_vel", [1e308, 1e308], "efforts.cmd_vel")]


@pytest.mark.parametrize("method, topic, values, key", HUGE_COMMANDS,
                         ids=[f"{m}-{t}-{v[0]:g}" for m, t, v, _ in HUGE_COMMANDS])
def test_a_huge_command_after_a_reset_pauses_the_node_until_reset(probe, simulator, tmp_path,
                                                                  method, topic, values, key):
    """Each segment failure ends in one error line naming the cause ("simulation failed …"); the
    node pauses, answers services, and ~/reset brings publishing back."""
    from geometry_msgs.msg import Twist
    probe.pause(True)
    name = f"huge_{method}_sim"
    velocity = ["-p", "base_command:=velocity"] if topic == "cmd_vel" else []
    node = start_simulator(probe, tmp_path, "-p", f"integrator.method:={method}",
                           "-p", "real_time_factor:=5.0", *velocity, "-r", f"__node:={name}")
    reset = probe.node.create_client(Trigger, f"/{name}/reset")
    pause = probe.node.create_client(SetBool, f"/{name}/pause")
    twist = probe.node.create_publisher(Twist, "/cmd_vel", 10)

    def send(v):
        if topic == "wheels":
            probe.send(wheels=v)
        else:
            message = Twist()
            message.linear.x, message.angular.z = v
            twist.publish(message)
    try:
        wait_for(lambda: reset.service_is_ready() and pause.service_is_ready()
                 and (topic == "wheels" or twist.get_subscription_count() > 0), "its services")
        assert probe.call(pause, SetBool.Request(data=True)).success
        assert probe.call(reset, Trigger.Request()).success
        send(values)
        assert probe.call(pause, SetBool.Request(data=False)).success
        # radau's step watch runs SciPy's steps from Python: slow on a loaded machine
        failed = wait_for(lambda: [line for line in node.output().splitlines()
                                   if "simulation failed" in line],
                          "the engine's error in the log", timeout=90.0)
        assert len(failed) == 1 and f"{key}: " in failed[0], failed
        assert "; paused, call ~/reset" in failed[0], failed[0]
        assert "Traceback" not in node.output(), node.output()
        response = probe.call(pause, SetBool.Request(data=False))
        assert not response.success and "call ~/reset" in response.message
        marks = probe.marks()
        send([0.0, 0.0])
        assert probe.call(reset, Trigger.Request()).success
        assert probe.call(pause, SetBool.Request(data=False)).success
        wait_for(lambda: len(probe.snapshot("joints")) >= marks["joints"] + 20,
                 "publishing after the reset")
        assert node.process.poll() is None
    finally:
        probe.node.destroy_client(reset)
        probe.node.destroy_client(pause)
        probe.node.destroy_publisher(twist)
        assert node.stop() == 0, node.output()


# --- start-up ---------------------------------------------------------------------------------

@pytest.mark.parametrize("content",
                         [None, "robot: [1, 2\n", "robot: {base: {mass: -1}}\n", ALIAS_BOMB])
def test_a_missing_or_invalid_scene_exits_2_with_one_line(tmp_path, content):
    path = tmp_path / "scene.yaml"
    if content is not None:
        path.write_text(content)
    result = subprocess.run([SIMULATOR, "--ros-args", "-p", f"scene:={path}"], env=child_env(),
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("simulator: error: "), result.stderr


def test_robot_description_reaches_a_late_subscriber(probe, simulator):
    received = []
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    subscription = probe.node.create_subscription(String, "/robot_description",
                                                  lambda msg: received.append(msg.data), latched)
    try:
        text = wait_for(lambda: received and received[0], "/robot_description")
        assert text.lstrip().startswith("<") and "<robot" in text and "right_wheel_joint" in text
    finally:
        probe.node.destroy_subscription(subscription)


# --- ROS-native naming and stepping --------------------------------------------------------

class NamespacedProbe:
    """Counts odom, joint_states and clock in /robot1 and /robot2, and on the root topics."""

    NAMESPACES = ("/robot1", "/robot2", "")
    TOPICS = (("odom", Odometry), ("joint_states", JointState), ("clock", Clock))

    def __init__(self, context: Context):
        self.node = rclpy.create_node("namespace_probe", context=context)
        self.lock = threading.Lock()
        self.counts = {}
        for namespace in self.NAMESPACES:
            for topic, kind in self.TOPICS:
                name = f"{namespace}/{topic}"
                self.counts[name] = 0
                self.node.create_subscription(kind, name, lambda msg, name=name: self._on(name),
                                              RELIABLE)

    def _on(self, name):
        with self.lock:
            self.counts[name] += 1

    def snapshot(self) -> dict:
        with self.lock:
            return dict(self.counts)


def test_two_simulators_in_two_namespaces_publish_only_there(probe, tmp_path):
    """`__ns:=/robot1` moves every topic but /clock: each namespace gets its own odom and
    joint_states, and the root ones stay silent (any other node on the domain is paused); /clock
    stays absolute, where use_sim_time clients read it (test_node_view.py: publish_clock)."""
    probe.pause(True)
    nodes = [SimulatorProcess(tmp_path, *FAST, "-r", f"__ns:={namespace}")
             for namespace in ("/robot1", "/robot2")]
    try:
        with spinning(NamespacedProbe, DOMAIN_ID) as counter:
            def all_arrived():
                counts = counter.snapshot()
                assert all(node.process.poll() is None for node in nodes), nodes[0].output()
                return all(counts[f"{ns_}/{topic}"] >= 20 for ns_ in ("/robot1", "/robot2")
                           for topic in ("odom", "joint_states")) and counts["/clock"] >= 20
            wait_for(all_arrived, "20 messages on every namespaced topic", STARTUP_TIMEOUT)
            counts = counter.snapshot()
            assert counts["/odom"] == counts["/joint_states"] == 0, counts
            assert counts["/robot1/clock"] == counts["/robot2/clock"] == 0, counts
            names = dict(counter.node.get_service_names_and_types())
            assert "/robot1/mobile_manip_sim/step" in names
            assert "/robot2/mobile_manip_sim/reset" in names
    finally:
        for node in nodes:
            assert node.stop() == 0, node.output()


def test_ten_steps_while_paused_publish_ten_states_one_period_apart(fresh):
    fresh.wait_run("joints", lambda run: len(run) >= 5, "5 segments")
    client = fresh.node.create_client(Trigger, "/mobile_manip_sim/step")
    try:
        wait_for(client.service_is_ready, "the ~/step service")
        assert not fresh.call(client, Trigger.Request()).success   # running: refused
        stop = paused_at(fresh.pause(True))
        wait_for(lambda: fresh.snapshot("clock")[-1] == stop, "/clock to reach the pause time")
        before = len(fresh.snapshot("joints"))
        for k in range(1, 11):
            response = fresh.call(client, Trigger.Request())
            assert response.success, response.message
            assert paused_at(response) == stop + k * PERIOD_NS
        wait_for(lambda: len(fresh.snapshot("joints")) >= before + 10, "ten stepped states")
        # still paused where the tenth step left it: nothing more was stepped
        assert paused_at(fresh.pause(True)) == stop + 10 * PERIOD_NS
        stamps = [record[0] for record in fresh.snapshot("joints")[before:]]
        assert stamps == [stop + k * PERIOD_NS for k in range(1, 11)]
        assert fresh.snapshot("clock")[-10:] == stamps
    finally:
        fresh.node.destroy_client(client)


def lockstep_run(tmp_path, name: str, states: int):
    """A synchronous node at real_time_factor 0 and the PD controller process on a domain of
    their own; the node's bag as (topic, stamp, raw bytes), and the node's output."""
    from rosbags.rosbag2 import Reader
    env = ros_child_env(DOMAIN_ID + 1 if DOMAIN_ID < 199 else 1)   # not the probe's
    bag, log = tmp_path / name, tmp_path / f"{name}.log"
    with open(log, "w") as out:
        node = subprocess.Popen([SIMULATOR, "--ros-args", "-p", "integrator.method:=rk4",
                                 "-p", "integrator.dt:=0.001", "-p", "real_time_factor:=0.0",
                                 "-p", "synchronous:=true", "-p", "sync_timeout:=5.0",
                                 "-p", "command_timeout:=0.0", "-p", f"record:={bag}",
                                 *EFFORT_ARM], env=env, stdout=out, stderr=subprocess.STDOUT)
    try:
        # the controller starts after the node: once its start-up line is out
        wait_for(lambda: node.poll() is not None or "publishing at" in log.read_text(),
                 "the node's start-up line", STARTUP_TIMEOUT)
        assert node.poll() is None, log.read_text()
        controller = subprocess.run(
            [os.sys.executable, os.path.join(HELPERS, "pd_controller.py"),
             str(states)], env=env, timeout=STARTUP_TIMEOUT + 60, capture_output=True, text=True)
        assert controller.returncode == 0, controller.stderr
    finally:
        node.send_signal(signal.SIGTERM)
        node.wait(timeout=30)
    output = log.read_text()
    assert node.returncode == 0, output
    with Reader(bag) as reader:
        records = [(connection.topic, stamp, bytes(data))
                   for connection, stamp, data in reader.messages()]
    return records, output


def test_a_synchronous_node_alone_says_what_its_first_state_waits_for(tmp_path):
    """Nobody listens, nobody commands (a controller that publishes arm efforts to a node whose
    arm takes another topic is such a one): the node says so, naming its command topics, every
    SAY_EVERY s — not a word, before."""
    from mobile_manip_sim.node.lockstep import SAY_EVERY
    env = ros_child_env(DOMAIN_ID + 1 if DOMAIN_ID < 199 else 1)   # nobody there
    node = NodeProcess(tmp_path, *FAST, "-p", "synchronous:=true", env=env)
    said = "synchronous: the first state waits for a subscriber of its states and a publisher on "
    try:
        wait_for(lambda: not node.running() or node.output().count(said) >= 2,
                 f"two lines saying what the start waits for ({SAY_EVERY:g} s apart)",
                 STARTUP_TIMEOUT + 4 * SAY_EVERY)
        output = node.output()
    finally:
        assert node.stop() == 0, node.output()
    line = next(line for line in output.splitlines() if said in line)
    assert "/cmd_vel" in line or "/wheel_effort_controller/commands" in line, line
    assert line.endswith("(none has one)"), line


def test_a_pd_controller_in_lockstep_gives_the_same_bag_every_time(tmp_path):
    """Closed loop over DDS, synchronous, as fast as the two processes go: every state from
    t = 0 on, none skipped or repeated, each segment under the reply to its state — twice the
    same run, byte for byte."""
    states = 150
    first, output = lockstep_run(tmp_path, "first", states)
    assert "sync_timeout" not in output, output
    stamps = [stamp for topic, stamp, _ in first if topic == "/joint_states"]
    assert stamps == [k * PERIOD_NS for k in range(states + 1)]
    wheels = [data for topic, stamp, data in first if topic == "/wheel_effort_controller/commands"]
    assert len(wheels) >= 2       # the controller's replies changed the efforts
    second, output = lockstep_run(tmp_path, "second", states)
    assert "sync_timeout" not in output, output
    assert second == first


PARAMS_FILES = {  # case: (file content, or a special file's kind; what the one line says)
    "binary params file": (bytes(range(256)), "not UTF-8"),
    "alias bomb params file": (ALIAS_BOMB, "expands to more than 100000 YAML nodes"),
    "duplicate key params file": ("/**:\n  ros__parameters:\n    publish_rate: 50.0\n"
                                  "    publish_rate: 100.0\n",
                                  "publish_rate: duplicate key (line 4)"),
    "nested params file": ("[" * 3000 + "]" * 3000, "nested deeper than"),
    "huge params file": ("#" * (2 << 20), "larger than"),
    "fifo params file": ("fifo", "not a regular file"),
    "directory params file": ("directory", "not a regular file"),
    "missing params file": ("missing", "cannot read parameters file"),
}


def params_file(tmp_path, content):
    path = tmp_path / "params.yaml"
    if content == "fifo":
        os.mkfifo(path)    # rcl would block reading it, for good
    elif content == "directory":
        path.mkdir()
    elif content != "missing":
        (path.write_bytes if isinstance(content, bytes) else path.write_text)(content)
    return path


PARAMETERS = {  # case: (arguments, the key named, what the one line says)
    "unknown parameter": (["-p", "real_time_facter:=0.0"], "real_time_facter", "unknown"),
    # in the declared range [0, 1], but a step of 1e-10 s would take 1e8 steps per publication
    "dt 1e-10": (["-p", "integrator.method:=rk4", "-p", "integrator.dt:=1e-10"], "integrator.dt",
                 "must be in [1e-09, 1]"),
    # the arm controller
    "arm mode unknown": (["-p", "arm_controller:=torque"], "arm_controller", "unknown mode"),
    "arm gains per joint": (["-p", "arm_controller:=position", "-p", "arm_gains.kp:=[1.0, 2.0]"],
                            "arm_gains.kp", "expected one number or 4"),
    "arm gain text": (["-p", "arm_controller:=position", "-p", "arm_gains.kd:=stiff"],
                      "arm_gains.kd", "expected a number or a list of numbers"),
    "arm gain negative": (["-p", "arm_controller:=position", "-p", "arm_gains.ki:=-1.0"],
                          "arm_gains.ki", "expected numbers in"),
    "feedforward unknown": (["-p", "arm_feedforward:=magic"], "arm_feedforward",
                            "unknown feedforward"),
    # rcl's own parse fails (it logs a line of its own, which must not reach the user beside ours)
    "override rcl cannot parse": (["-p", "scene:=[1.0,"], "--ros-args",
                                  "Couldn't parse parameter override rule"),
}


@pytest.mark.parametrize("case", [*PARAMS_FILES, *PARAMETERS])
def test_bad_ros_arguments_exit_2_with_one_line_naming_the_cause(tmp_path, case):
    if case in PARAMS_FILES:
        content, problem = PARAMS_FILES[case]
        args, key = ["--params-file", str(params_file(tmp_path, content))], "--params-file"
    else:
        args, key, problem = PARAMETERS[case]
    start = time.monotonic()
    result = subprocess.run([SIMULATOR, "--ros-args", *args], env=child_env(),
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"simulator: error: {key}: "), result.stderr
    assert problem in lines[0], lines[0]
    assert "Traceback" not in result.stdout + result.stderr
    assert time.monotonic() - start < 30   # refused at start-up, nothing read without end


def test_the_shipped_params_file_applies_under_another_node_name(tmp_path):
    """Keyed /**: a renamed node still takes it (a wrong type in it would be refused)."""
    import shutil
    params = tmp_path / "params.yaml"
    shutil.copy(os.path.join(HELPERS, "..", "..", "config", "simulator.params.yaml"),
                params)
    params.write_text(params.read_text().replace("publish_rate: 100.0", "publish_rate: 100"))
    result = subprocess.run([SIMULATOR, "--ros-args", "--params-file", str(params),
                             "-r", "__node:=renamed"], env=child_env(), capture_output=True,
                            text=True, timeout=60)
    assert result.returncode == 2 and "publish_rate" in result.stderr, result.stderr


def test_cmd_vel_held_for_4_s_drives_the_base_at_that_twist_and_resimulates(probe, simulator,
                                                                           tmp_path):
    """base_command velocity: cmd_vel (0.3 m/s, 0.5 rad/s) for 4 s of simulated time; the
    wheel-speed loop inside the simulation brings /odom's twist within 10 % of it. The velocity
    command is part of the run: recorded as applied, and the bag re-simulates bit for bit."""
    from geometry_msgs.msg import Twist
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore
    probe.pause(True)
    bag = tmp_path / "velocity_run"
    node = start_simulator(probe, tmp_path, *FAST, "-p", "base_command:=velocity",
                           "-p", "wheel_speed.kp:=5.0", "-p", "wheel_speed.ki:=50.0",
                           "-p", f"record:={bag}", "-r", "__node:=velocity_sim")
    publisher = probe.node.create_publisher(Twist, "/cmd_vel", 10)
    try:
        wait_for(lambda: publisher.get_subscription_count() > 0, "the node's cmd_vel subscription")
        # State 1 out means segment 0 took its command (zero speed): the twist applies later.
        probe.wait_run("odom", lambda run: any(r[0] >= PERIOD_NS for r in run), "state 1")
        twist = Twist()
        twist.linear.x, twist.angular.z = 0.3, 0.5
        start = probe.snapshot("odom")[-1][0]
        while probe.snapshot("odom")[-1][0] < start + 4 * 10 ** 9:
            assert node.process.poll() is None, node.output()
            publisher.publish(twist)
            time.sleep(0.02)   # paces the publisher (a teleop's 50 Hz), not a wait
        last = probe.snapshot("odom")[-1]
        assert abs(last[5] - 0.3) <= 0.03 and abs(last[6] - 0.5) <= 0.05, last[:7]
        efforts = probe.snapshot("joints")[-1][3]
        assert efforts[0] != 0.0 and efforts[1] != 0.0   # the loop's torques, published
    finally:
        probe.node.destroy_publisher(publisher)
        assert node.stop() == 0, node.output()
    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as reader:
        topics = {connection.topic: connection.msgtype for connection in reader.connections}
        assert topics["/cmd_vel"] == "geometry_msgs/msg/Twist"
        assert "/wheel_effort_controller/commands" not in topics
        commands = [(stamp, store.deserialize_cdr(data, "geometry_msgs/msg/Twist"))
                    for connection, stamp, data in reader.messages()
                    if connection.topic == "/cmd_vel"]
    assert commands[0][0] == 0 and commands[0][1].linear.x == 0.0   # zero until commanded
    assert any((c.linear.x, c.angular.z) == (0.3, 0.5) for _, c in commands), commands
    assert all(stamp % PERIOD_NS == 0 for stamp, _ in commands)      # at segment starts
    result = subprocess.run([executable("replay"), str(bag), "--resimulate"], env=child_env(),
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and "IDENTICAL" in result.stdout, result.stdout + result.stderr


# --- load ---------------------------------------------------------------------------------------

def cpu_seconds(process: NodeProcess) -> float:
    return process_cpu_seconds(process.pid)


def test_a_10_khz_command_flood_neither_stalls_the_node_nor_its_services(probe, simulator,
                                                                         tmp_path):
    """Another process floods the wheel topic at 10 kHz while a node runs at real_time_factor
    1: the node takes commands latest first when it needs them, so its clock keeps moving and
    ~/pause answers. The real-time factor and the latencies are printed, not asserted (timings
    on a shared machine are a benchmark's, bench/NODE.md)."""
    probe.pause(True)   # the shared node idles
    node = start_simulator(probe, tmp_path, "-p", "integrator.method:=rk4",
                           "-p", "integrator.dt:=0.001", "-p", "real_time_factor:=1.0",
                           "-p", "command_timeout:=0.0", "-r", "__node:=flood_sim")
    pause = probe.node.create_client(SetBool, "/flood_sim/pause")
    seconds = 6.0
    flood = subprocess.Popen([os.sys.executable, os.path.join(HELPERS, "command_flood.py"),
                              "10000", str(seconds)], env=child_env(), stdout=subprocess.PIPE,
                             text=True)
    try:
        wait_for(pause.service_is_ready, "the flooded node's ~/pause")
        flooded = {(0.01, 0.02), (0.02, 0.01)}
        probe.wait_run("joints", lambda run: index_of(run, lambda r: r[3][:2] in flooded),
                       "the flood's commands in the node's efforts")   # the flood is on
        clock0, wall0, cpu0 = probe.snapshot("clock")[-1], time.monotonic(), cpu_seconds(node)
        # under the flood the clock moves: half a second of simulated time (a full second of
        # wall time at real_time_factor 1 on a quiet machine)
        wait_for(lambda: probe.snapshot("clock")[-1] >= clock0 + 5 * 10 ** 8,
                 "/clock to move 0.5 s under the flood")
        clock1, wall1, cpu1 = probe.snapshot("clock")[-1], time.monotonic(), cpu_seconds(node)
        factor = (clock1 - clock0) / 1e9 / (wall1 - wall0)
        load = (cpu1 - cpu0) / (wall1 - wall0)
        latencies = []
        for paused in (True, False, True, False):
            begin = time.monotonic()
            future = pause.call_async(SetBool.Request(data=paused))
            wait_for(future.done, "a ~/pause answer")
            latencies.append(time.monotonic() - begin)
            assert future.result().success
            at = paused_at(future.result())
            if paused:   # the clock stops where ~/pause said, and runs on after the resume
                wait_for(lambda at=at: probe.snapshot("clock")[-1] == at, "/clock to stop")
            else:
                wait_for(lambda at=at: probe.snapshot("clock")[-1] > at, "/clock to run again")
        assert flood.poll() is None, "the flood ended before the measurements"
        sent = flood.communicate(timeout=seconds + 30)[0]
        count = int(re.search(r"sent (\d+) in ([\d.]+) s", sent).group(1))
        print(f"flood: {sent.strip()}, real-time factor {factor:.3f}, node CPU {load:.0%} of a "
              f"core, ~/pause latencies "
              f"{', '.join(f'{1000 * latency:.1f}' for latency in latencies)} ms")
        assert count >= 1000 * seconds, sent   # a flood indeed (10 kHz asked)
        assert clock1 > clock0, "the clock stood still under the flood"
        assert node.process.poll() is None, node.output()
    finally:
        if flood.poll() is None:
            flood.kill()
            flood.wait()
        probe.node.destroy_client(pause)
        assert node.stop() == 0, node.output()


def resident_mb(pid: int) -> float:
    """VmRSS of a process (MB), from /proc."""
    status = open(f"/proc/{pid}/status").read()
    return int(re.search(r"VmRSS:\s+(\d+)", status).group(1)) / 1024


@pytest.mark.bench_target
def test_at_real_time_factor_1_the_node_holds_at_most_200_mb(probe, simulator, tmp_path):
    """rk4 at real_time_factor 1, driven into the end stops: the node's resident memory (no
    compiler in the process: the engine is compiled ahead of time)."""
    probe.pause(True)   # the shared node idles
    node = start_simulator(probe, tmp_path, "-p", "integrator.method:=rk4",
                           "-p", "integrator.dt:=0.001", "-p", "real_time_factor:=1.0",
                           "-p", "command_timeout:=0.0", *EFFORT_ARM, "-r", "__node:=memory_sim")
    try:
        scene = load_scene(None)
        probe.send(scene.wheel_efforts.tolist(), scene.joint_efforts.tolist())
        # past the first impacts (at 1.5 s the paper scene has had them): 4 s of this node's
        # simulated time (the shared node, paused, publishes nothing)
        probe.wait_run("joints", lambda run: run and run[-1][0] >= 4 * 10 ** 9,
                       "4 s of simulated time", STARTUP_TIMEOUT)
        total = resident_mb(node.process.pid)
        print(f"node VmRSS {total:.1f} MB")
        assert "libllvmlite" not in open(f"/proc/{node.process.pid}/maps").read()
        assert total <= 200.0, f"VmRSS {total:.1f} MB"
        assert node.process.poll() is None, node.output()
    finally:
        assert node.stop() == 0, node.output()
