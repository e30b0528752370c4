"""Against the peer, in the same run: the projected Pinocchio model (`peers.py`) per evaluation
and over the whole 1.5 s paper run driven by SciPy's DOP853, at equal accuracy.

The whole-run comparison uses the paper robot with its stroke limits removed: SciPy's
`solve_ivp` has no end-stop impacts, so with them the two runs would not solve the same
problem. Both sides are compared with the same reference (ours, DOP853 at rtol 1e-13).
"""
from __future__ import annotations

import math
import time

import numpy as np
from scipy.integrate import solve_ivp

from ..dynamics import Dynamics
from ..runtime.timeline import sample_times
from ..scene.effects import settings as effect_settings
from ..scene.loading import load_scene, make_integrator
from . import loops, peers
from .runs import simulate
from .scenes import without_stroke_limits

PEER_RTOLS = (1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
ACCURACY = 1e-6
SEED_SECONDS = 34.32   # the seed paper: MATLAB ode45, Core 2 Duo E7500, 1.5 s of the same robot


def rates_inputs(scene):
    """The compiled core's right-hand side of the scene's robot, as the engine calls it at the
    scene's efforts, damping and locks: (core, the arguments of `rates` after the state, a
    function (q, u) → the state with zero integrals)."""
    effects = effect_settings(scene)
    dyn = Dynamics(scene.robot, **effects.dynamics_options())
    core, nu = dyn.core, scene.robot.n_u
    Q = np.concatenate([dyn.wheel_forces(*scene.wheel_efforts), scene.joint_efforts])
    damping = effects.generalized_damping(scene.robot.base)
    moving = np.ones(nu)
    moving[list(effects.locked)] = 0.0
    args = (Q, np.empty(0) if damping is None else damping, moving, float(dyn.gravity))

    def state(q, u):
        return np.concatenate([q, u, np.zeros(core.state_size - len(q) - len(u))])
    return core, args, state


def per_evaluation(progress, quick: bool = False) -> dict:
    """Seconds per forward-dynamics evaluation of the paper robot, each way of calling it."""
    scene = load_scene()
    dyn = Dynamics(scene.robot, gravity=scene.effects.gravity,
                   wheel_inertia=scene.effects.wheel_inertia)
    peer = peers.ProjectedPinocchio(scene.robot, scene.effects.gravity,
                                    wheel_inertia=scene.effects.wheel_inertia)
    rng = np.random.default_rng(6)
    q = np.array(scene.initial_q)
    u = rng.normal(size=scene.robot.n_u)
    core, (Q, damping, moving, g), state = rates_inputs(scene)
    s = state(q, u)
    target = 0.02 if quick else 0.1
    out = {
        "Pinocchio: crba + rnea + projection + solve, from Python":
            loops.per_python_call(peer.forward_dynamics, q, u, Q, target=target),
        "Pinocchio: crba + rnea calls alone, from Python":
            loops.per_python_call(peer.crba_and_rnea, q, u, target=target),
        "ours: Dynamics.forward_dynamics (frames + articulated), from Python":
            loops.per_python_call(dyn.forward_dynamics, q, u, Q, target=target),
        "ours: frames + articulated forward dynamics, compiled loop":
            loops.per_call(lambda calls: dyn.core.time_forward_dynamics(
                q, u, Q, dyn.gravity, moving, calls), target=target),
        "ours: engine right-hand side (the core's rates), from Python":
            loops.per_python_call(core.rates, s, Q, damping, moving, g, target=target),
        "ours: engine right-hand side, compiled loop":
            loops.per_call(lambda calls: core.time_rates(s, Q, damping, moving, g, calls),
                           target=target),
        "ours: one rk4 step of 1 ms (four right-hand sides), compiled loop":
            loops.per_call(lambda calls: core.time_step("rk4", s, 1e-3, Q, damping, moving, g,
                                                        calls), target=target),
    }
    agree = peers.agreement(dyn, peer, rng)
    progress("per evaluation: " + ", ".join(f"{v * 1e6:.2f} µs" for v in out.values()))
    return {"times": out, "agreement": agree}


def _timed_solve_ivp(f, y0, duration, times, rtol, repeats):
    best, solution = math.inf, None
    for _ in range(repeats):
        start = time.thread_time()
        solution = solve_ivp(f, (0.0, duration), y0, method="DOP853", rtol=rtol, atol=rtol * 1e-2,
                             t_eval=times)
        best = min(best, time.thread_time() - start)
    return best, solution


def whole_run(progress, quick: bool = False) -> dict:
    """The 1.5 s paper run (stroke limits removed) at equal accuracy: peer vs ours."""
    scene = without_stroke_limits(load_scene())
    duration = scene.duration
    repeats = 1 if quick else 3
    reference = simulate(scene, make_integrator(scene.integrator, "dop853", rtol=1e-13, atol=1e-14))
    ref = reference.samples
    times = np.array(list(sample_times(duration, 100.0)))
    core, (Q, damping, moving, g), state = rates_inputs(scene)
    peer = peers.ProjectedPinocchio(scene.robot, scene.effects.gravity,
                                    wheel_inertia=scene.effects.wheel_inertia)
    nq = scene.robot.n_q
    y0 = np.concatenate([scene.initial_q, scene.initial_u])

    def error(solution, columns):
        if solution is None or not solution.success or solution.y.shape[1] != len(ref):
            return math.inf
        return float(np.abs(solution.y[:columns].T - ref).max())

    rows = {"Pinocchio + SciPy DOP853": [], "ours + SciPy DOP853": [], "ours, Simulation": []}
    f_peer = peer.rhs(Q)
    s0 = state(np.array(scene.initial_q, dtype=float), np.array(scene.initial_u, dtype=float))

    def f_ours(_t, y):
        return core.rates(y, Q, damping, moving, g)

    rtols = PEER_RTOLS[::2] if quick else PEER_RTOLS
    for rtol in rtols:
        cpu, solution = _timed_solve_ivp(f_peer, y0, duration, times, rtol, repeats)
        rows["Pinocchio + SciPy DOP853"].append((f"rtol={rtol:.0e}", cpu,
                                                 error(solution, nq + scene.robot.n_u),
                                                 solution.nfev))
        cpu, solution = _timed_solve_ivp(f_ours, s0, duration, times, rtol, repeats)
        rows["ours + SciPy DOP853"].append((f"rtol={rtol:.0e}", cpu,
                                            error(solution, nq + scene.robot.n_u), solution.nfev))
        peer_cpu = rows["Pinocchio + SciPy DOP853"][-1][1]
        progress(f"whole run rtol {rtol:.0e}: peer {peer_cpu * 1e3:.1f} ms, "
                 f"ours {rows['ours + SciPy DOP853'][-1][1] * 1e3:.1f} ms")
    for method, values in (("rk4", (1e-2, 5e-3, 2e-3, 1e-3)), ("dop853", (1e-6, 1e-8, 1e-10))):
        for value in values:
            settings = (make_integrator(scene.integrator, method, dt=value) if method == "rk4" else
                        make_integrator(scene.integrator, method, rtol=value, atol=value * 1e-2))
            run = simulate(scene, settings, repeats=repeats)
            rows["ours, Simulation"].append((f"{method} {run.setting}", run.cpu,
                                             run.error_against(reference), run.rhs_evaluations))
            progress(f"whole run ours {method} {run.setting}: {run.cpu * 1e3:.1f} ms, "
                     f"error {rows['ours, Simulation'][-1][2]:.1e}")
    check_cpu, check = _timed_solve_ivp(f_peer, y0, duration, times, 1e-12, 1)
    best = {name: min((r for r in entries if r[2] <= ACCURACY), key=lambda r: r[1], default=None)
            for name, entries in rows.items()}
    return {"rows": rows, "best": best, "peer_vs_reference": error(check, nq + scene.robot.n_u),
            "scene": scene.name}


def realtime(progress, quick: bool = False) -> list:
    """The paper scene at a fixed 1 kHz, sampled at 100 Hz and in one call:
    (label, Run, real-time factor)."""
    scene = load_scene()
    smooth = without_stroke_limits(scene)
    out = []
    repeats = 2 if quick else 7
    for method in ("rk4", "semi_implicit_euler", "euler"):
        settings = make_integrator(scene.integrator, method, dt=1e-3)
        for label, case, rate in ((method, scene, 100.0),
                                  (f"{method}, one advance_to call", scene, 1.0 / scene.duration),
                                  (f"{method}, no end stops, one advance_to call", smooth,
                                   1.0 / scene.duration)):
            run = simulate(case, settings, sample_rate=rate, repeats=repeats, record=False)
            out.append((label, run, scene.duration / run.cpu))
            progress(f"1 kHz {label}: {run.cpu * 1e3:.1f} ms CPU for 1.5 s, real-time factor "
                     f"{scene.duration / run.cpu:.0f}")
    return out
