"""Lanes stepped four at a time (`batch/blocks.py`): the plain steps of up to four lanes computed
together in vector lanes, every other step alone — and every lane still bit for bit its own run
(samples, impacts, holds, counters), whatever its block's other lanes do."""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from mobile_manip_sim.batch import Batch
from mobile_manip_sim.bench.scenes import paper_document
from mobile_manip_sim.dynamics.jit import ENABLED
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.engine.system import REDUCED_SOLVE, RHS_EVALS
from mobile_manip_sim.runtime.timeline import sample_times
from mobile_manip_sim.scene.overrides import scene_with
from test_batch import DURATION, RATE, assert_lane_is_its_run, random_lanes, same_bits, simulate

pytestmark = pytest.mark.skipif(not ENABLED, reason="vector lanes need numba")

TIMES = np.array(list(sample_times(DURATION, RATE)))




@pytest.mark.parametrize("method", ["rk4", "semi_implicit_euler", "euler"])
@pytest.mark.parametrize("seed, n_links, count", [(81, 2, 7), (83, 3, 10)])
def test_random_robots_every_lane_is_its_own_run_in_blocks(method, seed, n_links, count):
    document, lanes = random_lanes(seed, count, n_links)
    for overrides in lanes:   # one method: the lanes share blocks (7, 10: not multiples of 4)
        overrides["integrator.method"] = method
    batch = Batch(document, lanes, threads=2)
    rows = batch.sample(TIMES)
    impacts, resting = [], []
    for i, overrides in enumerate(lanes):
        sim = assert_lane_is_its_run(batch, rows, i, document, overrides)
        impacts.append(len(sim.impacts))
        resting.append(any(impact.resting for impact in sim.impacts))
    assert 0 in impacts and max(impacts) > 0, impacts
    assert any(resting) and not all(resting), resting
    vector, scalar = batch.lane_steps
    assert vector > 0 and scalar > 0, (vector, scalar)   # both paths ran
    assert vector + scalar >= sum(batch.lane(i).steps for i in range(count)) - count * 4


def paper_lanes(count: int, method: str, seed: int = 5):
    rng = np.random.default_rng(seed)
    return [{"integrator.method": method, "integrator.dt": 0.002, "duration": DURATION,
             "robot.arm.links[0].mass_per_length": float(rng.uniform(0.8, 1.2)),
             "efforts.joints[0]": float(rng.uniform(4.0, 5.0)),
             "efforts.joints[1]": float(rng.choice([0.0, 7.0]))}
            for _ in range(count)]


@pytest.mark.parametrize("method", ["rk4", "semi_implicit_euler", "euler"])
def test_paper_scene_lanes_in_blocks_are_their_own_runs(method):
    document = paper_document()
    lanes = paper_lanes(6, method)
    batch = Batch(copy.deepcopy(document), lanes, threads=2)
    rows = batch.sample(TIMES)
    alone = Batch(copy.deepcopy(document), lanes, threads=2, vector=False)
    assert same_bits(rows, alone.sample(TIMES))
    assert alone.lane_steps[0] == 0   # each lane alone, outside the blocks
    for i, overrides in enumerate(lanes):
        assert_lane_is_its_run(batch, rows, i, document, overrides)
    assert batch.lane_steps[0] > batch.lane_steps[1]   # most steps in vector lanes


def test_lanes_resting_at_their_stops_step_in_vector_lanes_with_the_same_bits():
    document = paper_document()
    lanes = paper_lanes(8, "rk4", seed=9)
    for overrides in lanes:
        overrides["duration"] = 1.5
        overrides["efforts.joints[1]"] = 7.0
    times = np.array(list(sample_times(1.5, RATE)))
    batch = Batch(copy.deepcopy(document), lanes, threads=2)
    alone = Batch(copy.deepcopy(document), lanes, threads=2, vector=False)
    assert same_bits(batch.sample(times), alone.sample(times))
    resting = []
    for i in range(len(lanes)):
        lane = batch.lane(i)
        assert np.array_equal(lane.system.counters, alone.lane(i).system.counters)
        assert lane.impacts == alone.lane(i).impacts
        # most of its evaluations with a rod locked at its stop: resting, its holding watched
        if lane.system.counters[REDUCED_SOLVE] > lane.system.counters[RHS_EVALS] // 3:
            resting.append(i)
            vector, scalar = batch.paths[i]
            assert vector > 0.7 * (vector + scalar), (i, vector, scalar)   # alone: < 0.67
    assert resting


def test_a_lane_given_a_non_finite_command_fails_alone_in_its_block():
    document = paper_document()
    lanes = paper_lanes(5, "rk4")
    batch = Batch(copy.deepcopy(document), lanes, threads=2)
    batch.advance_to(0.1)
    batch.set_efforts(joints=[0.0, math.inf, 0.0, 0.0], lanes=[2])
    batch.advance_to(DURATION)
    status = batch.status
    assert [s.ok for s in status] == [True, True, False, True, True]
    assert status[2].error.startswith("efforts.joints: values must be finite")
    assert status[2].t == 0.1
    for i in (0, 1, 3, 4):   # the others: their runs alone, advanced by the same calls
        sim = Simulation(scene_with(document, lanes[i]))
        sim.advance_to(0.1)
        sim.advance_to(DURATION)
        assert same_bits(batch.lane(i).s, sim.s)
        assert batch.lane(i).impacts == sim.impacts
        assert np.array_equal(batch.lane(i).system.counters, sim.system.counters)


def test_a_lane_whose_state_goes_non_finite_in_a_block_fails_with_its_runs_error():
    document, lanes = random_lanes(31, 5, 2)
    for overrides in lanes:
        overrides.update({"integrator.method": "euler", "integrator.dt": 0.002})
    lanes[1].update({"integrator.dt": 0.01, "effects.joint_damping": [1e6] * 4})
    batch = Batch(document, lanes, threads=1)
    rows = batch.sample(TIMES)
    status = batch.status
    assert status[1].ok is False and status[1].error.startswith("SimulationError: t = ")
    for i in (0, 2, 3, 4):
        assert status[i].ok
        expected, _ = simulate(document, lanes[i])
        assert same_bits(rows[i], expected)
