"""The node's stepping state machine (node/loop.py) without ROS: fake compute, publish and
restart callables, and a fake clock whose waits advance it, as test_pacing.py does. Driven one
`turn` at a time from the test; the ~/step tests run the loop in its own thread."""
import math
import threading

import pytest

from mobile_manip_sim.engine.simulation import SimulationError
from mobile_manip_sim.node.loop import MAX_WAIT, WATCHDOG_SECONDS, State, SteppingLoop
from mobile_manip_sim.runtime.pacing import Pacer
from mobile_manip_sim.runtime.timeline import Grid
from waiting import wait_for

RATE = 100
PERIOD = 1.0 / RATE
COMPUTE = 0.001   # s of (fake) wall time a segment takes


class FakeClock:
    def __init__(self):
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


class Harness:
    """A loop whose engine is a counter; what it published, when, and what it said."""

    def __init__(self, real_time_factor=1.0, fail=(), threaded=False):
        self.clock = FakeClock()
        self.fail = dict(fail)            # k → exception raised computing segment k → k + 1
        self.published = []               # (k, messages, wall time)
        self.errors, self.warnings, self.waits = [], [], []
        self.during_compute = None        # called inside compute (a service mid-segment)
        self.loop = SteppingLoop(Grid(RATE), Pacer(real_time_factor, PERIOD, self.clock),
                                 restart=lambda: ("state", 0), compute=self.compute,
                                 publish=self.publish, record=lambda: None,
                                 failed=self.errors.append, warn=self.warn,
                                 wait=None if threaded else self.wait)

    def compute(self, k, start_ns):
        assert start_ns == round(k * PERIOD * 1e9)
        self.clock.now += COMPUTE
        if self.during_compute is not None:
            self.during_compute()
        if k in self.fail:
            raise self.fail.pop(k)
        return ("state", k + 1)

    def publish(self, k, messages):
        assert messages == ("state", k)
        self.published.append((k, messages, self.clock.now))

    def warn(self, key, text):
        self.warnings.append(text)
        return True

    def wait(self, timeout):
        self.waits.append(timeout)
        if timeout is not None:
            self.clock.now += timeout

    def ks(self):
        return [k for k, _, _ in self.published]

    def run_until(self, k):
        """Turn until state k goes out (again)."""
        mark = len(self.published)
        for _ in range(10 * k + 20):
            if any(published == k for published in self.ks()[mark:]):
                return
            self.loop.turn()
        pytest.fail(f"state {k} never went out: {self.ks()}")


def test_states_go_out_one_period_apart_on_the_wall_clock_at_the_factor():
    harness = Harness(real_time_factor=2.0)
    assert harness.loop.begin()
    start = harness.clock.now          # pacing starts once the first segment is computed
    harness.run_until(10)
    assert harness.ks() == list(range(11))
    for k, _, wall in harness.published[1:]:   # computing before waiting: no compute jitter
        assert math.isclose(wall, start + k * PERIOD / 2.0, abs_tol=1e-9)
    assert harness.warnings == [] and harness.errors == []


def test_pause_stops_time_and_resume_goes_on_from_the_next_state_without_a_gap():
    harness = Harness()
    harness.loop.begin()
    harness.run_until(5)
    assert harness.loop.pause(True) == (True, "paused at t = 0.050000000 s")
    assert harness.loop.pause(True) == (True, "already paused at t = 0.050000000 s")
    for _ in range(5):
        harness.loop.turn()
    assert harness.ks()[-1] == 5 and harness.waits[-1] is None
    assert harness.loop.state is State.PAUSED
    harness.clock.now += 100.0            # a long pause
    assert harness.loop.pause(False) == (True, "resumed at t = 0.050000000 s")
    resumed = harness.clock.now
    harness.run_until(7)
    assert harness.ks() == list(range(8))
    # paced from the resume on: no burst to catch up the pause
    assert math.isclose(harness.published[-1][2], resumed + 2 * PERIOD, abs_tol=1e-9)


def test_a_failed_segment_says_so_once_pauses_and_a_reset_restarts_publishing():
    harness = Harness(fail={3: SimulationError("t = 0.0312 s: state became non-finite")})
    harness.loop.begin()
    for _ in range(30):
        harness.loop.turn()
    assert harness.ks() == [0, 1, 2, 3] and harness.loop.state is State.FAILED
    assert harness.errors == ["simulation failed in the segment after t = 0.030000000 s: t = "
                              "0.0312 s: state became non-finite; paused, call ~/reset to "
                              "start again"]
    success, message = harness.loop.pause(False)
    assert not success and "call ~/reset" in message
    assert harness.loop.step(1.0)[0] is False
    harness.loop.reset()
    harness.run_until(2)
    assert harness.ks() == [0, 1, 2, 3, 0, 1, 2] and harness.loop.state is State.RUNNING


def test_any_exception_in_a_segment_is_one_line_naming_its_type():
    harness = Harness(fail={1: ValueError("array must not\ncontain infs")})
    harness.loop.begin()
    for _ in range(10):
        harness.loop.turn()
    assert harness.loop.state is State.FAILED
    assert len(harness.errors) == 1 and "\n" not in harness.errors[0]
    assert ": ValueError: array must not contain infs; paused" in harness.errors[0]


def test_a_reset_during_a_segment_drops_it_and_the_next_state_is_t_0():
    harness = Harness()
    harness.loop.begin()
    harness.run_until(4)
    harness.during_compute = harness.loop.reset
    harness.loop.turn()   # the segment 4 → 5, across the reset
    harness.during_compute = None
    harness.run_until(1)
    assert harness.ks() == [0, 1, 2, 3, 4, 0, 1]


def test_a_pause_during_a_segment_keeps_it_for_the_resume():
    harness = Harness()
    harness.loop.begin()
    harness.run_until(4)
    harness.during_compute = lambda: harness.loop.pause(True)
    harness.loop.turn()
    harness.during_compute = None
    for _ in range(5):
        harness.loop.turn()
    assert harness.ks()[-1] == 4
    harness.loop.pause(False)
    harness.run_until(5)
    assert harness.ks() == [0, 1, 2, 3, 4, 5]


def test_a_reset_returns_to_paused_when_paused_also_after_a_failure():
    harness = Harness(fail={2: SimulationError("boom")})
    harness.loop.begin()
    for _ in range(20):
        harness.loop.turn()
    assert harness.loop.state is State.FAILED
    assert harness.loop.pause(True)[0]           # paused while failed: stays paused after reset
    harness.loop.reset()
    for _ in range(5):
        harness.loop.turn()
    assert harness.ks()[-1] == 0 and harness.loop.state is State.PAUSED
    assert harness.loop.pause(False) == (True, "resumed at t = 0.000000000 s")
    harness.run_until(1)


def test_falling_behind_is_said_with_the_measured_factor():
    harness = Harness()
    harness.loop.begin()
    harness.during_compute = lambda: setattr(harness.clock, "now", harness.clock.now + 0.05)
    harness.run_until(20)
    assert harness.warnings and harness.warnings[0].startswith(
        "cannot keep up with real_time_factor 1: ")
    assert "measured real-time factor 0.2" in harness.warnings[0]


@pytest.mark.parametrize("factor", [1e-12, 1e-300])
def test_a_tiny_real_time_factor_waits_in_bounded_pieces(factor):
    harness = Harness(real_time_factor=factor)
    harness.loop.begin()
    for _ in range(5):
        harness.loop.turn()
    assert harness.ks() == [0] and harness.waits and max(harness.waits) <= MAX_WAIT
    harness.loop.set_real_time_factor(1.0)
    harness.run_until(2)


def test_free_running_never_waits():
    harness = Harness(real_time_factor=0.0)
    harness.loop.begin()
    harness.run_until(50)
    assert harness.waits == []


@pytest.fixture
def threaded():
    """A loop running in its own thread, paused before it began."""
    harness = Harness(real_time_factor=0.0, threaded=True)
    harness.loop.pause(True)
    thread = threading.Thread(target=harness.loop.run, daemon=True)
    thread.start()
    yield harness
    harness.loop.stop()
    thread.join(timeout=10)
    assert not thread.is_alive()


def test_each_step_while_paused_publishes_the_next_state_then_answers(threaded):
    loop = threaded.loop
    for k in range(1, 4):
        assert loop.step(10.0) == (True, f"stepped to t = 0.0{k}0000000 s")
    assert threaded.ks() == [0, 1, 2, 3] and loop.state is State.PAUSED


def test_a_step_while_running_is_refused():
    harness = Harness()
    harness.loop.begin()
    assert harness.loop.step(1.0) == (False, "not paused: call ~/pause (true) first, then ~/step")


def test_a_segment_that_fails_because_the_node_is_stopping_is_no_failure():
    """SIGINT shuts rclpy's context down before the node tells its loop to stop: a segment
    publishing then (a FollowJointTrajectory goal's feedback) fails with "publisher's context
    is invalid". That is the stop, not a simulation failure: nothing is said."""
    harness = Harness(fail={3: RuntimeError("publisher's context is invalid")})
    context = {"up": True}
    harness.loop._alive = lambda: context["up"]
    harness.during_compute = lambda: context.update(up=harness.loop.k < 3)
    harness.loop.begin()
    for _ in range(30):
        harness.loop.turn()
    assert harness.errors == [] and harness.loop.state is not State.FAILED


def test_a_failure_outside_a_segment_fails_the_loop_and_the_thread_lives_on():
    harness = Harness(real_time_factor=0.0, threaded=True)
    broken = []

    def publish(k, messages):
        if k == 2 and not broken:
            broken.append(k)
            raise RuntimeError("publisher gone")
        harness.published.append((k, messages, 0.0))

    harness.loop._publish = publish
    harness.loop.pause(True)
    thread = threading.Thread(target=harness.loop.run, daemon=True)
    thread.start()
    try:
        assert harness.loop.step(10.0)[0]
        assert harness.loop.step(10.0)[0] is False     # its publication failed
        assert harness.loop.state is State.FAILED and thread.is_alive()
        assert harness.errors and "RuntimeError: publisher gone" in harness.errors[0]
        harness.loop.reset()
        assert harness.loop.step(10.0) == (True, "stepped to t = 0.010000000 s")
    finally:
        harness.loop.stop()
        thread.join(timeout=10)


def test_a_segment_without_progress_is_reported_once_and_a_reset_abandons_it():
    """A segment stuck in compiled code (dop853 once spun so on a 1e308 command): the watchdog
    says so once after WATCHDOG_SECONDS, and ~/reset replaces the engine and goes on from t = 0
    in a new thread; the stuck thread ends quietly if it ever returns."""
    harness = Harness(real_time_factor=0.0, threaded=True)
    stuck, replaced, reports = threading.Event(), [], []
    first = []

    def compute(k, start_ns):
        if k == 3 and not first:
            first.append(k)
            stuck.wait(60)
        return ("state", k + 1)

    harness.loop._compute = compute
    harness.loop._replace = lambda: replaced.append(True)
    harness.loop._report = reports.append
    thread = threading.Thread(target=harness.loop.run, daemon=True)
    thread.start()
    try:
        wait_for(lambda: harness.loop.computing is not None and first, "the stuck segment", 10)
        harness.clock.now += WATCHDOG_SECONDS / 2
        harness.loop.watch()
        assert reports == []
        harness.clock.now += WATCHDOG_SECONDS / 2 + 1
        harness.loop.watch()
        harness.loop.watch()
        assert len(reports) == 1 and reports[0].startswith(
            "watchdog: the segment after t = 0.030000000 s has made no progress for 11 s")
        harness.loop.reset()
        harness.loop.watch()
        assert replaced == [True] and "abandoned" in reports[-1]
        wait_for(lambda: harness.ks().count(0) == 2 and harness.ks()[-1] >= 5, "the new time line",
                 10)
        stuck.set()
        thread.join(10)
        assert not thread.is_alive()
        ks = harness.ks()
        assert ks[:5] == [0, 1, 2, 3, 0] and ks[4:] == list(range(len(ks) - 4))
    finally:
        stuck.set()
        harness.loop.stop()


def test_a_slow_segment_whose_engine_counts_steps_is_not_stuck():
    """The watchdog reads the engine's own progress (time, accepted steps): a segment that
    takes long but whose step count moves is never reported, nor abandoned by a reset."""
    harness = Harness(real_time_factor=0.0, threaded=True)
    steps, release, replaced, reports = [0], threading.Event(), [], []

    def compute(k, start_ns):
        if k == 2:
            release.wait(60)
        return ("state", k + 1)

    harness.loop._compute = compute
    harness.loop._progress = lambda: (0.02, steps[0])
    harness.loop._replace = lambda: replaced.append(True)
    harness.loop._report = reports.append
    thread = threading.Thread(target=harness.loop.run, daemon=True)
    thread.start()
    try:
        wait_for(lambda: harness.loop.computing is not None and harness.loop.k == 2,
                 "the slow segment", 10)
        for _ in range(5):
            harness.clock.now += WATCHDOG_SECONDS
            steps[0] += 1
            harness.loop.watch()
        harness.loop.reset()
        steps[0] += 1
        harness.clock.now += WATCHDOG_SECONDS
        harness.loop.watch()
        assert reports == [] and replaced == []
        harness.clock.now += WATCHDOG_SECONDS + 1   # now it does not move: stuck
        harness.loop.watch()
        assert replaced == [True] and "abandoned" in reports[-1]
    finally:
        release.set()
        harness.loop.stop()
        thread.join(10)


def test_a_clock_follower_publishes_each_state_once_the_heard_clock_reaches_it():
    """publish_clock false: state k goes out once the /clock heard has reached t_k, never
    before, whatever the wall clock says; a ~/step does not get ahead of it either."""
    from mobile_manip_sim.node.lockstep import ClockFollower
    harness = Harness()
    follower = ClockFollower(1.0, PERIOD, harness.clock)
    harness.loop.pacer = follower
    assert harness.loop.begin() and harness.ks() == [0]
    for _ in range(50):   # nothing heard: the wall clock runs, nothing more goes out
        harness.loop.turn()
    assert harness.ks() == [0]
    follower.heard(round(3 * PERIOD * 1e9))
    for _ in range(50):
        harness.loop.turn()
    assert harness.ks() == [0, 1, 2, 3]
    harness.loop.pause(True)
    with harness.loop.cv:   # what ~/step asks for (the service itself waits in its thread)
        harness.loop.state, harness.loop.steps = State.STEPPING, 1
    for _ in range(20):
        harness.loop.turn()
    assert harness.ks() == [0, 1, 2, 3]
    follower.heard(round(4 * PERIOD * 1e9))
    harness.run_until(4)
    assert harness.loop.state is State.PAUSED and harness.ks() == [0, 1, 2, 3, 4]
    assert not harness.warnings   # waiting for the clock is not "cannot keep up"
