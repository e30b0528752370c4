"""/tf as a ROS user sees it: the node and a subscriber in separate processes, with tf2_msgs
as tools/bootstrap.sh installs it into the venv (the fixture `interfaces_prefix` checks it is
there), real DDS on a random domain. Without tf2_msgs (hidden from the node's process) the node
says so in one line and runs on. The whole tree (publish_tf all): test_node_view.py."""
import itertools
import os
import signal
import subprocess
import sys
import threading

import interfaces_build
from executables import executable
from ros_harness import child_env, private_domain

SIMULATOR = executable("simulator")
LISTENER = os.path.join(os.path.dirname(__file__), "..", "helpers", "tf_listener.py")
PERIOD_NS = 10 ** 7   # publish_rate 100 Hz


def test_publish_tf_base_carries_odom_to_base_footprint_alone_at_every_publication(
        interfaces_prefix, tmp_path):
    """publish_tf base (for users who run robot_state_publisher): /tf carries the base alone."""
    env = child_env(private_domain(1, 99))
    listener = subprocess.Popen([sys.executable, LISTENER, "200"], env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    node = subprocess.Popen([SIMULATOR, "--ros-args", "-p", "integrator.method:=rk4",
                             "-p", "integrator.dt:=0.001", "-p", "real_time_factor:=5.0",
                             "-p", "publish_tf:=base"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        out, err = listener.communicate(timeout=120)
    finally:
        node.send_signal(signal.SIGTERM)
        log = node.communicate(timeout=30)[0]
    assert listener.returncode == 0, err
    assert node.returncode == 0 and "tf2_msgs does not import" not in log, log
    rows = [line.split() for line in out.splitlines()]
    assert len(rows) >= 200
    assert {(row[1], row[2]) for row in rows} == {("odom", "base_footprint")}
    stamps = [int(row[0]) for row in rows]
    # Simulated-time stamps, one per publication period, none skipped or repeated.
    assert all(b - a == PERIOD_NS for a, b in itertools.pairwise(stamps)), stamps[:20]
    assert all(abs(float(r[5]) ** 2 + float(r[6]) ** 2 - 1.0) < 1e-12 for r in rows)


def test_without_tf2_msgs_the_node_says_so_once_and_runs(tmp_path):
    env = interfaces_build.without(child_env(private_domain(1, 99)))
    node = subprocess.Popen([SIMULATOR, "--ros-args", "-p", "real_time_factor:=5.0"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    timer = threading.Timer(60.0, node.kill)   # bounds the wait for the start-up lines
    timer.start()
    lines = []
    try:
        for line in node.stdout:   # until the start-up line and the warning after it
            lines.append(line)
            if "tf2_msgs does not import" in line:
                break
    finally:
        timer.cancel()
        node.send_signal(signal.SIGTERM)
    log = "".join(lines) + node.communicate(timeout=30)[0]
    assert node.returncode == 0, log
    assert log.count("tf2_msgs does not import") == 1, log
