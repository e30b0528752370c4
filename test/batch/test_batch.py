"""The batch engine (`mobile_manip_sim.batch`): every lane is bit for bit its own `simulate` run,
whatever the other lanes do — impacts, rests, releases and holds in some lanes and not in others,
failures — and a lane that fails stops alone."""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from mobile_manip_sim.batch import Batch, lane_logs
from mobile_manip_sim.batch import runs as runs_module
from mobile_manip_sim.batch.lane_logs import LOG_ROWS
from mobile_manip_sim.runtime import headless
from mobile_manip_sim.runtime.timeline import sample_times
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.overrides import scene_with
from robots import random_robot_document

FIXED = ("rk4", "semi_implicit_euler", "euler")
DURATION, RATE = 0.4, 50.0


def random_lanes(seed: int, count: int, n_links: int):
    """A random robot with stops and `count` lanes of it: method, dt, a rod's mass, the initial
    rates (some fast enough to reach the stops, some not), efforts and the stops' law varied."""
    rng = np.random.default_rng(seed)
    document = random_robot_document(rng, n_links)
    document["effects"]["stroke_limits"] = {"restitution": 0.0, "rest_speed": 0.05}
    document["duration"] = DURATION
    lanes = []
    for i in range(count):
        slow = i % 2 == 0   # slow lanes without gravity stay off their stops; the others not
        speed = 0.01 if slow else 3.0
        lanes.append({
            "effects.gravity": 0.0 if slow else 10.0,
            "integrator.method": FIXED[i % 3],
            "integrator.dt": float(rng.choice([1e-3, 2e-3, 5e-3])),
            "robot.arm.links[0].mass_per_length": float(rng.uniform(0.5, 3.0)),
            "initial.velocity": (rng.normal(size=2) * speed).tolist()
                                + (rng.normal(size=2 * n_links) * speed).tolist(),
            "efforts.wheels": rng.uniform(-0.2, 0.2, 2).tolist(),
            "effects.stroke_limits.restitution": float(rng.choice([0.0, 0.5, 0.9])),
        })
    return document, lanes


def simulate(document: dict, overrides: dict):
    """The lane's own run, as `simulate` runs it: its samples (s, T + V) and the simulation."""
    rows = []
    sim = headless.run(scene_with(document, overrides), DURATION, RATE, None,
                       lambda sim: rows.append([*sim.s, sim.total_energy()]))
    return np.array(rows), sim


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and np.array_equal(a.view(np.int64), b.view(np.int64))


def assert_lane_is_its_run(batch, rows, i, document, overrides):
    """Lane i of `batch` (its sample rows `rows[i]`) is its own run alone, bit for bit:
    samples, impacts and holds, counters, steps, energy error; that run's Simulation."""
    expected, sim = simulate(document, overrides)
    lane, status = batch.lane(i), batch.status[i]
    assert status.ok and status.compiled, status.error
    assert same_bits(rows[i], expected), f"lane {i}: {overrides}"
    assert lane.impacts == sim.impacts
    assert [d.held for d in lane.impact_details] == [d.held for d in sim.impact_details]
    assert np.array_equal(lane.system.counters, sim.system.counters), i
    assert (lane.steps, lane.rhs_evaluations) == (sim.steps, sim.rhs_evaluations)
    assert same_bits(np.array([status.energy_error]), np.array([sim.energy_error()]))
    return sim


@pytest.mark.parametrize("seed, n_links, log_rows", [(11, 2, LOG_ROWS), (12, 3, LOG_ROWS),
                                                     (13, 2, 1)])
def test_every_lane_is_bit_for_bit_its_own_simulate_run(seed, n_links, log_rows, monkeypatch):
    # log_rows 1: a lane's own impact log holds one call's impacts at most, so lanes with more
    # pause, Python reads their logs, and they go on in the next call
    monkeypatch.setattr(lane_logs, "LOG_ROWS", log_rows)
    document, lanes = random_lanes(seed, 12, n_links)
    batch = Batch(document, lanes, threads=2)
    times = np.array(list(sample_times(DURATION, RATE)))
    rows = batch.sample(times)
    impacts, resting = [], []
    for i, overrides in enumerate(lanes):
        sim = assert_lane_is_its_run(batch, rows, i, document, overrides)
        assert batch.lane(i).t == sim.t == DURATION
        impacts.append(len(sim.impacts))
        resting.append(any(impact.resting for impact in sim.impacts))
    # the lanes differ in what happens to them: impacts in some, none in others; rests too
    assert 0 in impacts and max(impacts) > 0, impacts
    assert any(resting) and not all(resting), resting


def test_a_lane_given_a_non_finite_command_fails_alone_and_the_others_are_untouched():
    document, lanes = random_lanes(21, 4, 2)
    batch = Batch(document, lanes, threads=2)
    batch.advance_to(0.1)
    batch.set_efforts(wheels=[math.nan, 0.0], lanes=[1])
    batch.set_efforts(joints=[[0.0, 1.0, 0.0, math.inf]], lanes=[2])
    batch.advance_to(DURATION)
    status = batch.status
    assert [s.ok for s in status] == [True, False, False, True]
    assert status[1].error.startswith("efforts.wheels: values must be finite")
    assert status[2].error.startswith("efforts.joints: values must be finite")
    assert "\n" not in status[1].error + status[2].error
    assert status[1].t == status[2].t == 0.1   # stepped no more
    for i in (0, 3):   # the others: exactly their runs alone
        expected, sim = simulate(document, lanes[i])
        assert same_bits(batch.lane(i).s, sim.s)
        assert batch.lane(i).impacts == sim.impacts


def test_a_lane_whose_state_goes_non_finite_fails_alone_with_the_runs_own_error():
    document, lanes = random_lanes(31, 3, 2)
    # euler with a step far beyond what stiff joint damping allows: it diverges
    lanes[1].update({"integrator.method": "euler", "integrator.dt": 0.01,
                     "effects.joint_damping": [1e6] * 4})
    batch = Batch(document, lanes, threads=2)
    rows = batch.sample(np.array(list(sample_times(DURATION, RATE))))
    status = batch.status
    assert status[1].ok is False and status[1].error.startswith("SimulationError: t = ")
    assert np.isnan(rows[1, -1]).all()
    for i in (0, 2):
        assert status[i].ok
        expected, _ = simulate(document, lanes[i])
        assert same_bits(rows[i], expected)


def test_a_bad_override_fails_its_lane_at_once_naming_the_key():
    document, lanes = random_lanes(41, 3, 2)
    lanes[0] = {**lanes[0], "integrator.dt": -1.0}
    batch = Batch(document, lanes)
    batch.advance_to(0.05)
    status = batch.status
    assert not status[0].ok and status[0].error.startswith("integrator.dt")
    assert status[1].ok and status[2].ok and status[1].t == 0.05


def test_adaptive_lanes_are_stepped_by_their_own_simulation_with_the_same_numbers():
    document, lanes = random_lanes(51, 3, 2)
    lanes[1] = {**lanes[1], "integrator.method": "dop853"}
    batch = Batch(document, lanes, threads=2)
    rows = batch.sample(np.array(list(sample_times(DURATION, RATE))))
    assert [s.compiled for s in batch.status] == [True, False, True]
    for i, overrides in enumerate(lanes):
        expected, sim = simulate(document, overrides)
        assert same_bits(rows[i], expected)
        assert batch.lane(i).impacts == sim.impacts


def test_one_thread_and_two_give_the_same_bits():
    document, lanes = random_lanes(61, 6, 2)
    times = np.array(list(sample_times(DURATION, RATE)))
    one = Batch(copy.deepcopy(document), lanes, threads=1).sample(times)
    two = Batch(copy.deepcopy(document), lanes, threads=2).sample(times)
    assert same_bits(one, two)


def test_a_lane_whose_own_impact_log_fills_pauses_and_goes_on_with_the_same_bits(monkeypatch):
    document, lanes = random_lanes(11, 12, 2)
    times = np.array(list(sample_times(DURATION, RATE)))
    calls = []

    class CountedLanes(runs_module.LaneSet):   # the C++ core's lanes (`core.LaneSet`)
        def advance(self, *args):
            calls.append(args[0].size)
            return super().advance(*args)
    monkeypatch.setattr(runs_module, "LaneSet", CountedLanes)
    results = {}
    for rows in (LOG_ROWS, 1):
        monkeypatch.setattr(lane_logs, "LOG_ROWS", rows)
        calls.clear()
        batch = Batch(copy.deepcopy(document), lanes, threads=2)
        results[rows] = (batch.sample(times), len(calls),
                         [batch.lane(i).impacts for i in range(len(lanes))])
    assert same_bits(results[1][0], results[LOG_ROWS][0])
    assert results[1][2] == results[LOG_ROWS][2] and any(results[1][2])
    assert results[1][1] > results[LOG_ROWS][1]   # lanes paused with a one-row log


def test_of_scenes_takes_parsed_scenes_and_an_exception_fails_its_lane_alone():
    document, lanes = random_lanes(71, 2, 2)
    scenes = [scene_with(document, lanes[0]), UserError("robot.base.mass", "must be positive")]
    batch = Batch.of_scenes(scenes, threads=1)
    batch.advance_to(0.05)
    assert isinstance(scenes[1], UserError)   # the caller's list is left as it was
    status = batch.status
    assert status[0].ok and status[0].t == 0.05
    assert not status[1].ok and status[1].error == str(scenes[1])


def test_a_dropped_batchs_lanes_are_freed_without_the_cycle_collector():
    """The sweep holds Python's cycle collector off (`memory.collector_paused`): that is sound
    only while nothing of a lane — its simulation, records, scene — sits in a reference cycle,
    so that dropping a stepped batch frees every lane at once."""
    import gc
    import weakref
    document, lanes = random_lanes(5, 6, 2)
    gc.collect()
    gc.disable()
    try:
        batch = Batch(document, lanes)
        batch.prepare()
        batch.sample(np.array(list(sample_times(DURATION, RATE))))
        sims = [sim for sim in batch.sims if sim is not None]
        assert sims, "no lane was built"
        kept = [weakref.ref(item) for sim in sims
                for item in (sim, sim.system, sim.dynamics, sim.scene)]
        del batch, sims
        assert [ref() for ref in kept if ref() is not None] == []
    finally:
        gc.enable()


@pytest.mark.parametrize("first, block, samples, end", [
    (0, 128, 151, 151),    # 23 left after a block: taken in the same call
    (0, 128, 300, 128),    # 172 left: another call
    (0, 128, 192, 128),    # exactly half a block left: another call
    (0, 128, 191, 191),
    (0, 1, 1, 1), (0, 1, 2, 1), (5, 4, 10, 10), (100, 64, 151, 151)])
def test_a_call_takes_the_rest_of_the_samples_rather_than_leave_a_short_call(first, block,
                                                                               samples, end):
    from mobile_manip_sim.batch.runs import _call_end
    assert _call_end(first, block, samples) == end
    assert end - first <= block + block // 2   # a call stays within 1.5 blocks


def lanes_under_a_budget(document, lanes, budget, vector):
    """Samples and per-lane counters of a batch whose lanes restart their `advance` call every
    `budget` grid steps."""
    batch = Batch(copy.deepcopy(document), lanes, threads=2, vector=vector)
    for i in range(len(lanes)):
        if budget:
            batch.lane(i)._step_budget = budget
    rows = batch.sample(np.array(list(sample_times(DURATION, RATE))))
    return rows, [(batch.lane(i).steps, batch.lane(i).rhs_evaluations)
                  for i in range(len(lanes))], batch.lane_steps


def test_lanes_in_blocks_keep_to_their_step_budget():
    """A step budget of 3 grid steps per `advance` call (a sample needs 4 to 20 here). A lane
    that reaches it starts a new call, which computes f(s) afresh where a resting rod's step
    would have carried it over: its right-hand-side count shows where it restarted. Lanes in
    vector blocks, which take several steps in one go (core/include/mms/lanes.hpp), must restart
    exactly where the lanes stepped one by one do."""
    document, lanes = random_lanes(11, 12, 2)
    vector_rows, vector_counts, paths = lanes_under_a_budget(document, lanes, 3, True)
    alone_rows, alone_counts, _ = lanes_under_a_budget(document, lanes, 3, False)
    assert paths[0] > 0   # steps taken in vector blocks
    assert same_bits(vector_rows, alone_rows)
    assert vector_counts == alone_counts
    _, unbounded, _ = lanes_under_a_budget(document, lanes, None, False)
    assert unbounded != alone_counts   # the budget shows in the counts: the test can see it
