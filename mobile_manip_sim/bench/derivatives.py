"""Exact Jacobians and the compiled core's dynamics, against MuJoCo's finite differences in the
same process.

- **Ours**: the paper robot (15 states, 6 efforts) at a state of its paper run, with the
  paper's efforts. The continuous-time Jacobians (∂f/∂x, ∂f/∂τ: `Simulation.linearize`) and A, B
  of one rk4 step of 1 ms (`Simulation.step_jacobians`), exact, by dual numbers through the
  compiled core: CPU time of the kernel alone (a loop in C++, `Dynamics.time_jacobians`) and of
  the call from Python. One forward-dynamics evaluation, scalar and per lane of a vector block.
  A, B of the step of that run that holds its first impact (at 0.5879 s, the rod coming to
  rest), differentiated through it (the stepper's double run of the step, then the dual numbers
  through its event): from Python.
  The paper run without its stops (no events), dop853 at rtol 1e-10, sampled at 100 Hz: the
  compiled core's adaptive loop alone (`Dynamics.adaptive_run`) and the whole engine
  (`Simulation.sample`: its events watched, its samples handed back to Python).
- **The peer**: `mujoco.mjd_transitionFD` on the paper robot's 7-dof equivalent model
  (`mujoco_peer.py`) at the same state, with its Euler integrator at 1 ms (it refuses RK4):
  A and B (14 + 6 columns) by forward and by centred differences, ε = 1e-6. These are not exact:
  a difference of the step map with the accuracy that ε allows.
- CPU time of this thread (`time.thread_time` and the core's CLOCK_THREAD_CPUTIME_ID), best of
  seven batches.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from ..core import build_info
from ..engine.linearization import effort_map
from ..engine.simulation import Simulation
from ..scene.loading import IntegratorSettings, load_scene, parse_scene
from . import mujoco_peer
from .loops import per_python_call
from .tables import table, verdict
from .versus import rates_inputs

TARGETS = {"continuous": 3e-6, "rk4": 10e-6, "fd": 250e-9, "versus_centred": 4.0}


@dataclass
class DerivativesResult:
    continuous_kernel: float   # s per call
    continuous_python: float
    rk4_kernel: float
    rk4_python: float
    fd_scalar: float
    fd_lane: float
    lane_width: int
    rk4_impact_python: float = float("nan")  # s per call, a step holding an impact
    dop853_core: float = float("nan")     # s per 1.5 s paper run without stops
    dop853_simulation: float = float("nan")
    mujoco_forward: float = float("nan")
    mujoco_centred: float = float("nan")


def _best(measure, repeats: int = 7) -> float:
    return min(measure() for _ in range(repeats))


def measure(progress, quick: bool = False) -> DerivativesResult:
    scene = load_scene()
    sim = Simulation(scene, integrator=IntegratorSettings(method="rk4", dt=1e-3))
    sim.advance_to(0.5)
    core, nu = sim.dynamics.core, sim.nu
    q, u = sim.q.copy(), sim.u.copy()
    _, (Q, damping, moving, g), state = rates_inputs(scene)
    s, B = state(q, u), effort_map(sim.model)
    calls = 200 if quick else 2000
    width = build_info()["lane_width"]
    result = DerivativesResult(
        continuous_kernel=_best(lambda: core.time_jacobians("", s, 0.0, Q, B, damping, moving,
                                                            g, calls)),
        continuous_python=per_python_call(sim.linearize),
        rk4_kernel=_best(lambda: core.time_jacobians("rk4", s, 1e-3, Q, B, damping, moving, g,
                                                     calls // 4)),
        rk4_python=per_python_call(sim.step_jacobians),
        fd_scalar=_best(lambda: core.time_forward_dynamics(q, u, Q, g, moving, 50 * calls)),
        fd_lane=_best(lambda: core.time_forward_dynamics_lanes(
            np.tile(q, width), np.tile(u, width), np.tile(Q, width), g, np.ones(nu * width),
            10 * calls)),
        lane_width=width)
    progress(f"ours: continuous Jacobians {result.continuous_kernel * 1e6:.2f} us "
             f"(from Python {result.continuous_python * 1e6:.2f}), rk4 A, B "
             f"{result.rk4_kernel * 1e6:.2f} us (from Python {result.rk4_python * 1e6:.2f}); "
             f"FD {result.fd_scalar * 1e9:.0f} ns, {result.fd_lane * 1e9:.0f} ns per lane")
    impact = Simulation(scene, integrator=IntegratorSettings(method="rk4", dt=1e-3))
    impact.advance_to(0.587)   # the step to 0.588 s holds the run's first impact
    result.rk4_impact_python = per_python_call(impact.step_jacobians)
    progress(f"rk4 A, B through an impact: from Python {result.rk4_impact_python * 1e6:.2f} us")
    result.dop853_core, result.dop853_simulation = _adaptive_run(scene)
    progress(f"the paper run without stops, dop853: compiled loop "
             f"{result.dop853_core * 1e3:.2f} ms, Simulation.sample "
             f"{result.dop853_simulation * 1e3:.2f} ms")
    if mujoco_peer.available():
        import mujoco
        peer = mujoco_peer.MujocoPeer(scene.robot, g, 0.0, True, "Euler", 1e-3)
        peer.set_state(q, u)
        peer.data.ctrl[:] = peer.control(sim.wheel_efforts, sim.joint_efforts)
        n = 2 * peer.model.nv + peer.model.na
        A_peer, B_peer = np.zeros((n, n)), np.zeros((n, peer.model.nu))
        for centred in (False, True):
            seconds = per_python_call(mujoco.mjd_transitionFD, peer.model, peer.data, 1e-6,
                                      centred, A_peer, B_peer, None, None)
            if centred:
                result.mujoco_centred = seconds
            else:
                result.mujoco_forward = seconds
        progress(f"MuJoCo mjd_transitionFD (Euler): forward {result.mujoco_forward * 1e6:.2f} "
                 f"us, centred {result.mujoco_centred * 1e6:.2f} us")
    else:
        progress("mujoco is not installed: its finite differences are not measured")
    return result


def _adaptive_run(scene) -> tuple[float, float]:
    """CPU seconds of the paper run without its stops (dop853, rtol 1e-10, 100 Hz samples): the
    compiled core's adaptive loop alone, and `Simulation.sample`."""
    document = copy.deepcopy(scene.document)
    del document["effects"]["stroke_limits"]
    smooth = parse_scene(document)
    sim = Simulation(smooth, integrator=IntegratorSettings(method="dop853", rtol=1e-10,
                                                           atol=1e-12))
    times = np.linspace(0.0, smooth.duration, 151)[1:]
    core, (Q, damping, moving, g), state = rates_inputs(smooth)
    args = (state(np.array(smooth.initial_q), np.array(smooth.initial_u)), times, 1e-10, 1e-12,
            Q, damping, moving, g)

    def simulation():
        sim.reset()
        sim.sample(times)
    return per_python_call(core.adaptive_run, "dop853", *args), per_python_call(simulation)


def section(result: DerivativesResult, number: int) -> str:
    us = 1e6
    ratio = result.mujoco_centred / result.rk4_kernel
    rows = [
        ("∂f/∂x, ∂f/∂τ, continuous time (15 × 21), exact",
         f"{result.continuous_kernel * us:.2f} µs "
         f"(from Python {result.continuous_python * us:.1f})",
         verdict(result.continuous_kernel <= TARGETS["continuous"], "goal ≤ 3 µs")),
        ("A, B of one rk4 step (15 × 21), exact",
         f"{result.rk4_kernel * us:.2f} µs (from Python {result.rk4_python * us:.1f})",
         verdict(result.rk4_kernel <= TARGETS["rk4"], "goal ≤ 10 µs")),
        ("A, B of the rk4 step holding the run's first impact, exact through it",
         f"from Python {result.rk4_impact_python * us:.1f} µs", ""),
        ("MuJoCo `mjd_transitionFD`, Euler, forward differences (14 × 20)",
         f"{result.mujoco_forward * us:.2f} µs", ""),
        ("MuJoCo `mjd_transitionFD`, Euler, centred differences (14 × 20)",
         f"{result.mujoco_centred * us:.2f} µs",
         verdict(ratio >= TARGETS["versus_centred"],
                 f"ours (rk4, exact) ×{ratio:.2f} faster; goal ≥ 4×")),
        ("one forward-dynamics evaluation, scalar",
         f"{result.fd_scalar * 1e9:.0f} ns", verdict(result.fd_scalar <= TARGETS["fd"],
                                                    "goal ≤ 250 ns")),
        (f"… per lane, {result.lane_width} runs a vector block",
         f"{result.fd_lane * 1e9:.0f} ns (×{result.fd_scalar / result.fd_lane:.2f} the scalar)",
         ""),
        ("the 1.5 s paper run without stops, dop853 at rtol 1e-10, 100 Hz samples: the "
         "compiled loop", f"{result.dop853_core * 1e3:.2f} ms (`Simulation.sample`, its events "
         f"watched: {result.dop853_simulation * 1e3:.2f} ms)", "")]
    lines = [f"## {number}. Exact Jacobians, and the compiled core's dynamics", "",
             "The paper robot at t = 0.5 s of its run with rk4 at 1 kHz: the Jacobians by dual "
             "numbers through the compiled C++ core (8 derivative directions a pass, "
             f"{build_info()['lane_width']}-wide lanes in this build), against MuJoCo's finite "
             "differences of one step on its 7-dof equivalent model in the same process (MuJoCo "
             "differences Euler and its implicit integrators only). CPU time of the thread, best "
             "of seven batches; \"from Python\" adds the call and the arrays around it.", "",
             table(("what", "time", "target"), rows), ""]
    return "\n".join(lines)
