"""The node's browser view (node/view.py's ``browser_port``), as a user sees it: the `simulator`
in its own process, driven by arm efforts from a test node on a private domain, and a real
headless chromium loading the page the node's log names: the robot is drawn and moves, and the
page asks nothing of any other host. A bad or taken port is one line naming the parameter."""
import re
import socket
import subprocess

import rclpy
from std_msgs.msg import Float64MultiArray

from executables import executable
from headless_browser import HEIGHT, WIDTH, Browser
from mobile_manip_sim.ros.topics import ARM_TOPIC
from ros_harness import NodeProcess, child_env, private_domain, spinning
from test_browser import moved_pixels, requests_by_host, two_instants
from waiting import wait_for

DOMAIN_ID = private_domain(230, 232)
TIMEOUT = 120.0
ARM_EFFORTS = [2.0, 3.0, 1.0, 1.0]   # N·m, N, N·m, N: the arm turns, the rods slide


class Driver:
    """Publishes the arm's efforts 20 times a second (within the node's command timeout)."""

    def __init__(self, context):
        self.node = rclpy.create_node("browser_test_driver", context=context)
        publisher = self.node.create_publisher(Float64MultiArray, ARM_TOPIC, 10)
        self.node.create_timer(0.05, lambda: publisher.publish(
            Float64MultiArray(data=ARM_EFFORTS)))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_node_shows_its_robot_moving_in_a_browser(tmp_path):
    node = NodeProcess(tmp_path, "-p", "arm_controller:=effort", "-p",
                       f"browser_port:={free_port()}", env=child_env(DOMAIN_ID))
    try:
        url = wait_for(lambda: (re.findall(r"view: (http://\S+)", node.output()) or
                                [None])[0] or (not node.running() and node.output()),
                       "the node's browser view line", TIMEOUT)
        assert url.startswith("http://localhost:"), url
        with spinning(Driver, DOMAIN_ID), Browser() as browser:
            first, second = two_instants(browser, url, (0, 0, WIDTH, HEIGHT))
            outside, sockets = requests_by_host(browser, url)
    finally:
        status = node.stop()
    assert status == 0, node.output()
    before, after, changed = moved_pixels(first, second, (0, 0, WIDTH, HEIGHT))
    assert before >= 30 and after >= 30 and changed > 0.3 * before, (before, after, changed)
    assert outside == [] and sockets, (outside, sockets)


def test_bad_browser_parameters_are_one_line_naming_them():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        for rule, problem in ((f"browser_port:={port}", "browser_port: cannot serve the "
                               "browser view on 127.0.0.1: the port is in use"),
                              ("browser_port:=70000", "browser_port: "),
                              ("browser_host:=a b", "browser_host: 'a b' is not a host name")):
            result = subprocess.run([executable("simulator"), "--ros-args", "-p", rule],
                                    env=child_env(DOMAIN_ID), capture_output=True, text=True,
                                    timeout=120)
            assert result.returncode == 2, result.stderr
            lines = result.stderr.strip().splitlines()
            assert len(lines) == 1 and lines[0].startswith(f"simulator: error: {problem}"), \
                result.stderr
