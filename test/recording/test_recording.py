"""Recording, replay and re-simulation as users run them: the installed `simulator`, `simulate`
and `replay` executables in their own processes, real DDS (a random ROS_DOMAIN_ID, localhost
discovery), and bags read back by independent readers (rosbags; mcap + mcap_ros2)."""
import json
import random
import re
import resource
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest
import rclpy
import yaml
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap_ros2.decoder import DecoderFactory
from nav_msgs.msg import Odometry
from rclpy.context import Context
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import Reader as RosbagsReader
from rosbags.typesys import Stores, get_typestore
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from bag_rewrite import rewrite_bag
from executables import executable
from mobile_manip_sim import __version__
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.recording.bag_reader import open_bag
from mobile_manip_sim.recording.bag_writer import DEFAULT_CHUNK_SIZE
from mobile_manip_sim.recording.headless import HeadlessRecorder
from mobile_manip_sim.ros.cdr import exact_cdr
from mobile_manip_sim.ros.imu import ImuNoise
from mobile_manip_sim.ros.messages import float64_array
from mobile_manip_sim.ros.topics import recorded_topics
from mobile_manip_sim.runtime.headless import run as simulate_run
from mobile_manip_sim.scene.loading import load_scene, make_integrator
from ros_harness import NodeProcess, private_domain, spinning
from ros_harness import child_env as ros_child_env
from ros_harness import wait_for as harness_wait_for

DOMAIN_ID = private_domain(1, 99)   # test_node.py uses 100-199
EXECUTABLES = {name: executable(name) for name in ("simulator", "simulate", "replay")}
FAST = ["-p", "real_time_factor:=5.0", "-p", "integrator.method:=rk4", "-p", "integrator.dt:=0.001"]
# The arm takes efforts where a test sends them (the node's default controller holds the pose)
EFFORT_ARM = ["-p", "arm_controller:=effort"]
PERIOD_NS = 10 ** 7                    # the node's default 100 Hz
TIMEOUT = 20.0
STARTUP_TIMEOUT = 60.0
WHEELS, ARM = "/wheel_effort_controller/commands", "/arm_effort_controller/commands"
# The topics of a node's bag (effort mode): the states, the view topics and /imu.
TOPIC_TYPES = recorded_topics("effort", view=True, imu=True)
STATE_TOPICS = ("/joint_states", "/odom", "/clock")
# The headless run used for replay and determinism: 20 Hz samples and a last one off the grid.
HEADLESS = ["--duration", "2.005", "--sample-rate", "20", "--method", "rk4", "--dt", "0.001"]



def child_env() -> dict:
    return ros_child_env(DOMAIN_ID)


def wait_for(predicate, what: str, timeout: float = TIMEOUT):
    return harness_wait_for(predicate, what, timeout)


def ns(stamp) -> int:
    return stamp.sec * 10 ** 9 + stamp.nanosec


def run_cli(*args, timeout: float = 120.0) -> subprocess.CompletedProcess:
    name, *rest = args
    return subprocess.run([EXECUTABLES[name], *rest], env=child_env(), capture_output=True,
                          text=True, timeout=timeout)


def one_error_line(result, prog: str) -> str:
    assert result.returncode == 2, (result.returncode, result.stdout, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error: "), result.stderr
    return lines[0]


# --- exact CDR ----------------------------------------------------------------------------------

def test_payloads_are_exact_deterministic_cdr():
    """rclpy's serialisation, cleaned: deserialises to the same message, equals what an
    independent serialiser (rosbags) writes for it, byte for byte, and never varies."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    rng = random.Random(5)

    def text():
        return "".join(rng.choice("abcdefgh") for _ in range(rng.randrange(7)))

    def numbers():
        return [rng.uniform(-1, 1) for _ in range(rng.choice([0, 0, 1, 2, 3, 6]))]

    for i in range(400):
        if i % 3 == 0:
            message = JointState(name=[text() for _ in range(rng.randrange(4))],
                                 position=numbers(), velocity=numbers(), effort=numbers())
            message.header.frame_id = text()
            message.header.stamp.nanosec = rng.randrange(10 ** 9)
        elif i % 3 == 1:
            message = Odometry(child_frame_id=text())
            message.header.frame_id = text()
            message.pose.covariance = [rng.random() for _ in range(36)]
            message.twist.twist.angular.z = rng.random()
        else:
            message = float64_array(numbers())
        type_name = TOPIC_TYPES[{0: "/joint_states", 1: "/odom", 2: WHEELS}[i % 3]]
        data = exact_cdr(message)
        assert exact_cdr(message) == data
        assert deserialize_message(data, type(message)) == message
        independent = typestore.serialize_cdr(typestore.deserialize_cdr(data, type_name),
                                              type_name)
        assert bytes(independent) == data


# --- a probe node in this process ---------------------------------------------------------------

class Probe:
    """Receives every topic a bag holds (decoded, with its wall arrival time) and publishes
    effort commands."""

    TYPES = {"/joint_states": JointState, "/odom": Odometry, "/clock": Clock, "/tf": TFMessage,
             WHEELS: Float64MultiArray, ARM: Float64MultiArray}

    def __init__(self, context: Context):
        self.node = rclpy.create_node("recording_test_probe", context=context)
        self.lock = threading.Lock()
        self.received = {topic: [] for topic in self.TYPES}
        qos = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE)
        for topic, cls in self.TYPES.items():
            self.node.create_subscription(cls, topic, lambda msg, t=topic: self._on(t, msg), qos)
        self.wheels = self.node.create_publisher(Float64MultiArray, WHEELS, 10)
        self.arm = self.node.create_publisher(Float64MultiArray, ARM, 10)

    def _on(self, topic, msg):
        with self.lock:
            self.received[topic].append((time.monotonic(), msg))

    def clear(self):
        with self.lock:
            for records in self.received.values():
                records.clear()

    def messages(self, topic) -> list:
        with self.lock:
            return [msg for _, msg in self.received[topic]]

    def arrivals(self, topic) -> list:
        with self.lock:
            return list(self.received[topic])


@pytest.fixture(scope="module")
def probe():
    with spinning(Probe, DOMAIN_ID) as probe:
        yield probe


class Simulator(NodeProcess):
    """The installed `simulator`, recording; its log in a file; stopped by SIGINT unless told."""

    def __init__(self, tmp_path, *args, preexec_fn=None):
        env = child_env()
        env["ROS_LOG_DIR"] = str(tmp_path / "ros_log")
        super().__init__(tmp_path, *args, env=env, preexec_fn=preexec_fn)

    def stop(self, sig=signal.SIGINT) -> int:
        return super().stop(sig)


def start_simulator(probe, tmp_path, *args, **options) -> Simulator:
    """A recording node up and subscribed. The arm takes efforts (EFFORT_ARM) unless ``args``
    choose its controller: these tests send arm efforts and wait for the arm effort
    subscription (a node recording its default controller is test_arm_node's)."""
    if not any(str(arg).startswith("arm_controller:=") for arg in args):
        args = (*args, *EFFORT_ARM)
    probe.clear()
    simulator = Simulator(tmp_path, *args, **options)
    try:
        wait_for(lambda: simulator.process.poll() is not None or (
            probe.wheels.get_subscription_count() > 0 and probe.arm.get_subscription_count() > 0
            and probe.messages("/joint_states")), "the simulator's first messages", STARTUP_TIMEOUT)
        assert simulator.process.poll() is None, simulator.output()
    except BaseException:
        simulator.stop(signal.SIGKILL)
        raise
    return simulator


# --- a recorded node run, shared by several tests ---------------------------------------------

SENT = [([0.2, 0.1], [4.5, 7.0, 0.0, 1.0]), ([-0.1, 0.3], [1.0, 2.0, 0.5, -1.0]),
        ([0.05, 0.05], [0.5, 1.0, 0.0, 0.5])]


@pytest.fixture(scope="module")
def node_run(probe, tmp_path_factory):
    """A node recording while the probe sends three command changes; stopped by SIGINT."""
    tmp_path = tmp_path_factory.mktemp("node_run")
    bag = tmp_path / "run"
    simulator = start_simulator(probe, tmp_path, *FAST, *EFFORT_ARM, "-p", f"record:={bag}")
    try:
        # State 1 out means segment 0 took its commands (zeros): the first sent applies later.
        wait_for(lambda: any(ns(m.header.stamp) >= PERIOD_NS
                             for m in probe.messages("/joint_states")), "state 1")
        for wheels, arm in SENT:
            probe.wheels.publish(Float64MultiArray(data=wheels))
            probe.arm.publish(Float64MultiArray(data=arm))
            # Both applied (the two topics arrive independently) before the next pair is sent:
            # otherwise one segment could take two arm commands and record only the later.
            wait_for(lambda w=wheels, a=arm: any(list(m.effort[:2]) == w and list(m.effort[2:]) == a
                                                 for m in probe.messages("/joint_states")),
                     f"the efforts {wheels} and {arm} in /joint_states")
        count = len(probe.messages("/joint_states"))
        wait_for(lambda: len(probe.messages("/joint_states")) >= count + 50, "50 more states")
    finally:
        code = simulator.stop(signal.SIGINT)
    assert code == 0, simulator.output()
    received = {topic: probe.messages(topic) for topic in STATE_TOPICS}
    return bag, received, simulator.output()


def bag_file(bag: Path) -> Path:
    return bag / f"{bag.name}_0.mcap"


def test_a_node_bag_reads_back_with_rosbags(node_run):
    bag, received, _ = node_run
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with RosbagsReader(bag) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == TOPIC_TYPES
        counts = {c.topic: c.msgcount for c in reader.connections}
        records = [(c.topic, t, typestore.deserialize_cdr(raw, c.msgtype))
                   for c, t, raw in reader.messages()]
    times = [t for _, t, _ in records]
    assert times == sorted(times)
    states = {topic: [(t, m) for c, t, m in records if c == topic] for topic in STATE_TOPICS}
    for topic, stamped in states.items():
        assert len(stamped) == counts[topic]
        # One state per period from t = 0, each record's time its own stamp.
        assert [t for t, _ in stamped] == [k * PERIOD_NS for k in range(len(stamped))]
        stamps = [ns(m.clock if topic == "/clock" else m.header.stamp) for _, m in stamped]
        assert stamps == [t for t, _ in stamped]
    # Everything the subscriber received was recorded, with the stamp it carried.
    recorded_joints = {t: m for t, m in states["/joint_states"]}
    for message in received["/joint_states"]:
        stamp = ns(message.header.stamp)
        assert stamp in recorded_joints
        assert list(recorded_joints[stamp].position) == list(message.position)
        assert list(recorded_joints[stamp].effort) == list(message.effort)
    assert {ns(m.header.stamp) for m in received["/odom"]} <= {t for t, _ in states["/odom"]}
    assert {ns(m.clock) for m in received["/clock"]} <= {t for t, _ in states["/clock"]}
    # What a viewer needs: the latched ones once at t = 0 (one /tf_static message with every
    # fixed joint), /tf and /imu with every state.
    for topic in ("/tf_static", "/robot_description"):
        assert [t for c, t, _ in records if c == topic] == [0]
    static = next(m for c, _, m in records if c == "/tf_static")
    assert [t.child_frame_id for t in static.transforms] == ["base_link", "tip"]
    odom = [t for t, _ in states["/odom"]]
    for topic in ("/tf", "/imu"):   # the last may have been cut by the shutdown
        stamps = [t for c, t, _ in records if c == topic]
        assert stamps == odom[:len(stamps)] and len(stamps) >= len(odom) - 1
    # The subscriber may miss the first messages (discovery); from then on it got them all.
    got = [ns(m.header.stamp) for m in received["/joint_states"]]
    assert len(got) >= 50 and got == list(range(got[0], got[-1] + 1, PERIOD_NS))

    # Commands: zero at t = 0, then each change at the segment start from which it was held:
    # the state at the next stamp carries it as its effort. Every command sent is there, in order.
    for topic, part in ((WHEELS, slice(0, 2)), (ARM, slice(2, 6))):
        commands = [(t, list(m.data)) for c, t, m in records if c == topic]
        assert commands[0] == (0, [0.0] * (part.stop - part.start))
        for (t, values), (t_next, _) in zip(commands, commands[1:] + [(None, None)],
                                            strict=True):
            assert t % PERIOD_NS == 0
            held_until = t_next if t_next is not None else max(recorded_joints)
            assert all(list(recorded_joints[s].effort[part]) == values
                       for s in range(t + PERIOD_NS, held_until + 1, PERIOD_NS)
                       if s in recorded_joints)
        sent = [list(wheels if topic == WHEELS else arm) for wheels, arm in SENT]
        values = [v for _, v in commands]
        positions = [values.index(s) for s in sent]
        assert positions == sorted(positions)


def test_a_node_bag_reads_back_with_mcap_and_is_complete(node_run):
    bag, _, output = node_run
    path = bag_file(bag)
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        summary = reader.get_summary()
        last = -1
        counts = {}
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            assert message.log_time >= last
            last = message.log_time
            assert message.publish_time == message.log_time
            if channel.topic in ("/joint_states", "/odom"):
                assert ns(decoded.header.stamp) == message.log_time
            elif channel.topic == "/clock":
                assert ns(decoded.clock) == message.log_time
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            assert schema.name == TOPIC_TYPES[channel.topic] and schema.encoding == "ros2msg"
            assert channel.message_encoding == "cdr"
        attachments = {a.name: a for a in reader.iter_attachments()}
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    # SIGINT closed the bag: summary with statistics and chunk indexes, and metadata.yaml.
    assert header.profile == "ros2"
    assert summary.statistics.message_count == sum(counts.values())
    assert summary.chunk_indexes and all(i.compression == "zstd" for i in summary.chunk_indexes)
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["message_count"] == sum(counts.values())
    assert {t["topic_metadata"]["name"]: t["message_count"]
            for t in info["topics_with_message_count"]} == counts
    assert not open_bag(bag).recovered
    assert f"bag {bag} closed" in output
    # Self-describing: the full scene, the integrator and the impact log.
    assert attachments["scene.yaml"].media_type == "application/yaml"
    assert attachments["scene.yaml"].data.decode() == load_scene(None).to_yaml()
    impacts = json.loads(attachments["impacts.json"].data)
    assert isinstance(impacts, list)
    assert all(set(i) == {"time", "link", "stop", "ld_before", "ld_after", "energy_lost",
                          "resting", "held", "hold_energy"}
               and 0 <= i["time"] * 1e9 <= last for i in impacts)
    run = metadata["mobile_manip_sim"]
    assert run == {"version": __version__, "integrator_method": "rk4", "dt": "0.001",
                   "rtol": repr(load_scene(None).integrator.rtol),
                   "atol": repr(load_scene(None).integrator.atol),
                   "scene_name": "paper_two_link", "source": "node", "publish_rate": "100.0",
                   "controller_rate": "1000.0",   # the node's default: the scene's
                   "base_command": "effort", **ImuNoise().as_metadata()}   # a perfect IMU
    assert "rosbag2" in metadata
    for channel in summary.channels.values():
        qos = yaml.safe_load(channel.metadata["offered_qos_profiles"])
        latched = channel.topic in ("/tf_static", "/robot_description")
        assert (qos[0]["reliability"], qos[0]["durability"], qos[0]["history"]) == \
            ("reliable", "transient_local" if latched else "volatile", "keep_last")
        assert qos[0]["depth"] == (10 if channel.topic in (WHEELS, ARM) else 1 if latched
                                   else 100)


def test_resimulate_reproduces_the_node_run_bit_for_bit(node_run):
    bag, _, _ = node_run
    result = run_cli("replay", str(bag), "--resimulate")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "IDENTICAL" in result.stdout
    for quantity in ("x", "y", "yaw", "v", "omega", "arm_prismatic_2 position",
                     "right_wheel_joint velocity"):
        assert re.search(rf"^{re.escape(quantity)}\s+0\s+-$", result.stdout, re.M), result.stdout


def test_resimulate_reports_an_altered_command(node_run, tmp_path):
    bag, _, _ = node_run
    changed_at = []

    def alter(topic, data, index):
        if topic == WHEELS and index == 1:   # the first command after the zero at t = 0
            values = list(deserialize_message(data, Float64MultiArray).data)
            values[0] += 0.01
            changed_at.append(values)
            return exact_cdr(float64_array(values))
        return data

    altered = tmp_path / "altered"
    rewrite_bag(bag, altered, alter)
    assert changed_at
    result = run_cli("replay", str(altered), "--resimulate")
    assert result.returncode == 1, result.stdout + result.stderr
    assert "DIFFERENT" in result.stdout and "right_wheel_joint effort" in result.stdout
    assert re.search(r"^x\s+\S+\s+\d+\.\d{9}\s+> tolerance$", result.stdout, re.M), result.stdout
    # A tolerance the alteration stays within passes.
    assert run_cli("replay", str(altered), "--resimulate", "--tolerance", "1e9").returncode == 0


# --- headless ---------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def headless_bags(tmp_path_factory):
    """The same headless run recorded twice, into directories of the same name."""
    bags = []
    for run in ("first", "second"):
        directory = tmp_path_factory.mktemp(run)
        result = run_cli("simulate", *HEADLESS, "--out", str(directory / "run.csv"),
                         "--record", str(directory / "bag"))
        assert result.returncode == 0, result.stderr
        bags.append(directory / "bag")
    return bags


def test_identical_headless_runs_give_identical_bags_that_rosbags_reads(headless_bags):
    first, second = headless_bags
    assert bag_file(first).read_bytes() == bag_file(second).read_bytes()
    assert (first / "metadata.yaml").read_bytes() == (second / "metadata.yaml").read_bytes()
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with RosbagsReader(first) as reader:
        decoded = [(c.topic, t, typestore.deserialize_cdr(raw, c.msgtype))
                   for c, t, raw in reader.messages()]
    stamps = [t for topic, t, _ in decoded if topic == "/joint_states"]
    assert stamps == [k * 50_000_000 for k in range(41)] + [2_005_000_000]
    commands = [(topic, t, list(m.data)) for topic, t, m in decoded if topic in (WHEELS, ARM)]
    scene = load_scene(None)
    assert sorted(commands) == [(ARM, 0, scene.joint_efforts.tolist()),
                                (WHEELS, 0, scene.wheel_efforts.tolist())]
    metadata = open_bag(first).metadata()["mobile_manip_sim"]
    assert metadata["source"] == "simulate" and metadata["sample_rate"] == "20.0"
    assert json.loads(open_bag(first).attachments()["impacts.json"])   # this run hits its stops


def test_resimulate_reproduces_a_headless_run_bit_for_bit(headless_bags):
    result = run_cli("replay", str(headless_bags[0]), "--resimulate")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "IDENTICAL" in result.stdout and "42 /joint_states and 42 /odom" in result.stdout


def test_recording_memory_is_bounded_by_the_chunk_size(tmp_path):
    """60 s of simulated time at 100 Hz: what waits in memory for the disk never exceeds one
    chunk plus one message, and chunks keep going to the file."""
    scene = load_scene(None)
    settings = make_integrator(scene.integrator, "rk4", 0.001)
    recorder = HeadlessRecorder(tmp_path / "long", scene, settings, 100.0, 60.0)
    writer = recorder.writer
    original_write = writer.write
    worst = {"buffered": 0, "excess": 0, "messages": 0}
    sizes = []

    def write(topic, data, log_time_ns, publish_time_ns=None):
        original_write(topic, data, log_time_ns, publish_time_ns)
        worst["messages"] += 1
        worst["buffered"] = max(worst["buffered"], writer.buffered_bytes)
        worst["excess"] = max(worst["excess"], writer.buffered_bytes - DEFAULT_CHUNK_SIZE
                              - (31 + len(data)))
        if worst["messages"] % 3000 == 0:
            sizes.append(bag_file(tmp_path / "long").stat().st_size)

    writer.write = write
    simulate_run(scene, 60.0, 100.0, settings, recorder.sample)
    recorder.close()
    assert worst["messages"] == 4 * 6001 + 2 + 2   # states and /tf, commands, latched
    assert worst["excess"] <= 0, worst
    assert DEFAULT_CHUNK_SIZE // 2 < worst["buffered"] <= DEFAULT_CHUNK_SIZE + 1024
    assert sizes == sorted(sizes) and sizes[-1] > sizes[0] > 0   # streamed, not held back
    summary_chunks = len(open_bag(tmp_path / "long")._files[0].summary.chunk_indexes)
    assert summary_chunks >= 20


# --- the node's bag rotation (recording/rotation.py), without a node -------------------------

def test_a_new_time_line_rotates_the_bag_and_a_failure_only_stops_recording(tmp_path):
    from mobile_manip_sim.recording.recorder import RunRecorder
    from mobile_manip_sim.recording.rotation import RotatingRecorder
    from mobile_manip_sim.ros.messages import state_messages
    from mobile_manip_sim.scene.errors import UserError

    scene = load_scene(None)
    sim = Simulation(scene)
    names = scene.robot.joint_names()
    opened, lines = [], []

    def make_bag(path):
        if len(opened) == 2:
            raise UserError("record", f"{path}: cannot create")
        opened.append(path)
        return RunRecorder(path, scene, scene.integrator, {"source": "node",
                                                           "publish_rate": "100.0"})

    recording = RotatingRecorder(tmp_path / "run", make_bag, lines.append, lines.append)
    for stamp in (0, 10_000_000, 0, 10_000_000, 0, 10_000_000):   # three time lines
        recording.states(stamp, state_messages(sim, stamp, names), sim.impacts)
        recording.commands(stamp, [0.0, 0.0], [0.0] * 4)
    recording.close()
    assert opened == [str(tmp_path / "run"), str(tmp_path / "run_1")]
    assert lines == [f"reset: bag {tmp_path / 'run'} closed, recording on in {tmp_path / 'run_1'}",
                     f"recording stopped at the reset: record: {tmp_path / 'run_2'}: cannot "
                     f"create"]
    for bag in opened:   # each closed, each one time line
        assert [m.log_time_ns for m in open_bag(bag).messages("/joint_states")] == \
            [0, 10_000_000]


def test_a_recording_opens_at_most_max_bags_however_often_it_is_reset(tmp_path):
    """A peer calling ~/reset in a loop: the node records at most RECORDING_BAGS time lines,
    then one error line, and no further directory is made."""
    from mobile_manip_sim.recording.recorder import RunRecorder
    from mobile_manip_sim.recording.rotation import RotatingRecorder
    from mobile_manip_sim.ros.messages import state_messages

    scene = load_scene(None)
    sim = Simulation(scene)
    names = scene.robot.joint_names()
    lines = []

    def make_bag(path):
        return RunRecorder(path, scene, scene.integrator, {"source": "node",
                                                           "publish_rate": "100.0"})

    recording = RotatingRecorder(tmp_path / "run", make_bag, lines.append, lines.append,
                                 max_bags=3)
    for _ in range(6):   # six time lines
        for stamp in (0, 10_000_000):
            recording.states(stamp, state_messages(sim, stamp, names), sim.impacts)
    recording.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "run_1", "run_2"]
    assert lines[-1] == ("recording stopped at the reset: 3 bags recorded, the most one node "
                         "records (one per time line); the simulation goes on")
    assert sum("recording stopped" in line for line in lines) == 1


# --- replay -----------------------------------------------------------------------------------

def test_replay_publishes_the_recorded_messages_in_order_at_the_recorded_rate(probe, headless_bags):
    bag = headless_bags[0]
    probe.clear()
    rate, offset = 2.0, 0.5
    result = run_cli("replay", str(bag), "--rate", str(rate), "--start-offset", str(offset),
                     "--wait-for-subscribers", timeout=60)
    assert result.returncode == 0, result.stderr
    start = round(offset * 1e9)
    recorded = {topic: [(m.log_time_ns, deserialize_message(m.data, Probe.TYPES[topic]))
                        for m in open_bag(bag).messages(topic) if m.log_time_ns >= start]
                for topic in Probe.TYPES}
    wait_for(lambda: all(len(probe.messages(t)) >= len(recorded[t]) for t in recorded),
             "every replayed message")
    for topic, expected in recorded.items():
        assert probe.messages(topic) == [m for _, m in expected], topic
    # The pacing itself (from the offset, at the rate, never early) is checked on a fake clock
    # in test_replay.py: arrival times here would race with the machine's load.
    # … and /robot_description and /tf_static, latched, played first (their t = 0 messages,
    # before the start)
    assert f"played {sum(len(v) for v in recorded.values()) + 2} messages" in result.stdout
    # The time printed is the playing's: at least the bag's span at that rate (paced, never
    # early), and it leaves out the wait for subscribers and the final acknowledgements.
    played_in = float(re.search(r" in ([\d.]+) s \(rate", result.stdout)[1])
    last = max(t for messages in recorded.values() for t, _ in messages)
    assert played_in >= (last - start) / 1e9 / rate - 0.001, result.stdout


def test_replay_without_waiting_still_reaches_a_subscriber_that_already_runs(probe,
                                                                           headless_bags):
    """No --wait-for-subscribers: discovery of the running probe is still awaited (bounded),
    so its first message is the bag's first (it lost ~0.4 s of the bag before)."""
    bag = headless_bags[0]
    probe.clear()
    start = time.monotonic()
    result = run_cli("replay", str(bag), "--topics", "/joint_states", timeout=60)
    wall = time.monotonic() - start
    assert result.returncode == 0, result.stderr
    recorded = [deserialize_message(m.data, JointState)
                for m in open_bag(bag).messages("/joint_states")]
    deadline = time.monotonic() + 20.0
    while len(probe.messages("/joint_states")) < len(recorded) and time.monotonic() < deadline:
        time.sleep(0.01)
    received = probe.messages("/joint_states")
    assert received == recorded, (
        f"{len(received)} of {len(recorded)} received; the first received is recorded message "
        f"{recorded.index(received[0]) if received and received[0] in recorded else None}")
    assert wall < 30, f"replay took {wall:.1f} s"


# --- crashes and failures ---------------------------------------------------------------------

def assert_resimulates_exactly(bag: Path) -> None:
    result = run_cli("replay", str(bag), "--resimulate")
    assert result.returncode == 0 and "IDENTICAL" in result.stdout, result.stdout + result.stderr


def test_reset_starts_a_new_bag_and_sigkill_leaves_complete_chunks_readable(probe, tmp_path):
    bag = tmp_path / "killed"
    simulator = start_simulator(probe, tmp_path, *FAST, "-p", f"record:={bag}")
    try:
        wait_for(lambda: len(probe.messages("/joint_states")) > 50, "50 states")
        client = probe.node.create_client(Trigger, "/mobile_manip_sim/reset")
        try:
            wait_for(client.service_is_ready, "the reset service")
            future = client.call_async(Trigger.Request())
            wait_for(future.done, "the reset")
        finally:
            probe.node.destroy_client(client)
        wait_for(lambda: f"recording on in {bag}_1" in simulator.output(), "the second bag")
        second = bag_file(tmp_path / "killed_1")
        wait_for(lambda: second.stat().st_size > 4 * DEFAULT_CHUNK_SIZE // 3, "chunks on disk")
    finally:
        code = simulator.stop(signal.SIGKILL)
    assert code == -signal.SIGKILL
    # The reset closed the first time line's bag: complete, and a run of its own.
    assert (bag / "metadata.yaml").exists() and not open_bag(bag).recovered
    assert_resimulates_exactly(bag)

    killed = tmp_path / "killed_1"
    assert not (killed / "metadata.yaml").exists()
    recovered = open_bag(killed)
    assert recovered.recovered
    ours = list(recovered.messages())
    assert len(ours) > 100
    stamps = [m.log_time_ns for m in ours if m.topic == "/joint_states"]
    assert stamps == [k * PERIOD_NS for k in range(len(stamps))]
    # mcap's own stream reader gets the same messages before it meets the cut.
    theirs = []
    with open(bag_file(killed), "rb") as stream:
        with pytest.raises(McapError):   # at the cut
            for _, channel, message in NonSeekingReader(stream).iter_messages(
                    log_time_order=False):
                theirs.append((channel.topic, message.log_time))
    assert sorted(theirs) == sorted((m.topic, m.log_time_ns) for m in ours)
    # What survived is a complete record of the run up to there: it re-simulates exactly.
    assert_resimulates_exactly(killed)


def test_a_write_failure_stops_recording_but_not_the_simulation(probe, tmp_path):
    limit = 3 * DEFAULT_CHUNK_SIZE   # files this process writes may not grow beyond this

    def limit_file_size():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    bag = tmp_path / "limited"
    simulator = start_simulator(probe, tmp_path, *FAST, "-p", f"record:={bag}",
                                preexec_fn=limit_file_size)
    try:
        wait_for(lambda: "recording stopped" in simulator.output(), "the recording error")
        count = len(probe.messages("/joint_states"))
        wait_for(lambda: len(probe.messages("/joint_states")) > count + 100,
                 "publishing to go on")
        assert simulator.process.poll() is None
    finally:
        code = simulator.stop(signal.SIGINT)
    assert code == 0, simulator.output()
    errors = [line for line in simulator.output().splitlines() if "recording stopped" in line]
    assert len(errors) == 1 and "File too large" in errors[0], simulator.output()
    assert "Traceback" not in simulator.output()
    assert open_bag(bag).recovered and list(open_bag(bag).messages("/clock"))


def test_an_unwritable_record_path_exits_2_with_one_line(tmp_path):
    line = one_error_line(run_cli("simulator", "--ros-args", "-p",
                                  "record:=/proc/no_such_dir/bag"), "simulator")
    assert "record: /proc/no_such_dir/bag: cannot create bag directory" in line
    occupied = tmp_path / "occupied"
    occupied.mkdir()
    (occupied / "keep.txt").write_text("not a bag")
    line = one_error_line(run_cli("simulate", "--duration", "0.1", "--out",
                                  str(tmp_path / "r.csv"), "--record", str(occupied)), "simulate")
    assert "already exists and is not an empty directory" in line


# --- bad input to replay ------------------------------------------------------------------------

def test_replay_rejects_bad_bags_with_one_line(headless_bags, tmp_path):
    bag = headless_bags[0]
    line = one_error_line(run_cli("replay", str(tmp_path / "missing")), "replay")
    assert "no such bag" in line
    (tmp_path / "empty").mkdir()
    assert "not a rosbag2 MCAP bag" in one_error_line(run_cli("replay", str(tmp_path / "empty")),
                                                      "replay")
    text = tmp_path / "notes.mcap"
    text.write_text("just some text, not an MCAP file\n")
    assert "not an MCAP file" in one_error_line(run_cli("replay", str(text)), "replay")
    data = bag_file(bag).read_bytes()
    for cut, expected in ((20, "no complete MCAP header"), (600, "no complete message")):
        truncated = tmp_path / f"cut{cut}.mcap"
        truncated.write_bytes(data[:cut])
        for mode in ([], ["--resimulate"]):
            line = one_error_line(run_cli("replay", str(truncated), *mode), "replay")
            assert expected in line, line
    line = one_error_line(run_cli("replay", str(bag), "--topics", "/odom", "/scan"), "replay")
    assert line.startswith("replay: error: /scan: not in bag") and "/joint_states" in line


def test_replay_rejects_a_bag_from_another_robot(headless_bags, tmp_path):
    def rename_joints(topic, data, index):
        if topic != "/joint_states":
            return data
        message = deserialize_message(data, JointState)
        message.name = ["left", "right", "shoulder", "slide"]
        message.position, message.velocity = message.position[:4], message.velocity[:4]
        return exact_cdr(message)

    other = tmp_path / "other_robot"
    rewrite_bag(headless_bags[0], other, rename_joints)
    for mode in (["--resimulate"], ["--topics", "/odom"]):
        line = one_error_line(run_cli("replay", str(other), *mode), "replay")
        assert "a bag from another robot" in line, line


def rclpy_type_hashes() -> dict:
    """Type name → the RIHS01 hash rclpy reports for a live publisher of that type."""
    import importlib
    context = Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    try:
        node = rclpy.create_node("type_hash_probe", context=context)
        hashes = {}
        for index, type_name in enumerate(sorted(set(TOPIC_TYPES.values()))):
            package, _, name = type_name.partition("/msg/")
            kind = getattr(importlib.import_module(f"{package}.msg"), name)
            node.create_publisher(kind, f"/type_hash_{index}", 1)
            info = node.get_publishers_info_by_topic(f"/type_hash_{index}")
            hashes[type_name] = str(info[0].topic_type_hash)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    return hashes


def test_a_node_bag_carries_rclpys_type_hashes(node_run, interfaces_prefix):
    """RIHS01 hashes in metadata.yaml and in each channel's metadata, as Jazzy's `ros2 bag
    record` writes them: equal to what rclpy reports for each type (and to rosbags' own)."""
    bag, _, _ = node_run
    expected = rclpy_type_hashes()
    typestore = get_typestore(Stores.ROS2_JAZZY)
    assert all(re.fullmatch(r"RIHS01_[0-9a-f]{64}", h) for h in expected.values()), expected
    assert all(typestore.hash_rihs01(name) == h for name, h in expected.items())
    assert set(expected) == set(TOPIC_TYPES.values())   # tf2_msgs too: built into the venv
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    topics = [entry["topic_metadata"] for entry in info["topics_with_message_count"]]
    assert {t["name"] for t in topics} == set(TOPIC_TYPES)
    assert all(t["type_description_hash"] == expected[t["type"]] for t in topics), topics
    with open(bag_file(bag), "rb") as stream:
        channels = make_reader(stream).get_summary().channels.values()
        assert {c.topic: c.metadata["topic_type_hash"] for c in channels} == {
            topic: expected[type_name] for topic, type_name in TOPIC_TYPES.items()}


def _last_state_on_disk(path: Path) -> int:
    """The latest /joint_states stamp that mcap's stream reader finds in the file so far (ns);
    -1 when none."""
    last = -1
    try:
        with open(path, "rb") as stream:
            for _, channel, message in NonSeekingReader(stream).iter_messages(
                    log_time_order=False):
                if channel.topic == "/joint_states":
                    last = max(last, message.log_time)
    except (McapError, OSError, EOFError):
        pass   # the cut at the open end of a file being written
    return last


def test_a_paused_node_puts_its_recording_on_disk_and_a_sigkill_keeps_it(probe, tmp_path):
    """While paused nothing new is recorded, yet the open chunk goes to disk on the flush
    timer: the state the pause stopped at reaches the file without any further state (it
    stayed in memory for ever before), and survives a SIGKILL."""
    from std_srvs.srv import SetBool
    bag = tmp_path / "paused"
    simulator = start_simulator(probe, tmp_path, *FAST, "-p", f"record:={bag}")
    try:
        wait_for(lambda: len(probe.messages("/joint_states")) > 20, "20 states")
        client = probe.node.create_client(SetBool, "/mobile_manip_sim/pause")
        try:
            wait_for(client.service_is_ready, "the pause service")
            future = client.call_async(SetBool.Request(data=True))
            wait_for(future.done, "the pause")
        finally:
            probe.node.destroy_client(client)
        answer = future.result().message
        seconds, nanos = re.search(r"paused at t = (\d+)\.(\d{9}) s", answer).groups()
        paused_at = int(seconds) * 10 ** 9 + int(nanos)
        wait_for(lambda: _last_state_on_disk(bag_file(bag)) >= paused_at,
                 "the state the node paused at, on disk")
    finally:
        code = simulator.stop(signal.SIGKILL)
    assert code == -signal.SIGKILL
    recovered = open_bag(bag)
    stamps = [m.log_time_ns for m in recovered.messages() if m.topic == "/joint_states"]
    assert stamps == [k * PERIOD_NS for k in range(len(stamps))] and stamps[-1] == paused_at


def test_replay_imports_nothing_a_bag_names_and_leaves_out_names_rcl_refuses(tmp_path):
    """A crafted bag: type names `this/msg/Zen` (which imported `this` and printed the Zen of
    Python) and `..os/msg/X`, a topic `/bad name!` (create_publisher's traceback). Each is left
    out with one warning and the rest plays; named with --topics, one line, status 2."""
    from mcap.writer import Writer

    from mobile_manip_sim.ros.message_definitions import definition_text
    path = tmp_path / "hostile.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start(profile="ros2", library="test")
        string = writer.register_schema("std_msgs/msg/String", "ros2msg",
                                        definition_text("std_msgs/msg/String").encode())
        zen = writer.register_schema("this/msg/Zen", "ros2msg", b"string data")
        dots = writer.register_schema("..os/msg/X", "ros2msg", b"string data")
        channels = [writer.register_channel(topic, "cdr", schema) for topic, schema in (
            ("/chatter", string), ("/bad name!", string), ("/zen", zen), ("/os", dots))]
        data = exact_cdr(String(data="hi"))
        for k in range(5):
            for channel in channels:
                writer.add_message(channel, log_time=k * 10 ** 8, data=data,
                                   publish_time=k * 10 ** 8)
        writer.finish()
    result = run_cli("replay", str(path))
    assert result.returncode == 0, result.stderr
    assert "played 5 messages on 1 topics" in result.stdout
    assert "Beautiful is better than ugly" not in result.stdout + result.stderr
    warnings = result.stderr.strip().splitlines()
    assert warnings == [
        "replay: warning: /bad name! not played: not a valid ROS 2 topic name",
        "replay: warning: /zen not played: this/msg/Zen: package this is not a known ROS 2 "
        "message package",
        "replay: warning: /os not played: ..os/msg/X: not a message type name (package/msg/Type)"]
    for topic in ("/zen", "/bad name!"):
        named = run_cli("replay", str(path), "--topics", topic)
        lines = named.stderr.strip().splitlines()
        assert named.returncode == 2 and len(lines) == 1 and topic in lines[0], named.stderr


@pytest.mark.parametrize("rows", [[[0.1, 0.2], [0.1]], [[0.1, 0.2, 0.3], [0.1, 0.2, 0.3]],
                                  [[], []]])
def test_a_recorded_trajectory_with_ragged_or_wrong_length_points_is_one_line(rows):
    """What `replay --resimulate` reads back from an arm trajectory record: a damaged one (rows
    of the wrong length, ragged) is one line naming the point, not numpy's error."""
    from mobile_manip_sim.ros.messages import trajectory_values
    from mobile_manip_sim.scene.errors import UserError
    message = JointTrajectory(joint_names=["a", "b"])
    for i, row in enumerate(rows):
        point = JointTrajectoryPoint(positions=row)
        point.time_from_start.sec = i + 1
        message.points.append(point)
    with pytest.raises(UserError) as caught:
        trajectory_values(message)
    assert str(caught.value).startswith("recorded trajectory point ") and \
        "\n" not in str(caught.value)
