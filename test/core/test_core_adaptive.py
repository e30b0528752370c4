"""The compiled core's adaptive methods, rk45 and dop853 (core/include/mms/runge_kutta.hpp and
adaptive_solve.hpp), against the numba engine's kernels they replace (engine/runge_kutta.py,
engine/adaptive_stepping.py), bit for bit while both exist: the initial step, every accepted
step, its next size, its right-hand sides and rejections, and its dense output at several θ
over runs of many steps; whole sampled runs of the compiled loop (no events; with effort
changes, where the solve restarts) against the engine's. And facts of their own: the dense output
starts at the step's start and ends at its end, and converges at its order against a tight
reference solution of SciPy's; the dual-number instance of a step agrees with central differences
of the double one; a run that cannot go on, or bad input, says why in one line.
"""
import copy
import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy import integrate

import robots
from differences import best_agreement
from mobile_manip_sim.engine import runge_kutta as rk
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.engine.stepping import CLOCK_STEPS
from mobile_manip_sim.engine.system import RHS_EVALS
from mobile_manip_sim.scene.loading import load_scene, make_integrator, parse_scene
from mobile_manip_sim.scene.methods import IDS
from test_core import identical, numba_system, system_case
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
    """The paper scene in effort mode (its rods free: no rod rests at the start): the engine's
    system, its compiled core, the initial state and the core's effort arguments."""
    system, s0, _, scene = paper_system()
    core = Simulation(scene).dynamics.core
    return system, core, s0, (system.Q_cmd.copy(), system.damping, moving_of(system),
                              float(system.data.gravity))


def random_case(seed, n):
    c = system_case(seed, n)
    return numba_system(c), c["core"], c["s"], (c["Q"], c["damping"], c["moving"], c["g"])


CASES = {"paper": paper_case, **{f"random-{n}-links": (lambda n=n: random_case(500 + n, n))
                                 for n in (0, 1, 2, 5)}}


def engine_dense(m, system, s, h, work, rtol, atol, full):
    """The engine's dense output of the step in `work` at THETAS (as adaptive_stepping's
    `interpolant` builds it): (rows, from the stages alone)."""
    K = work[rk.WORK_K:rk.WORK_K + rk.MAX_STAGES]
    coeffs = work[rk.WORK_COEFFS:rk.WORK_COEFFS + rk.MAX_DENSE]
    y1, f0, f1 = work[rk.WORK_Y1], work[rk.WORK_F0], work[rk.WORK_F1]
    from_stages = not full and rk.dense_from_stages(m, s, y1, h, K, coeffs, rtol, atol)
    if not from_stages:
        rk.dense_prepare(m, system.data, s, y1, f0, f1, h, K, coeffs)
    rows = np.empty((THETAS.size, s.size))
    for i, theta in enumerate(THETAS):
        rk.dense_eval(m, coeffs, s, h, theta, rows[i])
    return rows, from_stages


def test_the_tableau_header_is_what_its_generator_writes_from_the_engines_tableaus():
    """tableaus.hpp holds engine/tableaus.py's numbers (one owner): regenerating it changes
    nothing."""
    path = ROOT / "tools" / "generate_tableaus.py"
    spec = importlib.util.spec_from_file_location("generate_tableaus", path)
    generator = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(generator)
    assert generator.HEADER.read_text() == generator.header_text()


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("method", METHODS)
def test_every_step_of_a_run_equals_the_engines_bit_for_bit(method, case):
    """80 accepted steps from the initial step on: each step's end state, length, next length,
    right-hand sides and rejections, and its dense output at several θ (the full interpolant and
    the one a sample reads: dop853's from its stages where accurate enough) equal the numba
    kernels'. Every 6th step first tries 8 times the proposed length (it is rejected), and one
    step is cut short by t_bound."""
    system, core, s, args = CASES[case]()
    m, rtol, atol = IDS[method], 1e-7, 1e-9
    work = rk.work_array(s.size)
    f0 = system.derivative(s)
    h_next = rk.initial_step(m, system.data, s, f0, np.inf, rtol, atol, np.inf,
                             np.zeros(s.size), np.zeros(s.size))
    assert core.initial_step(method, s, np.inf, rtol, atol, np.inf, *args) == h_next
    span = 0.5   # a finite span and a step limit bound the initial step too
    assert (core.initial_step(method, s, span, rtol, atol, 1e-4, *args)
            == rk.initial_step(m, system.data, s, f0, span, rtol, atol, 1e-4,
                               np.zeros(s.size), np.zeros(s.size)))
    t, rejections, from_stages = 0.0, 0, set()
    for step in range(80):
        h_try = 8.0 * h_next if step % 6 == 5 else h_next
        t_bound = t + 0.4 * h_next if step == 40 else np.inf
        work[rk.WORK_F0] = system.derivative(s)
        before = system.counters[RHS_EVALS]
        h, h_next = rk.accepted_step(m, system.data, s, t, h_try, t_bound, rtol, atol, work)
        evaluations = system.counters[RHS_EVALS] - before
        y, h_c, h_next_c, evaluations_c, rejected = core.adaptive_step(
            method, s, t, h_try, t_bound, rtol, atol, *args)
        assert (h_c, h_next_c, evaluations_c) == (h, h_next, evaluations), step
        assert step != 40 or h < h_try   # cut short by t_bound
        assert identical(y, work[rk.WORK_Y1]), step
        # a try costs 6 right-hand sides (rk45) or 11 (dop853, f(y₁) only once accepted)
        tries = evaluations // 6 if method == "rk45" else (evaluations - 1) // 11
        assert rejected == tries - 1
        rejections += rejected
        for full in (True, False):
            rows, stages_only = core.dense_output(THETAS, full)
            engine_rows, engine_stages_only = engine_dense(m, system, s, h, work, rtol, atol, full)
            assert identical(rows, engine_rows) and stages_only == engine_stages_only, step
            from_stages.add(stages_only)
        s, t = y, t + h
    assert rejections >= 10 and np.isfinite(s).all()
    if method == "dop853":
        assert True in from_stages   # both dense outputs were compared


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
    _, core, s0, args = paper_case()   # the core's right-hand side has no stops: smooth
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
    """The numba engine's sampled run of an effort-mode scene without stops (rows of s), and the
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
def test_a_sampled_run_of_the_compiled_loop_equals_the_engines_bit_for_bit(method, scene):
    """1.5 s sampled at 100 Hz (the samples read from the step in hand's dense output, the step
    never cut at a sample): the same states, steps and right-hand sides as the engine's
    adaptive core."""
    times = np.linspace(0.0, 1.5, 151)[1:]
    sim, s0, args, engine_rows = engine_sampled_run(SCENES[scene](), method, 1e-8, times)
    rows, steps, evaluations, rejections = sim.dynamics.core.adaptive_run(
        method, s0, times, 1e-8, 1e-10, *args)
    assert identical(rows, engine_rows)
    assert steps == sim._clock[CLOCK_STEPS] > 20
    assert evaluations == sim.system.counters[RHS_EVALS]
    assert np.ptp(rows[:, :sim.nq], axis=0).max() > 0.1   # the robot did move


@pytest.mark.parametrize("method", METHODS)
def test_a_run_restarted_at_effort_changes_equals_the_engines_bit_for_bit(method):
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
    _, core, s, args = paper_case()
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
    _, core, s, (Q, damping, moving, g) = paper_case()
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
