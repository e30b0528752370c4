"""The node's pacing (pacing.py) on a fake clock: when publications are due, what changing the
real-time factor does, and how falling behind is reported and recovered from."""
import math

from mobile_manip_sim.runtime.pacing import LAG_TOLERANCE, Pacer

MS = 10 ** 6   # ns


class FakeClock:
    def __init__(self):
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_publications_are_due_at_their_simulated_time_over_the_factor():
    clock = FakeClock()
    pacer = Pacer(2.0, 0.01, clock)
    assert pacer.delay(0) == 0.0
    assert math.isclose(pacer.delay(100 * MS), 0.05)   # 0.1 s simulated at 2× real time
    clock.now += 0.03
    assert math.isclose(pacer.delay(100 * MS), 0.02)


def test_free_running_is_never_due_later_than_now():
    pacer = Pacer(0.0, 0.01, FakeClock())
    assert pacer.delay(10 ** 12) == 0.0 and pacer.late(10 ** 12, 100.0) is None


def test_a_new_factor_paces_from_the_current_state_on():
    clock = FakeClock()
    pacer = Pacer(1.0, 0.01, clock)
    clock.now += 0.5
    pacer.set_real_time_factor(4.0, now_ns=500 * MS)
    assert math.isclose(pacer.delay(600 * MS), 0.025)


def test_falling_behind_is_reported_with_the_measured_factor_and_paced_on_from_there():
    clock = FakeClock()
    pacer = Pacer(1.0, 0.01, clock)
    assert pacer.late(10 * MS, LAG_TOLERANCE * 0.9) is None      # within tolerance: silent
    clock.now += 2.0                                               # 1 s simulated in 2 s wall
    measured = pacer.late(1000 * MS, 1.0)
    assert math.isclose(measured, 0.5)
    # No burst to catch up: the next period is due one period after now, not in the past.
    assert math.isclose(pacer.delay(1010 * MS), 0.01)
    pacer.restart_window()
    clock.now += 1.0
    assert math.isclose(pacer.late(1500 * MS, 0.5), 0.5)   # measured since the report


def test_the_tolerance_grows_with_a_long_publication_period():
    clock = FakeClock()
    pacer = Pacer(1.0, 1.0, clock)     # 1 Hz: 5 periods = 5 s of slack
    assert pacer.late(10 ** 9, 4.0) is None and pacer.late(10 ** 9, 6.0) is not None


def test_wait_for_sleeps_until_a_sample_is_due_and_paces_on_from_a_late_one():
    now, slept = [0.0], []
    pacer = Pacer(1.0, 0.01, clock=lambda: now[0])
    pacer.wait_for(0, first=True, sleep=slept.append)          # the run's first: due now
    pacer.wait_for(500_000_000, sleep=slept.append)             # 0.5 s of simulation later
    assert slept == [0.5]
    now[0] = 2.0                                                 # the next one 1.4 s late
    pacer.wait_for(600_000_000, sleep=slept.append)
    assert slept == [0.5] and pacer.anchor == (2.0, 600_000_000)   # no burst to catch up
    pacer.wait_for(700_000_000, sleep=slept.append)
    assert len(slept) == 2 and abs(slept[1] - 0.1) < 1e-12
