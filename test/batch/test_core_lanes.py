"""The batch's lanes on the C++ core (`core.LaneSet`, core/include/mms/lanes.hpp) against each
lane's own run alone, with and without the vector blocks: bit for bit, for every fixed-step method,
with impacts, rests, Zeno holds and releases in some lanes and not in others, the plain grid steps
in vector blocks. Compared: every sample (s, T + V) and the lane's own clock there, the clock, the
stage counters, every impact with its details, which rods rest."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from engine_cases import one_link_doc
from mobile_manip_sim.batch import Batch
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.engine.stepping import CLOCK_HOLDS
from mobile_manip_sim.runtime.timeline import sample_times
from mobile_manip_sim.scene.overrides import scene_with
from test_batch import DURATION, RATE, random_lanes, same_bits

FIXED = ("rk4", "semi_implicit_euler", "euler")


def outcome(sim, rows, t) -> dict:
    return dict(rows=rows, t=t, clock=sim._clock.copy(), counters=sim.system.counters.copy(),
                impacts=list(sim.impacts), details=list(sim.impact_details),
                resting=sim.resting.copy(), s=sim.s.copy())


def assert_identical(a: dict, b: dict, lane: int) -> None:
    assert same_bits(a["rows"], b["rows"]), f"lane {lane}: samples"
    assert same_bits(a["t"], b["t"]), f"lane {lane}: the lane's clock at its samples"
    for key in ("clock", "counters", "resting", "s"):
        assert np.array_equal(a[key], b[key], equal_nan=True), (lane, key)
    assert a["impacts"] == b["impacts"], lane
    assert len(a["details"]) == len(b["details"]), lane
    for x, y in zip(a["details"], b["details"], strict=True):
        for field in x._fields:
            assert np.array_equal(getattr(x, field), getattr(y, field)), (lane, field)


def batch_outcomes(document, lanes, parts, vector=True) -> list[dict]:
    """Each lane's outcome of a batch run through `parts`: (sample times, then a command to the
    batch or None); the grid steps (in vector blocks, alone)."""
    batch = Batch(copy.deepcopy(document), lanes, threads=2, vector=vector)
    rows, t = [], []
    for times, command in parts:
        rows.append(batch.sample(times))
        t.append(batch.sample_t.copy())
        if command is not None:
            command(batch)
    outcomes = [outcome(batch.lane(i), np.concatenate([r[i] for r in rows]),
                        np.concatenate([x[i] for x in t])) for i in range(len(lanes))]
    assert all(status.ok and status.compiled for status in batch.status)
    return outcomes, batch.lane_steps


def alone(document, overrides, parts, lane: int) -> dict:
    """The lane's own run: a Simulation of its scene advanced to each sample as `simulate` does,
    given the batch's commands for this lane."""
    sim = Simulation(scene_with(document, overrides))
    rows, t = [], []
    for times, command in parts:
        for at in times:
            sim.advance_to(at)
            rows.append([*sim.s, sim.total_energy()])
            t.append(sim.t)
        if command is not None:
            command(Lone(sim, lane))
    return outcome(sim, np.array(rows), np.array(t))


class Lone:
    """A run alone, commanded as a batch commands its lane `lane`."""

    def __init__(self, sim, lane: int):
        self.sim, self.own = sim, lane

    def set_efforts(self, wheels=None, joints=None, lanes=None):
        if lanes is None or self.own in lanes:
            self.sim.set_efforts(wheels, joints)


def assert_three_agree(document, lanes, parts) -> list[dict]:
    """Lanes in vector blocks = lanes stepped one by one = each lane alone, bit for bit; the lanes
    took plain steps in vector blocks and steps alone. Returns the outcomes."""
    blocks, (vector, scalar) = batch_outcomes(document, lanes, parts)
    one_by_one, _ = batch_outcomes(document, lanes, parts, vector=False)
    assert vector > 0 and scalar > 0, (vector, scalar)
    for i, overrides in enumerate(lanes):
        own = alone(document, overrides, parts, i)
        assert_identical(blocks[i], own, i)
        assert_identical(one_by_one[i], own, i)
    return blocks


@pytest.mark.parametrize("method", FIXED)
@pytest.mark.parametrize("seed, n_links", [(40, 2), (42, 3)])
def test_random_robots_lanes_in_blocks_equal_their_runs(method, seed, n_links):
    document, lanes = random_lanes(seed, 11, n_links)   # 11: one full block of 8 and a short one
    for overrides in lanes:
        overrides["integrator.method"] = method
        overrides["integrator.dt"] = 0.002   # one step: the lanes share vector blocks
    times = np.array(list(sample_times(DURATION, RATE)))
    cpp = assert_three_agree(document, lanes, [(times, None)])
    impacts = [len(lane["impacts"]) for lane in cpp]
    resting = [any(impact.resting for impact in lane["impacts"]) for lane in cpp]
    assert 0 in impacts and max(impacts) > 0, impacts
    assert any(resting) and not all(resting), resting


@pytest.mark.parametrize("method", FIXED)
def test_held_and_released_rods_in_some_lanes_equal_their_runs(method):
    """One rod straight up falling onto its lower stop (rest_speed 0): its bounces accumulate
    and the Zeno guard holds it at rest; then a push along the rod releases it. Lanes differ in
    restitution, gravity (none: the rod floats, never reaching its stop) and push."""
    document = one_link_doc(joints=(1.5707963267948966, 0.5), stroke=(0.0, 1.0),
                            effects={"gravity": 10.0,
                                     "stroke_limits": {"restitution": 0.3, "rest_speed": 0.0}})
    lanes = [{"integrator.method": method, "integrator.dt": 0.001,
              "effects.stroke_limits.restitution": r, "effects.gravity": g}
             for r, g in ((0.3, 10.0), (0.5, 10.0), (0.4, 0.0), (0.3, 9.0), (0.5, 0.0),
                          (0.45, 10.0), (0.35, 8.0), (0.3, 10.0), (0.5, 10.0), (0.4, 9.5))]
    first = np.array(list(sample_times(1.5, RATE)))
    then = first[-1] + first[first <= 0.5]
    pushed = [0, 1, 3, 5, 6]

    def push(batch):
        batch.set_efforts(joints=[0.0, 15.0], lanes=pushed)

    cpp = assert_three_agree(document, lanes, [(first, push), (then, None)])
    rested = [any(impact.resting for impact in lane["impacts"]) for lane in cpp]
    assert not rested[2] and not rested[4]   # without gravity: never at the stop
    if method == "euler":   # explicit Euler gains energy at every flight: it chatters on, and
        return              # is compared as it is
    held = [lane["clock"][CLOCK_HOLDS] >= 1 for lane in cpp]
    assert any(held) and not all(held), held
    released = [i for i in pushed if rested[i] and cpp[i]["resting"][0] != -1]
    assert released, rested   # pulled off their stops by the push
