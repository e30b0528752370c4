"""What the node shows (node/view.py), as users see it: the `simulator` executable in its
own process, tf listeners in processes of their own that import tf2_msgs (built into the venv by
tools/bootstrap.sh), a probe node in this process, real DDS on a private domain.

- every link frame composed from /tf and /tf_static equals Pinocchio's forward kinematics on the
  node's own /robot_description at the published joint positions (paper robot, random 5-link arm);
- /tf_static reaches a late subscriber as ONE message with every fixed joint;
- two namespaced simulators with frame_prefix make one tree (each frame one parent, no frame of
  one robot in the other's), one /clock (publish_clock false on the second), which a
  use_sim_time node in a namespace follows;
- publish_tf none publishes neither; QoS overrides reach the publishers (read from this process)
  and bad ones are one line;
- /imu at rest reads (0, 0, g) and zero rates (a perfect sensor: covariances at the floor);
- foxglove_port: a third-party Foxglove client gets every channel with its ros2msg schema and
  decodes /tf and /joint_states at the publication rate;
- foxglove_host: the default serves this machine only (a client at its network address is
  refused), 0.0.0.0 every interface."""
import json
import os
import re
import signal
import socket
import subprocess
import sys

import numpy as np
import pinocchio as pin
import pytest
import rclpy
import yaml
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu

import foxglove_js
import interfaces_build
from engine_cases import base_only_doc
from executables import executable
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.ros.frames import FrameTree
from mobile_manip_sim.ros.topics import LIVE_TOPIC_TYPES
from mobile_manip_sim.scene.loading import load_scene
from raw_websocket import RawClient
from ros_harness import NodeProcess, child_env, private_domain, spinning
from ros_harness import wait_for as harness_wait_for
from test_urdf import SCENES

DOMAIN_ID = private_domain(200, 229)
LISTENER = os.path.join(os.path.dirname(__file__), "..", "helpers", "view_listener.py")
FAST = ["-p", "integrator.method:=rk4", "-p", "integrator.dt:=0.001"]
PERIOD_NS = 10 ** 7     # publish_rate 100 Hz
TOL = 1e-9
TIMEOUT = 60.0
RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)


@pytest.fixture(scope="module")
def tf2_env():
    interfaces_build.installed()
    return child_env(DOMAIN_ID)


class Probe:
    """Counts /clock and keeps the last /imu messages; asks the graph."""

    def __init__(self, context):
        self.node = rclpy.create_node("view_test_probe", context=context)
        self.clock, self.imu, self.robot2 = [], [], []
        self.node.create_subscription(Clock, "/clock", self.clock.append, RELIABLE)
        self.node.create_subscription(Imu, "/imu", self.imu.append, RELIABLE)
        self.node.create_subscription(Imu, "/robot2/imu", self.robot2.append, RELIABLE)

    def publishers(self, topic: str) -> list:
        return self.node.get_publishers_info_by_topic(topic)


@pytest.fixture(scope="module")
def probe():
    with spinning(Probe, DOMAIN_ID) as probe:
        yield probe


def wait_for(predicate, what: str, timeout: float = TIMEOUT):
    return harness_wait_for(predicate, what, timeout)


def start(tmp_path, env, *args) -> NodeProcess:
    return NodeProcess(tmp_path, *FAST, *args, env=env)


def listen(env, count: int, namespace: str = "", statics: int = 1, prefixes=("",),
           matched: int = 0) -> dict:
    listener = subprocess.Popen([sys.executable, LISTENER, str(count), namespace, str(statics),
                                 ",".join(prefixes), str(matched)],
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
    try:
        out, err = listener.communicate(timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        listener.send_signal(signal.SIGINT)
        out, err = listener.communicate(timeout=TIMEOUT)
    assert listener.returncode == 0, err[-3000:]
    return json.loads(out)


def stop(node: NodeProcess) -> None:
    assert node.stop() == 0, node.output()


def scene_file(tmp_path, name: str) -> str:
    path = tmp_path / f"{name}.yaml"
    path.write_text(SCENES[name].to_yaml() if name in SCENES else yaml.safe_dump(name))
    return str(path)


def se3(row) -> pin.SE3:
    x, y, z, qx, qy, qz, qw = row[3:]
    return pin.SE3(pin.Quaternion(qw, qx, qy, qz).matrix(), np.array([x, y, z]))


@pytest.mark.parametrize("name", ["paper", "random_5"])
def test_every_link_on_tf_is_the_urdf_forward_kinematics(probe, tf2_env, tmp_path, name):
    node = start(tmp_path, tf2_env, "-p", f"scene:={scene_file(tmp_path, name)}")
    try:
        # a LATE subscriber: the node has published for a while when the listener starts
        wait_for(lambda: len(probe.clock) > 20 or not node.running(), "the node's /clock",
                 TIMEOUT)
        seen = listen(tf2_env, 30, matched=25)
    finally:
        stop(node)
    robot = SCENES[name].robot
    tree = FrameTree(robot)
    assert len(seen["static"]) == 1   # one latched message, every fixed joint in it
    assert [row[1:3] for row in seen["static"][0]] == [[j.parent, j.child] for j in tree.fixed]
    model = pin.buildModelFromXML(seen["description"], pin.JointModelPlanar())
    data = model.createData()
    by_stamp = {}
    for row in seen["tf"]:
        by_stamp.setdefault(row[0], []).append(row)
    compared = 0
    for stamp, rows in by_stamp.items():
        if str(stamp) not in seen["joints"] or str(stamp) not in seen["odom"]:
            continue
        assert [r[1:3] for r in rows] == [["odom", tree.root]] + [[j.parent, j.child]
                                                                  for j in tree.moving]
        names, positions = seen["joints"][str(stamp)]
        _, _, x, y, qz, qw = seen["odom"][str(stamp)]
        q = np.zeros(model.nq)
        q[:4] = x, y, qw * qw - qz * qz, 2.0 * qz * qw     # planar root: x, y, cos, sin yaw
        for joint_name, value in zip(names, positions, strict=True):
            joint = model.joints[model.getJointId(joint_name)]
            q[joint.idx_q:joint.idx_q + joint.nq] = ((np.cos(value), np.sin(value))
                                                     if joint.nq == 2 else value)
        pin.framesForwardKinematics(model, data, q)
        poses = {}
        for row in rows[:1] + seen["static"][0][:1] + rows[1:] + seen["static"][0][1:]:
            parent = poses.get(row[1], pin.SE3.Identity())
            poses[row[2]] = parent * se3(row)
        assert set(poses) == set(tree.links)
        for frame, pose in poses.items():
            reference = data.oMf[model.getFrameId(frame)]
            assert np.max(np.abs(pose.translation - reference.translation)) < TOL, frame
            assert np.max(np.abs(pose.rotation - reference.rotation)) < TOL, frame
        compared += 1
    assert compared >= 25


class SimTimeClient:
    """A node in /robot1 with use_sim_time, as a controller there would run."""

    def __init__(self, context):
        self.node = rclpy.create_node("sim_time_client", namespace="/robot1", context=context,
                                      parameter_overrides=[rclpy.parameter.Parameter(
                                          "use_sim_time", value=True)])

    def now_ns(self) -> int:
        return self.node.get_clock().now().nanoseconds


def test_two_namespaced_simulators_make_one_tree_and_one_clock(probe, tf2_env, tmp_path):
    first = start(tmp_path, tf2_env, "-r", "__ns:=/robot1", "-p", "frame_prefix:=robot1/")
    second = start(tmp_path, tf2_env, "-r", "__ns:=/robot2", "-p", "frame_prefix:=robot2/",
                   "-p", "publish_clock:=false")
    try:
        # the second follows the first's /clock: it publishes once it has heard it
        wait_for(lambda: len(probe.robot2) >= 5, "the second simulator following the clock")
        seen = listen(tf2_env, 25, "/robot1", statics=2, prefixes=("robot1/", "robot2/"))
        # one /clock, absolute (not /robot1/clock), from the first simulator only
        wait_for(lambda: len(probe.publishers("/clock")) == 1 or None, "one /clock publisher")
        assert probe.publishers("/robot1/clock") == probe.publishers("/robot2/clock") == []
        with spinning(SimTimeClient, DOMAIN_ID) as client:
            before = wait_for(lambda: client.now_ns(), "sim time in /robot1", TIMEOUT)
            wait_for(lambda: client.now_ns() > before, "sim time moving on in /robot1")
    finally:
        stop(first)
        stop(second)
    tree = FrameTree(SCENES["paper"].robot)
    edges = {(row[1], row[2]) for row in seen["tf"]}
    edges |= {(row[1], row[2]) for message in seen["static"] for row in message}
    parents = {}
    for parent, child in edges:
        parents.setdefault(child, set()).add(parent)
    assert all(len(p) == 1 for p in parents.values()), parents   # no frame with two parents
    expected = set()
    for prefix in ("robot1/", "robot2/"):
        expected |= {(prefix + "odom", prefix + tree.root)}
        expected |= {(prefix + j.parent, prefix + j.child) for j in tree.joints}
    assert edges == expected
    odom = next(iter(seen["odom"].values()))
    assert odom[:2] == ["robot1/odom", "robot1/base_footprint"]
    assert 'link name="robot1/base_link"' in seen["description"]
    assert 'joint name="arm_revolute_1"' in seen["description"]   # joint names stay bare


def qos_of(probe, topic):
    infos = wait_for(lambda: probe.publishers(topic), f"a publisher of {topic}")
    return infos[0].qos_profile


def parameter(probe, name: str):
    """The node's parameter ``name`` read through its get_parameters service."""
    from rcl_interfaces.srv import GetParameters
    client = probe.node.create_client(GetParameters, "/mobile_manip_sim/get_parameters")
    assert client.wait_for_service(timeout_sec=TIMEOUT)
    response = client.call(GetParameters.Request(names=[name]), timeout_sec=TIMEOUT)
    probe.node.destroy_client(client)
    return response.values[0]


def test_publish_tf_none_and_qos_overrides_as_another_process_sees_them(probe, tf2_env,
                                                                        tmp_path):
    """Reliability and durability are what discovery tells another process; depth is the
    publisher's own, read back from the parameter the override set."""
    node = start(tmp_path, tf2_env, "-p", "publish_tf:=none",
                 "-p", "qos_overrides./odom.publisher.reliability:=best_effort",
                 "-p", "qos_overrides./odom.publisher.depth:=7",
                 "-p", "qos_overrides./clock.publisher.reliability:=best_effort")
    try:
        odom = qos_of(probe, "/odom")
        clock, joints = qos_of(probe, "/clock"), qos_of(probe, "/joint_states")
        description = qos_of(probe, "/robot_description")
        depth = parameter(probe, "qos_overrides./odom.publisher.depth")
        tf, tf_static = probe.publishers("/tf"), probe.publishers("/tf_static")
    finally:
        stop(node)
    assert odom.reliability == clock.reliability == rclpy.qos.ReliabilityPolicy.BEST_EFFORT
    assert joints.reliability == rclpy.qos.ReliabilityPolicy.RELIABLE
    assert description.durability == rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL
    assert depth.integer_value == 7
    assert tf == tf_static == []


@pytest.mark.parametrize("rule, key, problem", [
    ("qos_overrides./odom.publisher.reliability:=sometimes",
     "qos_overrides./odom.publisher.reliability", "expected one of reliable, best_effort"),
    ("qos_overrides./odom.publisher.depth:=0", "qos_overrides./odom.publisher.depth",
     "expected an integer from 1 to 100000, got 0"),
    ("qos_overrides./odm.publisher.depth:=5", "qos_overrides./odm.publisher.depth",
     "unknown QoS override"),
    ("publish_tf:=some", "publish_tf", "'some' is not one of all, base, none"),
    ("imu.noise.linear_acceleration_stddev:=[0.1, -0.1, 0.0]",
     "imu.noise.linear_acceleration_stddev[1]", ""),
    ("foxglove_port:=70000", "foxglove_port", "outside [0, 65535]"),
    ("qos_overrides./odom.publisher.depth:=1000000000000", "qos_overrides./odom.publisher.depth",
     "expected an integer from 1 to 100000, got 1000000000000"),
    ("imu.noise.angular_velocity_bias:=[]", "imu.noise.angular_velocity_bias",
     "got an empty list"),
    ("arm_gains.kp:=[]", "arm_gains.kp", "got an empty list"),
    ("foxglove_host:=a b", "foxglove_host", "'a b' is not a host name or address"),
    ("odom_frame:=a b", "odom_frame", "'a b' is not a tf frame name"),
    ("odom_frame:=/odom", "odom_frame", "'/odom' is not a tf frame name"),
    ("odom_frame:=tip", "odom_frame", "'tip' is the name of one of the robot's links"),
    ("base_frame:=left_wheel", "base_frame", "'left_wheel' is the name of one of the robot's"),
    ("frame_prefix:=robot1//", "frame_prefix", "no empty part"),
    ("record:=null", "record", "YAML's null, not a directory"),
])
def test_bad_view_parameters_exit_2_with_one_line(rule, key, problem):
    result = subprocess.run([executable("simulator"), "--ros-args", "-p", rule],
                            env=child_env(DOMAIN_ID), capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"simulator: error: {key}: "), result.stderr
    assert problem in lines[0], lines[0]


def imu_run(probe, tmp_path, count: int, *args) -> list:
    """The /imu messages of a node started with ``args``, once ``count`` have come."""
    probe.imu.clear()
    node = start(tmp_path, child_env(DOMAIN_ID), *args)
    try:
        wait_for(lambda: len(probe.imu) > count or not node.running(), "/imu", TIMEOUT)
    finally:
        stop(node)
    return list(probe.imu)


def test_a_foxglove_port_in_use_is_one_line_naming_the_parameter():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = subprocess.run([executable("simulator"), "--ros-args", "-p",
                                 f"foxglove_port:={port}"], env=child_env(DOMAIN_ID),
                                capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("simulator: error: foxglove_port: cannot "
                                                   "start the Foxglove server"), result.stderr


def test_imu_at_rest_reads_g_up_and_no_rate(probe, tmp_path):
    doc = base_only_doc()
    gravity = 9.81
    doc["effects"] = {**doc.get("effects", {}), "gravity": gravity}
    path = tmp_path / "base.yaml"
    path.write_text(yaml.safe_dump(doc))
    for message in imu_run(probe, tmp_path, 20, "-p", f"scene:={path}"):
        a, w = message.linear_acceleration, message.angular_velocity
        assert (a.x, a.y, a.z) == (0.0, 0.0, gravity)
        assert (w.x, w.y, w.z) == (0.0, 0.0, 0.0)
        assert message.header.frame_id == "base_link"
        assert message.orientation.w == 1.0
        assert list(message.linear_acceleration_covariance)[::4] == [1e-9] * 3


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_foxglove_client_sees_the_robot_of_the_node(probe, tmp_path):
    modules = foxglove_js.install()
    port = free_port()
    node = start(tmp_path, child_env(DOMAIN_ID), "-p", f"foxglove_port:={port}")
    try:
        wait_for(lambda: "live view: ws://localhost:" in node.output() or not node.running(),
                 "the live view", TIMEOUT)
        events = foxglove_js.run(modules, f"ws://localhost:{port}",
                                 {"/tf": 100, "/joint_states": 100, "/robot_description": 1,
                                  "/tf_static": 1, "/imu": 1})
    finally:
        stop(node)
    channels = {e["topic"]: e for e in events if e["event"] == "channel"}
    assert {t: (c["schemaName"], c["schemaEncoding"], c["encoding"])
            for t, c in channels.items()} == {t: (kind, "ros2msg", "cdr")
                                              for t, kind in LIVE_TOPIC_TYPES.items()}
    tree = FrameTree(load_scene().robot)
    for topic in ("/tf", "/joint_states"):
        received = [e for e in events if e["event"] == "message" and e["topic"] == topic]
        stamps = [int(m["stamp"]) for m in received]
        assert len(stamps) >= 100
        assert all(b - a == PERIOD_NS for a, b in zip(stamps, stamps[1:], strict=False)), \
            stamps[:10]
        assert all(int(m["logTime"]) == int(m["stamp"]) for m in received)
    tf = next(e for e in events if e["event"] == "message" and e["topic"] == "/tf")
    assert tf["frames"] == [["odom", tree.root]] + [[j.parent, j.child] for j in tree.moving]
    static = next(e for e in events if e["event"] == "message" and e["topic"] == "/tf_static")
    assert static["frames"] == [[j.parent, j.child] for j in tree.fixed]
    imu = next(e for e in events if e["event"] == "message" and e["topic"] == "/imu")
    assert imu["linear_acceleration"]["z"] == Simulation(load_scene()).dynamics.gravity


def network_address() -> str | None:
    """An IPv4 address of this machine that is not loopback — the one its route to the outside
    leaves from, or the first global one `ip` lists — or None."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
        try:
            udp.connect(("192.0.2.1", 9))   # TEST-NET-1; a UDP connect sends nothing
            address = udp.getsockname()[0]
        except OSError:
            address = None
    if address and not address.startswith("127."):
        return address
    try:
        listed = subprocess.run(["ip", "-4", "-o", "addr", "show", "scope", "global"],
                                capture_output=True, text=True, timeout=10).stdout
    except OSError:
        return None
    found = re.search(r"\binet (\d+\.\d+\.\d+\.\d+)/", listed)
    return found.group(1) if found else None


def live_view_node(tmp_path, port: int, *args) -> NodeProcess:
    """A node serving its live view on ``port``, once its start-up says so."""
    node = start(tmp_path, child_env(DOMAIN_ID), "-p", f"foxglove_port:={port}", *args)
    try:
        wait_for(lambda: "live view: ws://" in node.output() or not node.running(),
                 "the live view", TIMEOUT)
        assert node.running(), node.output()
    except BaseException:
        node.stop()
        raise
    return node


def test_foxglove_host_binds_where_it_says(probe, tmp_path):
    """The default (127.0.0.1) serves loopback and refuses a client that comes to this
    machine's network address; foxglove_host 0.0.0.0 takes it, and it gets the live channels."""
    address = network_address()
    if address is None:
        pytest.skip("this machine has no IPv4 address but loopback")
    port = free_port()
    node = live_view_node(tmp_path, port)
    try:
        RawClient(port).close()
        with pytest.raises(ConnectionRefusedError):
            RawClient(port, address)
    finally:
        stop(node)
    port = free_port()
    node = live_view_node(tmp_path, port, "-p", "foxglove_host:=0.0.0.0")
    try:
        client = RawClient(port, address)
        try:
            assert client.status.split()[1] == "101", client.status
            assert "/joint_states" in client.channels()
        finally:
            client.close()
    finally:
        stop(node)


def test_a_noisy_imu_is_recorded_and_resimulates_identical(probe, tmp_path):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore
    bag = tmp_path / "imu_run"
    imu_run(probe, tmp_path, 50, "-p", f"record:={bag}",
            "-p", "imu.noise.linear_acceleration_stddev:=[0.1, 0.1, 0.1]",
            "-p", "imu.noise.angular_velocity_bias:=[0.0, 0.0, 0.01]", "-p", "imu.noise.seed:=42")
    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as reader:
        imu = [store.deserialize_cdr(data, "sensor_msgs/msg/Imu")
               for connection, _, data in reader.messages() if connection.topic == "/imu"]
    assert len(imu) > 50
    first = imu[0]   # t = 0, at rest: the bias alone on the rate gyro
    assert (first.header.stamp.sec, first.header.stamp.nanosec) == (0, 0)
    assert first.angular_velocity.z == 0.01
    assert list(first.linear_acceleration_covariance) == [0.1 ** 2, 0, 0, 0, 0.1 ** 2, 0, 0, 0,
                                                          0.1 ** 2]   # σ² on the diagonal
    result = subprocess.run([executable("replay"), str(bag), "--resimulate"],
                            env=child_env(DOMAIN_ID), capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and "IDENTICAL" in result.stdout, result.stdout + result.stderr
    assert f"and {len(imu)} /imu from" in result.stdout, result.stdout
