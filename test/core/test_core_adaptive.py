"""The compiled core's adaptive methods, rk45 and dop853 (core/include/mms/runge_kutta.hpp and
adaptive_solve.hpp; SciPy's are their reference in test_runge_kutta.py): whole sampled runs of the
compiled loop (no events; with effort changes, where the solve restarts) equal the engine's
stepper's bit for bit (the two drive the same steps); the dense output starts at the step's
start and ends at its end, and converges at its order against a tight reference solution of
SciPy's; the dual-number instance of a step agrees with central differences of the double one; a
run that cannot go on, or bad input, says why in one line.
"""
import copy
import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy import integrate

import robots
from differences import best_agreement
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.engine.stepping import CLOCK_STEPS
from mobile_manip_sim.engine.system import RHS_EVALS
from mobile_manip_sim.scene.loading import load_scene, make_integrator, parse_scene
from test_core import identical, system_case
from test_runge_kutta import paper_system

ROOT = Path(__file__).resolve().parents[2]
METHODS = ["rk45", "dop853"]
THETAS = np.array([0.0, 0.1, 0.37, 0.5, 0.83, 1.0])


def moving_of(system):
    """1.0 for each free pseudo-velocity of an engine `System`, 0.0 for a locked one."""
    moving = np.zeros(system.Q_cmd.size)
    moving[[k for k in system.free if k >= 0]] = 1.0
    return moving


def paper_case():
    """The paper scene in effort mode (its rods free: no rod rests at the start): its compiled
    core, the initial state and the core's effort arguments."""
    core, s0, args, _, _ = paper_system()
    return core, s0, args


def test_the_tableau_header_is_what_its_generator_writes_from_the_engines_tableaus():
    """tableaus.hpp holds engine/tableaus.py's numbers (one owner): regenerating it changes
    nothing."""
    path = ROOT / "tools" / "generate_tableaus.py"
    spec = importlib.util.spec_from_file_location("generate_tableaus", path)
    generator = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(generator)
    assert generator.HEADER.read_text() == generator.header_text()


def one_step_dense(core, method, s, h, args, theta, full):
    """The core's dense output at θ of one accepted step of length h from s (tolerances so loose
    that h is accepted and dop853's stage-only extension always chosen when not `full`)."""
    y, taken, *_ = core.adaptive_step(method, s, 0.0, h, np.inf, 1e3, 1e3, *args)
    assert taken == h
    rows, stages_only = core.dense_output(np.array([theta]), full)
    assert stages_only == (method == "dop853" and not full)
    return y, rows[0]


@pytest.mark.parametrize("method, full, order", [("rk45", True, 4), ("dop853", True, 7),
                                                 ("dop853", False, 6)])
def test_dense_output_joins_the_steps_ends_and_has_its_order(method, full, order):
    """At θ = 0 the dense output is the step's start exactly, at θ = 1 its end to round-off; its
    error at θ = ½ against SciPy's DOP853 at rtol 1e-13 on the core's own right-hand side falls
    as h^(p+1), p the interpolant's order (4 rk45, 7 dop853, 6 dop853 from its stages alone)."""
    core, s0, args = paper_case()   # the core's right-hand side has no stops: smooth
    hs = (0.16, 0.08, 0.04, 0.02) if method == "dop853" else (0.04, 0.02, 0.01, 0.005)
    reference = integrate.solve_ivp(lambda t, y: core.rates(y, *args), (0.0, hs[0]), s0,
                                    method="DOP853", rtol=1e-13, atol=1e-15,
                                    dense_output=True).sol
    errors = []
    for h in hs:
        y, start = one_step_dense(core, method, s0, h, args, 0.0, full)
        assert identical(start, s0)
        _, end = one_step_dense(core, method, s0, h, args, 1.0, full)
        # dop853's stage-only weights reach 5e3: round-off, amplified
        assert np.max(np.abs(end - y)) <= (1e-14 if full else 1e-11) * np.max(np.abs(y))
        _, middle = one_step_dense(core, method, s0, h, args, 0.5, full)
        errors.append(np.max(np.abs(middle - reference(0.5 * h))))
    slopes = np.diff(np.log(errors)) / np.diff(np.log(hs))
    assert np.all(np.abs(slopes - (order + 1)) < 0.7), (errors, slopes)


def engine_sampled_run(scene, method, rtol, times):
    """The engine's sampled run of an effort-mode scene without stops (rows of s), and the
    core's arguments for the same run."""
    sim = Simulation(scene, make_integrator(scene.integrator, method, rtol=rtol, atol=rtol * 1e-2))
    s0, system = sim.s.copy(), sim.system
    args = (system.Q_cmd.copy(), system.damping, moving_of(system), float(system.data.gravity))
    rows = sim.sample(times)[:, :-1]
    return sim, s0, args, rows


def smooth_paper_scene():
    document = copy.deepcopy(load_scene().document)
    del document["effects"]["stroke_limits"]
    return parse_scene(document)


SCENES = {"paper": smooth_paper_scene,
          "random-3-links": lambda: parse_scene(robots.random_robot_document(
              np.random.default_rng(7), 3))}


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("method", METHODS)
def test_a_sampled_run_of_the_compiled_loop_equals_the_steppers_bit_for_bit(method, scene):
    """1.5 s sampled at 100 Hz (the samples read from the step in hand's dense output, the step
    never cut at a sample): the same states, steps and right-hand sides as the engine's
    stepper."""
    times = np.linspace(0.0, 1.5, 151)[1:]
    sim, s0, args, engine_rows = engine_sampled_run(SCENES[scene](), method, 1e-8, times)
    rows, steps, evaluations, rejections = sim.dynamics.core.adaptive_run(
        method, s0, times, 1e-8, 1e-10, *args)
    assert identical(rows, engine_rows)
    assert steps == sim._clock[CLOCK_STEPS] > 20
    assert evaluations == sim.system.counters[RHS_EVALS]
    assert np.ptp(rows[:, :sim.nq], axis=0).max() > 0.1   # the robot did move


@pytest.mark.parametrize("method", METHODS)
def test_a_run_restarted_at_effort_changes_equals_the_steppers_bit_for_bit(method):
    """New efforts at 0.3 s and twice within one step near 0.75 s: each change ends the solve
    there and the next starts with the last step's length (`restart`); the samples, steps and
    right-hand sides are the engine's (its `set_efforts` restarts its solve the same way)."""
    scene = smooth_paper_scene()
    sim = Simulation(scene, make_integrator(scene.integrator, method, rtol=1e-8, atol=1e-10))
    s0, system = sim.s.copy(), sim.system
    times, changes = np.linspace(0.0, 1.5, 151)[1:], [0.3, 0.7501, 0.7502]
    rng = np.random.default_rng(3)
    efforts, engine_rows, previous = [system.Q_cmd.copy()], [], 0.0
    for change in changes:
        engine_rows.append(sim.sample(times[(times > previous) & (times <= change)]))
        sim.advance_to(change)
        sim.set_efforts(rng.uniform(-0.3, 0.3, 2), rng.uniform(-5.0, 5.0, 4))
        efforts.append(system.Q_cmd.copy())
        previous = change
    engine_rows.append(sim.sample(times[times > previous]))
    rows, steps, evaluations, _ = sim.dynamics.core.adaptive_run(
        method, s0, times, 1e-8, 1e-10, np.array(efforts), system.damping, moving_of(system),
        float(system.data.gravity), changes=changes)
    assert identical(rows, np.concatenate(engine_rows)[:, :-1])
    assert steps == sim._clock[CLOCK_STEPS] and evaluations == system.counters[RHS_EVALS]
    # the efforts did change the run: the same run without the changes differs after 0.3 s
    unchanged = sim.dynamics.core.adaptive_run(method, s0, times, 1e-8, 1e-10, efforts[0],
                                               system.damping, moving_of(system),
                                               float(system.data.gravity))[0]
    assert identical(rows[times < 0.3], unchanged[times < 0.3])
    assert np.abs(rows[-1] - unchanged[-1]).max() > 1e-3


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("n", [0, 2, 5])
def test_dual_jacobians_of_a_step_agree_with_central_differences_of_the_double_step(n, method):
    """∂y₁/∂(x, τ) of one step of a given length (the dual-number instance of the same kernels)
    against central differences of the double step (`adaptive_step` accepting that length):
    1e-8 relative to the Jacobian's size; the dual value is the double step bit for bit."""
    c = system_case(600 + n, n)
    core, s, rng = c["core"], c["s"], c["rng"]
    nq, nu, h = c["robot"].n_q, c["robot"].n_u, 0.005
    B, tau0 = rng.normal(size=(nu, 3)), np.zeros(3)

    def mapped(x, tau):
        state = np.concatenate([x, s[nq + nu:]])
        y, taken, *_ = core.adaptive_step(method, state, 0.0, h, np.inf, 1e3, 1e3,
                                          c["Q"] + B @ tau, c["damping"], c["moving"], c["g"])
        assert taken == h
        return y[:nq + nu]
    value, d_dx, d_dtau = core.jacobians(method, s, h, c["Q"], B, c["damping"], c["moving"],
                                         c["g"])
    x = s[:nq + nu]
    assert identical(value, mapped(x, tau0))
    assert best_agreement(lambda x: mapped(x, tau0), x, d_dx) <= 1e-8
    assert best_agreement(lambda tau: mapped(x, tau), tau0, d_dtau) <= 1e-8


def test_bad_input_is_refused_in_one_line_naming_it():
    core, s, args = paper_case()
    with pytest.raises(ValueError, match=r"^method: expected rk45 or dop853, got rk4$"):
        core.adaptive_step("rk4", s, 0.0, 0.01, np.inf, 1e-6, 1e-9, *args)
    with pytest.raises(ValueError, match=r"^rtol: expected a positive number, got -1"):
        core.adaptive_step("rk45", s, 0.0, 0.01, np.inf, -1.0, 1e-9, *args)
    with pytest.raises(ValueError, match=r"^atol: expected a positive number, got nan$"):
        core.adaptive_run("rk45", s, np.array([0.1]), 1e-6, np.nan, *args)
    with pytest.raises(ValueError, match=r"^h_abs: expected a positive step$"):
        core.adaptive_step("dop853", s, 0.0, 0.0, np.inf, 1e-6, 1e-9, *args)
    with pytest.raises(ValueError, match=r"^dense_output: no accepted step in hand"):
        core.dense_output(THETAS, True)
    with pytest.raises(ValueError, match=r"^times: expected finite increasing times from 0, "
                                         r"got 0\.1 at index 2$"):
        core.adaptive_run("dop853", s, np.array([0.1, 0.2, 0.1]), 1e-6, 1e-9, *args)
    with pytest.raises(ValueError, match=r"^changes: expected finite increasing times from 0, "
                                         r"got -1 at index 0$"):
        core.adaptive_run("dop853", s, np.array([0.1]), 1e-6, 1e-9, np.tile(args[0], (2, 1)),
                          *args[1:], changes=[-1.0])
    with pytest.raises(ValueError, match=r"^Q_cmd \(a row of efforts before and after each "
                                         r"change\): expected 18 numbers, got 6$"):
        core.adaptive_run("dop853", s, np.array([0.1]), 1e-6, 1e-9, *args, changes=[0.1, 0.2])
    core.adaptive_step("dop853", s, 0.0, 0.01, np.inf, 1e-6, 1e-9, *args)
    with pytest.raises(ValueError, match=r"^thetas: expected values in \[0, 1\], got 1\.5"):
        core.dense_output(np.array([0.5, 1.5]), True)
    with pytest.raises(ValueError, match=r"^method: expected euler, semi_implicit_euler, rk4, "
                                         r"rk45 or dop853, got rk5$"):
        core.jacobians("rk5", s, 0.01, args[0], np.eye(args[0].size), *args[1:])
    s_bad = s.copy()
    s_bad[3] = np.nan
    with pytest.raises(ValueError, match=r"^s: expected finite numbers, got nan at index 3$"):
        core.adaptive_run("rk45", s_bad, np.array([0.1]), 1e-6, 1e-9, *args)


def test_a_run_that_cannot_go_on_says_why_in_one_line():
    """Efforts of 1e100 (accelerations the steps cannot follow): the step shrinks below 10
    spacings of t and the run stops saying so; a stalled step leaves no step in hand; a run
    stops after its step budget."""
    core, s, (Q, damping, moving, g) = paper_case()
    huge = np.full_like(Q, 1e100)
    with pytest.raises(RuntimeError, match=r"^t = \S+ s: the step fell below 10 spacings of t "
                                           r"\(h = \S+ s\)$"):
        core.adaptive_run("dop853", s, np.array([0.1]), 1e-6, 1e-9, huge, damping, moving, g)
    y, h, h_next, _, rejections = core.adaptive_step("rk45", s, 1.0, 1e-3, np.inf, 1e-6, 1e-9,
                                                     huge, damping, moving, g)
    spacing = np.spacing(1.0)
    assert h == -1.0 and h_next < 10 * spacing <= h_next / 0.2 and identical(y, s)
    assert rejections > 5
    with pytest.raises(ValueError, match=r"^dense_output: no accepted step in hand"):
        core.dense_output(THETAS, True)
    with pytest.raises(RuntimeError, match=r"^t = \S+ s: the run used its 5 steps$"):
        core.adaptive_run("rk45", s, np.array([1.5]), 1e-6, 1e-9, Q, damping, moving, g,
                          max_steps=5)


def test_scipy_steps_are_handed_in_to_a_radau_or_bdf_stepper_only():
    """A step handed in to another method's stepper, a radau stepper asked to advance itself, or
    a power series of the wrong shape: one line naming the call or the argument."""
    scene = load_scene()
    rk4 = Simulation(scene, make_integrator(scene.integrator, "rk4", 1e-3))
    with pytest.raises(ValueError, match="^hand_in_step: only for radau and bdf"):
        rk4._stepper.hand_in_step(1e-3, rk4.s, np.zeros((3, rk4.s.size)))
    radau = Simulation(scene, make_integrator(scene.integrator, "radau"))
    with pytest.raises(ValueError, match="^advance: radau and bdf are stepped from Python"):
        radau._stepper.advance(radau.s, radau._clock, 1.0, 10)
    with pytest.raises(ValueError, match=r"^series: expected \(rows ≤ 7, "):
        radau._stepper.hand_in_step(1e-3, radau.s, np.zeros((8, radau.s.size)))
