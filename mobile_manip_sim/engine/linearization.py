"""Exact Jacobians of the simulated robot, by dual numbers through the compiled core.

Continuous time: ẋ = f(x, τ), x = (q, u) (n_q + n_u), τ = (τ_R, τ_L, τ_1, F_1, …) the commanded
wheel and joint efforts (n_u); f = (q̇(q, u), u̇), u̇ = M(q)⁻¹ (Q − h(q, u)) with
Q = B τ − c ⊙ u: B turns wheel torques into (Q_v, Q_ω) = ((τ_R + τ_L)/r, b (τ_R − τ_L)/r) and
passes the joint efforts on; c are the damping effect's coefficients. Pseudo-velocities that are
locked now (the scene's locked joints, rods resting at a stop) have u̇ ≡ 0: their rows are zero.
An effort held at its limit by the effort-limits effect has a zero column (the clamp is active).

One step: the exact derivative of the step map of each fixed-step method — the core's own step
(`core/include/mms/fixed_step.hpp`: euler, semi_implicit_euler, rk4) instantiated for dual
numbers, so that A and B are the derivatives of the very map the step computes. The step is the
one between events: a step that would hold an impact or a release is not differentiated through
its event here.
"""
from __future__ import annotations

import numpy as np

from ..scene.errors import UserError
from ..scene.limits import ANGLE, SPEED
from ..scene.methods import METHODS

# the fixed-step methods the core differentiates
DIFFERENTIATED = ("euler", "semi_implicit_euler", "rk4")


def effort_map(model) -> np.ndarray:
    """B (n_u × n_u): the generalized forces Q of the efforts τ = (τ_R, τ_L, τ_1, F_1, …)."""
    r, b = model.base.wheel_radius, model.base.half_track
    B = np.eye(model.n_u)
    B[:2, :2] = [[1.0 / r, 1.0 / r], [b / r, -b / r]]
    return B


def check_effort_mode(sim, what: str) -> None:
    """The Jacobians are of the robot driven by efforts: say so where a controller drives it."""
    if sim.velocity_mode:
        raise UserError(what, "the base takes velocity commands (its wheel-speed loop is not "
                              "differentiated yet): give wheel efforts (set_efforts) first")
    if sim.arm_controller.active:
        raise UserError(what, f"the arm is driven by its {sim.arm_controller.mode} controller "
                              f"(not differentiated yet): linearize in effort mode")


def jacobians(sim, method: str, q, u, h: float = 0.0):
    """(value, ∂/∂x, ∂/∂τ) of the rates (method "") or of one step of `method`, at (q, u) with
    the simulation's efforts, damping and locks (module doc)."""
    nu = sim.nu
    moving = np.ones(nu)
    moving[list(sim.system.locked)] = 0.0
    B = effort_map(sim.model)
    limits = sim.effects.effort_limits
    if limits is not None:
        B[:, np.abs(np.concatenate([sim.wheel_efforts, sim.joint_efforts])) >= limits] = 0.0
    s = np.concatenate([q, u, np.zeros(3)])
    return sim.dynamics.core.jacobians(method, s, float(h), sim.system.Q_cmd, B,
                                       sim.system.damping, moving, sim.dynamics.gravity)


def linearize(sim, q=None, u=None):
    """(∂f/∂x, ∂f/∂τ) of the simulation at (q, u) (default: its current state)."""
    check_effort_mode(sim, "linearize")
    q, u = _state(sim, q, u)
    _, F_x, F_tau = jacobians(sim, "", q, u)
    return F_x, F_tau


def step_jacobians(sim, q=None, u=None, dt: float | None = None):
    """(A, B) = (∂x⁺/∂x, ∂x⁺/∂τ) of one step of the run's fixed-step method of length dt
    (default: the run's) from (q, u) (default: the current state)."""
    check_effort_mode(sim, "step_jacobians")
    method = sim.settings.method
    if method not in DIFFERENTIATED:
        kind = "adaptive" if not METHODS[method].fixed_step else "not differentiated"
        raise UserError("integrator.method", f"step_jacobians differentiates the steps of "
                                             f"{', '.join(DIFFERENTIATED)}; {method} is {kind}")
    h = sim.settings.dt if dt is None else float(dt)
    if not np.isfinite(h) or h <= 0.0:
        raise UserError("dt", f"must be a positive step in seconds, got {dt!r}")
    q, u = _state(sim, q, u)
    _, A, B = jacobians(sim, method, q, u, h)
    return A, B


def _state(sim, q, u):
    """(q, u) given (checked as `Simulation.set_state` checks them), else the current ones."""
    q = sim.q.copy() if q is None else sim._state_vector(q, sim.nq, "q", ANGLE)
    u = sim.u.copy() if u is None else sim._state_vector(u, sim.nu, "u", SPEED)
    return q, u
