"""Integrators (the core's fixed-step and adaptive methods, SciPy's radau and bdf): convergence at
their orders, the stepping interface, and bit-identical repeats (zero-order-hold commands).

One generic suite over every method, as Drake's `generic_integrator_test.h` does: the error at
t = 0.2 s on a smooth scene (the paper robot, no stops, moving in every coordinate) against a
DOP853 reference at rtol 1e-13.
"""
import math
import subprocess
import sys

import numpy as np
import pytest

from engine_cases import PAPER_SCENE, paper_doc, sampled, simulation
from mobile_manip_sim.scene import methods
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.loading import FIXED_STEP_METHODS, METHODS

ADAPTIVE_METHODS = [m for m in METHODS if m not in FIXED_STEP_METHODS]
T_END = 0.2


def smooth_doc():
    """The paper scene, gravity and efforts on, stroke limits off, every velocity nonzero."""
    doc = paper_doc()
    del doc["effects"]["stroke_limits"]
    doc["initial"]["velocity"] = [0.3, 0.5, 1.0, 0.4, -1.5, 0.3]
    return doc


@pytest.fixture(scope="module")
def reference():
    sim = simulation(smooth_doc(), "dop853", rtol=1e-13, atol=1e-15)
    sim.advance_to(T_END)
    return sim.s.copy()


def final_error(reference, method, **settings):
    sim = simulation(smooth_doc(), method, **settings)
    sim.advance_to(T_END)
    return np.max(np.abs(sim.s - reference))


def test_every_fixed_step_method_the_engine_runs_has_an_order_to_be_tested_at():
    assert set(FIXED_STEP_METHODS) == {name for name, m in methods.METHODS.items()
                                       if m.stepper == "stepping"}
    # the ids the compiled core branches on are the registry's, one per method
    compiled = {methods.IDS[name] for name, m in methods.METHODS.items() if m.compiled}
    assert len(compiled) == 5


@pytest.mark.parametrize("method, dt, slack", [
    ("euler", 1e-3, 0.5), ("semi_implicit_euler", 1e-3, 0.5), ("rk4", 1e-2, 0.3)])
def test_every_fixed_step_method_converges_at_its_order(reference, method, dt, slack):
    """Observed order log2(e(dt) / e(dt/2)) within `slack` of the nominal order."""
    errors = [final_error(reference, method, dt=h) for h in (dt, dt / 2)]
    assert errors[1] > 1e3 * 1e-12, "the reference must be far more accurate than the method"
    observed = math.log2(errors[0] / errors[1])
    assert abs(observed - methods.METHODS[method].order) < slack, (errors, observed)


@pytest.mark.parametrize("method", ADAPTIVE_METHODS)
def test_every_adaptive_method_meets_its_tolerance(reference, method):
    """The error falls as rtol falls and stays within ~100 rtol of the reference."""
    rtols = (1e-4, 1e-6, 1e-8)
    errors = [final_error(reference, method, rtol=r, atol=1e-3 * r) for r in rtols]
    assert errors[0] > errors[1] > errors[2], errors
    for rtol, error in zip(rtols, errors, strict=True):
        assert error < 100 * rtol, (rtol, error)


@pytest.mark.parametrize("method", METHODS)
def test_advance_lands_exactly_on_the_requested_time(method):
    sim = simulation(smooth_doc(), method, dt=1e-3, rtol=1e-8, atol=1e-11)
    for t in (0.0123, 0.05, 0.05, 0.0731):   # off the dt grid, on it, zero length, off again
        sim.advance_to(t)
        assert sim.t == pytest.approx(t, abs=1e-15)
    before = sim.s.copy()
    sim.advance_to(sim.t)
    assert np.array_equal(sim.s, before)
    with pytest.raises(UserError, match="t_end"):
        sim.advance_to(0.01)


@pytest.mark.parametrize("method", ["rk4", "semi_implicit_euler"])
def test_sampling_on_the_grid_does_not_change_a_fixed_step_run(method):
    """Zero-order hold on the dt grid: one call or 100 calls give the very same states."""
    one = simulation(smooth_doc(), method, dt=1e-3)
    one.advance_to(0.1)
    many = simulation(smooth_doc(), method, dt=1e-3)
    sampled(many, 0.1, 1000)
    assert np.array_equal(one.s, many.s)
    assert one.steps == many.steps == 100


# --- bit-identical repeats -----------------------------------------------------------------

def commanded_run(method, **settings):
    """The paper scene (end stops on) under a changing command sequence, sampled at 100 Hz."""
    sim = simulation(paper_doc(), method, **settings)
    states = []
    for i in range(1, 121):
        if i % 20 == 0:
            sim.set_efforts(wheels=[0.1 * math.sin(i), 0.2],
                            joints=[4.5 + (i % 40) / 10, 7.0, 0.0, 1.0])
        sim.advance_to(i / 100)
        states.append(sim.s.copy())
    return np.array(states), [impact.as_dict() for impact in sim.impacts], sim.stats()


@pytest.mark.parametrize("method, settings", [("rk4", dict(dt=1e-3)), ("dop853", {}),
                                              ("radau", dict(rtol=1e-6))])
def test_repeating_a_run_in_process_is_bit_identical(method, settings):
    first = commanded_run(method, **settings)
    second = commanded_run(method, **settings)
    assert first[1], "the run should hit an end stop"
    assert np.array_equal(first[0], second[0])
    assert first[1] == second[1] and first[2] == second[2]


def test_reset_repeats_the_run_bit_identically():
    sim = simulation(paper_doc(), "dop853")
    sim.advance_to(1.0)
    s, impacts = sim.s.copy(), list(sim.impacts)
    sim.reset()
    sim.advance_to(1.0)
    assert np.array_equal(sim.s, s) and sim.impacts == impacts


def test_repeating_the_simulate_cli_gives_identical_bytes(tmp_path):
    outputs = []
    for name in ("a", "b"):
        out = tmp_path / f"{name}.csv"
        result = subprocess.run(
            [sys.executable, "-m", "mobile_manip_sim.programs.simulate",
             "--scene", str(PAPER_SCENE),
             "--duration", "1.0", "--sample-rate", "200", "--out", str(out)],
            capture_output=True, text=True, timeout=120)
        assert result.returncode == 0, result.stderr
        assert len(result.stdout.strip().splitlines()) == 1   # the summary line
        outputs.append((out.read_bytes(), out.with_suffix(".impacts.csv").read_bytes()))
    assert outputs[0] == outputs[1]
    assert outputs[0][0].count(b"\n") == 202
    assert outputs[0][1].count(b"\n") == 4   # header + 3 impacts in 1 s
