"""`replay`'s pacing and its wait for subscribers.

Pacing is checked on a fake wall clock (no timing race): a bag whose scan to --start-offset
costs a lot of (fake) time must still be played from the offset at the recorded pace, never in
a burst. The wait for subscribers is checked with the real executable and a real subscriber
that takes only one of the bag's topics."""
import subprocess
import threading
from dataclasses import dataclass

import pytest
import rclpy
from nav_msgs.msg import Odometry
from rclpy.qos import QoSProfile, ReliabilityPolicy

from executables import executable
from mobile_manip_sim.recording.bag_reader import open_bag
from mobile_manip_sim.replay.play import _play_once
from ros_harness import child_env, on_domain, private_domain, spinning, wait_for

DOMAIN_ID = private_domain(1, 232)
NS = 1_000_000_000


@dataclass
class Message:
    topic: str
    log_time_ns: int
    data: bytes = b""


class FakeWall:
    """A wall clock that moves only when told: by sleeps, and by reading the bag."""

    def __init__(self):
        self.now = 100.0

    def sleep(self, seconds: float) -> None:
        assert seconds > 0
        self.now += seconds


class SlowBag:
    """Messages every 10 ms for 10 s; reading each one before ``start`` costs ``scan`` s of
    the fake wall clock (a long bag seeking far in)."""

    def __init__(self, wall: FakeWall, start: int, scan: float):
        self.wall, self.start, self.scan = wall, start, scan

    def messages(self, topics):
        for k in range(1000):
            t = k * 10_000_000
            if t < self.start:
                self.wall.now += self.scan
            yield Message("/joint_states", t)


class Published:
    def __init__(self, wall: FakeWall):
        self.wall, self.times = wall, []

    def publish(self, data) -> None:
        self.times.append(self.wall.now)


@pytest.mark.parametrize("offset, rate", [(9.0, 1.0), (5.905, 2.0), (0.0, 0.5)])
def test_a_start_offset_is_played_at_the_recorded_pace_from_the_offset(offset, rate):
    wall = FakeWall()
    start = round(offset * NS)
    bag = SlowBag(wall, start, scan=0.01)   # scanning 9 s of bag costs 9 s of wall time
    published = Published(wall)
    played = _play_once(bag, ["/joint_states"], start, rate, {"/joint_states": published},
                        None, wall=lambda: wall.now, sleep=wall.sleep, ok=lambda: True)
    stamps = [m.log_time_ns for m in bag.messages(None) if m.log_time_ns >= start]
    assert played == len(published.times) == len(stamps)
    first = published.times[0]
    for when, stamp in zip(published.times, stamps, strict=True):
        # due (t − t_first) / rate after the first: never early, and late by no more than
        # the sleep granularity of the fake clock (it sleeps exactly what remains)
        due = first + (stamp - stamps[0]) / NS / rate
        assert when == pytest.approx(due, abs=1e-9)
    span = (stamps[-1] - stamps[0]) / NS / rate
    assert published.times[-1] - first == pytest.approx(span, abs=1e-9)


class OdomOnly:
    """A subscriber of /odom alone, of all the bag's topics."""

    def __init__(self, context):
        self.node = rclpy.create_node("odom_only", context=context)
        self.lock = threading.Lock()
        self.received = 0
        self.node.create_subscription(Odometry, "/odom", self._on,
                                      QoSProfile(depth=1000,
                                                 reliability=ReliabilityPolicy.RELIABLE))

    def _on(self, message):
        with self.lock:
            self.received += 1


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    directory = tmp_path_factory.mktemp("replay")
    result = subprocess.run([executable("simulate"), "--duration", "0.5", "--sample-rate", "20",
                             "--method", "rk4", "--dt", "0.001", "--out",
                             str(directory / "run.csv"), "--record", str(directory / "bag")],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    return directory / "bag"


def test_wait_for_subscribers_plays_to_a_subscriber_of_only_some_topics(bag):
    odom = [m for m in open_bag(bag).messages("/odom")]
    assert len(open_bag(bag).topics()) > 2
    with on_domain(DOMAIN_ID), spinning(OdomOnly, DOMAIN_ID) as probe:
        result = subprocess.run([executable("replay"), str(bag), "--wait-for-subscribers"],
                                env=child_env(DOMAIN_ID), capture_output=True, text=True,
                                timeout=120)
        assert result.returncode == 0, result.stderr
        wait_for(lambda: probe.received >= len(odom), "every /odom message", 30.0)
        assert probe.received == len(odom)


@pytest.mark.parametrize("rate", ["5e-324", "0", "-1", "nan", "inf", "1e7"])
def test_a_rate_outside_its_bounds_is_one_line(tmp_path, rate):
    """5e-324 passed as "positive" and played for ever: refused before the bag is read."""
    result = subprocess.run([executable("replay"), str(tmp_path / "no_bag"), "--rate", rate],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip() == f"replay: error: --rate: must be in [1e-06, 1e+06], got " \
                                    f"{float(rate)}", result.stderr
