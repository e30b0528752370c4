"""The live view (live_view.py) as Foxglove sees it: a third-party client — @foxglove/ws-protocol
under Node.js, decoding with the Foxglove app's own ros2msg/CDR readers — connects to
`simulate --view`, finds every channel with its ROS 2 schema, decodes /tf and /joint_states at
the sample rate (no stamp skipped or repeated), and a client that connects late still gets the
latched /robot_description and /tf_static."""
import itertools
import signal
import subprocess
import threading

import pytest

import foxglove_js
from executables import executable
from mobile_manip_sim.ros.frames import FrameTree
from mobile_manip_sim.ros.topics import LIVE_TOPIC_TYPES
from mobile_manip_sim.ros.urdf import robot_description
from mobile_manip_sim.scene.loading import load_scene

SIMULATE = executable("simulate")
PERIOD_NS = 10 ** 7     # --sample-rate 100


@pytest.fixture(scope="module")
def modules():
    return foxglove_js.install()


@pytest.fixture
def viewed_run(tmp_path):
    """`simulate --view 0` of the paper scene for 60 s (stopped by SIGTERM); yields its URL."""
    process = subprocess.Popen([SIMULATE, "--view", "0", "--duration", "60", "--out",
                                str(tmp_path / "run.csv")], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    timer = threading.Timer(120.0, process.kill)   # bounds the wait for the first line
    timer.start()
    try:
        first = process.stdout.readline()
    finally:
        timer.cancel()
    assert first.startswith("live view: ws://localhost:"), first + process.stderr.read()
    try:
        yield first.split()[2]
    finally:
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=30)
        assert process.returncode == 143, err   # stopped by the signal, as any run


def messages(events, topic):
    return [e for e in events if e["event"] == "message" and e["topic"] == topic]


def test_a_foxglove_client_sees_the_robot_of_simulate_view(modules, viewed_run):
    events = foxglove_js.run(modules, viewed_run, {"/tf": 100, "/joint_states": 100,
                                                   "/robot_description": 1, "/tf_static": 1})
    assert events[0] == {"event": "open", "protocol": "foxglove.sdk.v1"}
    channels = {e["topic"]: e for e in events if e["event"] == "channel"}
    assert {t: (c["schemaName"], c["schemaEncoding"], c["encoding"])
            for t, c in channels.items()} == {t: (kind, "ros2msg", "cdr")
                                              for t, kind in LIVE_TOPIC_TYPES.items()}
    scene = load_scene()
    tree = FrameTree(scene.robot)
    q0 = scene.initial_q
    for topic in ("/tf", "/joint_states"):
        received = messages(events, topic)
        stamps = [int(m["stamp"]) for m in received]
        assert len(stamps) >= 100
        # at the sample rate: every sample in turn, each message's time its own stamp
        assert all(b - a == PERIOD_NS for a, b in itertools.pairwise(stamps)), stamps[:10]
        assert all(int(m["logTime"]) == int(m["stamp"]) for m in received)
    tf = messages(events, "/tf")[0]
    expected = [tree.base_transform(q0)] + tree.moving_transforms(q0)
    assert tf["frames"] == [[t.parent, t.child] for t in expected]
    assert messages(events, "/joint_states")[0]["names"] == scene.robot.joint_names()
    static = messages(events, "/tf_static")
    assert [s["frames"] for s in static[:1]] == [[[t.parent, t.child]
                                                  for t in tree.static_transforms()]]
    description = messages(events, "/robot_description")
    assert description[0]["length"] == len(robot_description(scene))

    # A client that connects now, long after t = 0, still gets the latched ones.
    late = foxglove_js.run(modules, viewed_run, {"/robot_description": 1, "/tf_static": 1,
                                                 "/tf": 1})
    latest = int(messages(late, "/tf")[0]["stamp"])
    assert latest > int(messages(events, "/tf")[-1]["stamp"])
    assert messages(late, "/robot_description")[0]["length"] == len(robot_description(scene))
    assert messages(late, "/tf_static")[0]["stamp"] == "0"


@pytest.mark.parametrize("port, problem", [("70000", "must be in [0, 65535]"),
                                           ("x", "invalid int value")])
def test_a_bad_view_port_is_a_one_line_error(port, problem):
    result = subprocess.run([SIMULATE, "--view", port, "--out", "/dev/null"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and problem in lines[0], result.stderr


def test_a_view_port_in_use_is_a_one_line_error():
    from mobile_manip_sim.ros.live_view import LiveView

    view = LiveView(0)
    try:
        result = subprocess.run([SIMULATE, "--view", str(view.port), "--out", "/dev/null"],
                                capture_output=True, text=True, timeout=120)
    finally:
        view.close()
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and f"port {view.port}" in lines[0], result.stderr
