"""The run's time line (timeline.py): grid points and stamps, segments, and the rules for when a
command takes effect — node (`CommandSlot`) and recorded (`CommandHistory`) alike."""
from fractions import Fraction

import numpy as np
import pytest

from mobile_manip_sim.runtime.timeline import (
    NS,
    CommandHistory,
    CommandSlot,
    Grid,
    format_ns,
    sample_times,
    stamp_ns,
)


def test_stamps_are_exact_and_never_drift():
    grid = Grid(3.0)   # 1/3 s: not an integer number of ns
    assert [grid.stamp(k) for k in range(4)] == [0, 333333333, 666666667, 10 ** 9]
    assert grid.stamp(3 * 10 ** 6) == 10 ** 15   # a million seconds on: still exact
    assert grid.time(7) == 7 / 3.0 and stamp_ns(7, Fraction(3)) == grid.stamp(7)


def test_a_headless_grid_ends_at_its_duration_off_the_grid():
    grid = Grid(100.0, 0.035)
    assert list(grid.times()) == [0.0, 0.01, 0.02, 0.03, 0.035]
    assert list(sample_times(0.035, 100.0)) == list(grid.times())
    assert grid.count == 5 and grid.stamp(4) == 35_000_000
    assert list(Grid(100.0, 0.03).times()) == [0.0, 0.01, 0.02, 0.03]   # on the grid: no extra


def test_index_finds_points_and_only_points():
    grid = Grid(100.0, 0.035)
    assert [grid.index(grid.stamp(k)) for k in range(5)] == list(range(5))
    assert grid.index(5_000_000) is None and grid.index(40_000_000) is None
    assert Grid(100.0).index(10 ** 9) == 100
    off = Grid(20.0, 2.005)   # the last point is nearer to k = 40 than to 41
    assert off.index(2_005_000_000) == 41 and off.index(2_000_000_000) == 40


def test_segments_advance_to_the_next_point():
    grid = Grid(100.0, 0.035)
    assert list(grid.segments(10_000_000, 35_000_000)) == [(10_000_000, 0.02),
                                                           (20_000_000, 0.03),
                                                           (30_000_000, 0.035)]
    with pytest.raises(ValueError, match="not a point of the 100 Hz grid of a 0.035 s run"):
        list(grid.segments(0, 15_000_000))


def test_a_sample_grid_of_a_billion_points_costs_nothing_up_front():
    grid = Grid(1e6, 1e3)
    assert grid.count == 10 ** 9 + 1 and grid.stamp(grid.count - 1) == 1000 * NS


def test_a_command_times_out_once_per_silence_and_a_new_one_rearms_it():
    slot = CommandSlot(2)
    slot.receive([1.0, 2.0], now_ns=100)
    assert slot.held(100 + 199, timeout_ns=200)[1] is False
    values, timed_out = slot.held(100 + 200, timeout_ns=200)
    assert timed_out and values.tolist() == [0.0, 0.0]
    assert slot.held(10 ** 9, timeout_ns=200) == (pytest.approx(np.zeros(2)), False)  # once
    slot.receive([3.0, 4.0], now_ns=10 ** 9)
    assert slot.held(10 ** 9, timeout_ns=200)[0].tolist() == [3.0, 4.0]
    assert slot.held(10 ** 12, timeout_ns=0)[0].tolist() == [3.0, 4.0]   # 0: never times out


def test_a_recorded_command_holds_from_its_stamp_until_the_next():
    history = CommandHistory([(0, [1.0]), (30, [2.0]), (50, [0.0])])
    assert [history.at(t)[0] for t in (0, 29, 30, 49, 50, 10 ** 9)] == [1, 1, 2, 2, 0, 0]
    assert CommandHistory([(10, [1.0])]).at(9) is None and not CommandHistory()
    with pytest.raises(ValueError, match="recorded after one at 50 ns"):
        history.add(20, [5.0])


def test_format_ns_is_exact():
    assert format_ns(1_000_000_001) == "1.000000001" and format_ns(-5) == "-0.000000005"
