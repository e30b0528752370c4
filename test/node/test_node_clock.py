"""Two robots, one time line: a simulator with publish_clock false follows the /clock it hears
(another simulator's), so its messages are never stamped ahead of that clock. Two `simulator`
processes on real DDS and a use_sim_time client node in this process, as RViz or tf would run.
The clock's owner runs at half real time and the follower would run at full speed on its own:
without following, its stamps run ahead within a second."""
import re
import threading

import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool

from ros_harness import NodeProcess, child_env, on_domain, private_domain, spinning, wait_for

DOMAIN_ID = private_domain(1, 232)
TIMEOUT = 60.0
PERIOD_NS = 10_000_000   # 100 Hz, both nodes
RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
FAST = ["-p", "integrator.method:=rk4", "-p", "integrator.dt:=0.001"]


def ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class SimTimeClient:
    """use_sim_time: its clock is /clock. Records, at each robot2 joint state's arrival, its
    stamp and the client's sim time then."""

    def __init__(self, context):
        self.node = rclpy.create_node("sim_time_client", context=context,
                                      parameter_overrides=[rclpy.parameter.Parameter(
                                          "use_sim_time", value=True)])
        self.lock = threading.Lock()
        self.clock: list[int] = []
        self.robot2: list[tuple[int, int]] = []   # (stamp, client's sim time at arrival)
        self.node.create_subscription(Clock, "/clock", self._on_clock, RELIABLE)
        self.node.create_subscription(JointState, "/robot2/joint_states", self._on_state,
                                      RELIABLE)
        self.pause_robot1 = self.node.create_client(SetBool, "/robot1/mobile_manip_sim/pause")

    def _on_clock(self, message):
        with self.lock:
            self.clock.append(ns(message.clock))

    def _on_state(self, message):
        with self.lock:
            self.robot2.append((ns(message.header.stamp),
                                self.node.get_clock().now().nanoseconds))

    def snapshot(self):
        with self.lock:
            return list(self.clock), list(self.robot2)


def test_a_follower_is_never_stamped_ahead_of_the_clock_it_hears(tmp_path):
    with on_domain(DOMAIN_ID):
        owner = NodeProcess(tmp_path, *FAST, "-r", "__ns:=/robot1", "-p", "frame_prefix:=robot1/",
                            "-p", "real_time_factor:=0.5", env=child_env(DOMAIN_ID))
        follower = NodeProcess(tmp_path, *FAST, "-r", "__ns:=/robot2",
                               "-p", "frame_prefix:=robot2/", "-p", "publish_clock:=false",
                               "-p", "real_time_factor:=1.0", env=child_env(DOMAIN_ID))
        try:
            with spinning(SimTimeClient, DOMAIN_ID) as client:
                def running():
                    assert owner.running(), owner.output()
                    assert follower.running(), follower.output()
                    clock, robot2 = client.snapshot()
                    heard = sum(1 for _, now in robot2 if now > 0)
                    return clock and clock[-1] >= 2_000_000_000 and heard >= 100
                wait_for(running, "2 s on /clock and 100 joint states of robot2 heard with it",
                         TIMEOUT)
                clock, robot2 = client.snapshot()
                # while running: never more than one period ahead of what this client's clock
                # said at arrival (the owner's /clock and robot2's state travel apart). Arrivals
                # before this client's own clock heard its first /clock (now = 0: discovery
                # matched robot2 first) say nothing of the follower and are left out.
                heard = [(stamp, now) for stamp, now in robot2 if now > 0]
                ahead = [(stamp, now) for stamp, now in heard if stamp > now + PERIOD_NS]
                assert not ahead, ahead[:5]
                # the owner pauses: its clock stops; the follower catches up to it, not beyond
                assert client.pause_robot1.wait_for_service(timeout_sec=TIMEOUT)
                future = client.pause_robot1.call_async(SetBool.Request(data=True))
                wait_for(future.done, "robot1 paused", TIMEOUT)
                response = future.result()
                assert response.success, response.message
                # "paused at t = 2.34 s": the stamp of its last state, the last /clock
                final = round(float(response.message.split("t = ")[1].split()[0]) * 1e9)
                wait_for(lambda: client.snapshot()[0][-1] == final, "the owner's last /clock",
                         TIMEOUT)

                def caught_up():
                    stamps = [stamp for stamp, _ in client.snapshot()[1]]
                    return stamps[-1] >= final - PERIOD_NS
                wait_for(caught_up, "robot2 at the owner's clock", TIMEOUT)
                clock, robot2 = client.snapshot()
                assert clock[-1] == final
                assert max(stamp for stamp, _ in robot2) <= final
                stamps = [stamp for stamp, _ in robot2]
                assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)
            # the start-up line says the mode: how it is driven, how it is paced
            assert re.search(r"mode: base effort, arm_controller \w+; "
                             r"following the /clock it hears", follower.output()), \
                follower.output()
            assert re.search(r"mode: base effort, arm_controller \w+; paced by the wall clock",
                             owner.output()), owner.output()
        finally:
            assert owner.stop() == 0, owner.output()
            assert follower.stop() == 0, follower.output()


def test_the_follower_releases_a_state_only_once_its_stamp_is_heard():
    from mobile_manip_sim.node.lockstep import ClockFollower
    woken = []
    follower = ClockFollower(1.0, 0.01, clock=lambda: 0.0)
    follower.notify = lambda: woken.append(True)
    assert follower.delay(0) > 0 and follower.delay(PERIOD_NS) > 0   # nothing heard yet
    follower.heard(3 * PERIOD_NS)
    assert woken == [True]
    assert follower.delay(3 * PERIOD_NS) <= 0 < follower.delay(3 * PERIOD_NS + 1)
    assert follower.late(3 * PERIOD_NS, 10.0) is None       # waiting is never "behind"
    follower.heard(PERIOD_NS)                                 # the owner was reset
    assert follower.delay(2 * PERIOD_NS) > 0


def test_the_follower_refuses_a_nanosec_past_a_second_and_says_a_leap():
    """nanosec ≥ 10⁹ is no time: refused, said; a leap of 10⁶ s ahead is followed, said."""
    from mobile_manip_sim.node.lockstep import ClockFollower
    follower = ClockFollower(1.0, 0.01, clock=lambda: 0.0)
    said = []
    follower.warn = lambda key, text: said.append(text)
    follower.heard_message(1, 1_000_000_000)
    assert follower.heard_ns is None
    assert said == ["/clock: nanosec 1000000000 is not in [0, 1e9): not a time, ignored"]
    follower.heard_message(2, 0)
    follower.heard_message(1_000_002, 5)
    assert follower.heard_ns == 1_000_002_000_000_005 and len(said) == 2
    assert said[1].startswith("/clock leapt 1e+06 s ahead, from t = 2.000000000 s"), said[1]


class TwoClocks:
    """Two nodes publishing /clock, each its own time."""

    def __init__(self, context):
        self.node = rclpy.create_node("first_clock", context=context)
        self.other = rclpy.create_node("second_clock", context=context)
        self.publishers = [node.create_publisher(Clock, "/clock", RELIABLE)
                           for node in (self.node, self.other)]


def test_a_follower_says_when_two_nodes_publish_the_clock(tmp_path):
    with on_domain(DOMAIN_ID):
        follower = NodeProcess(tmp_path, *FAST, "-p", "publish_clock:=false",
                               env=child_env(DOMAIN_ID))
        try:
            with spinning(TwoClocks, DOMAIN_ID):
                wait_for(lambda: not follower.running() or "2 nodes publish /clock" in
                         follower.output(), "the follower's warning of two clocks", TIMEOUT)
            assert follower.running(), follower.output()
        finally:
            assert follower.stop() == 0, follower.output()
    assert "follows whichever it heard last" in follower.output()
