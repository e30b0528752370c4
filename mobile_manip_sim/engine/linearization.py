"""Exact Jacobians of the simulated robot, by dual numbers through the compiled core.

Continuous time: ẋ = f(x, τ), x = (q, u) (n_q + n_u), τ = (τ_R, τ_L, τ_1, F_1, …) the commanded
wheel and joint efforts (n_u); f = (q̇(q, u), u̇), u̇ = M(q)⁻¹ (Q − h(q, u)) with
Q = B τ − c ⊙ u: B turns wheel torques into (Q_v, Q_ω) = ((τ_R + τ_L)/r, b (τ_R − τ_L)/r) and
passes the joint efforts on; c are the damping effect's coefficients. Pseudo-velocities that are
locked now (the scene's locked joints, rods resting at a stop) have u̇ ≡ 0: their rows are zero.
An effort held at its limit by the effort-limits effect has a zero column (the clamp is active).

One step: the exact derivative of the step map of each fixed-step method (`fixed_step.py`) — the
chain rule through its stages, every stage's Jacobian exact:
  euler                 x⁺ = x + h f(x)                     A = 1 + h F_x
  semi_implicit_euler   u⁺ = u + h u̇(q, u), q⁺ = q + h q̇(q, u⁺)
  rk4                   x_i = x + c_i h k_{i−1}, k_i = f(x_i), x⁺ = x + h/6 (k₁ + 2k₂ + 2k₃ + k₄)
                        ∂k_i/∂x = F_x(x_i) (1 + c_i h ∂k_{i−1}/∂x)
The step is the one between events: a step that would hold an impact or a release is not
differentiated through its event here.
"""
from __future__ import annotations

import numpy as np

from ..scene.errors import UserError
from ..scene.limits import ANGLE, SPEED
from ..scene.methods import METHODS

# the fixed-step methods this module differentiates, and rk4's stage offsets c_i (times h)
DIFFERENTIATED = ("euler", "semi_implicit_euler", "rk4")
RK4_OFFSETS = (0.0, 0.5, 0.5, 1.0)


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


class Linearization:
    """The Jacobians of one simulation's right-hand side and step, at any state, with its efforts,
    damping and locks as they are now."""

    def __init__(self, sim):
        self.sim = sim
        self.nq, self.nu = sim.nq, sim.nu
        self.B = effort_map(sim.model)

    def rates(self, q, u):
        """(f, ∂f/∂x, ∂f/∂τ) at (q, u): f = (q̇, u̇) (module doc)."""
        sim = self.sim
        moving = np.ones(self.nu)
        moving[list(sim.system.locked)] = 0.0
        damping = sim.system.damping
        c = damping if damping.size else np.zeros(self.nu)
        Q = sim.system.Q_cmd - c * u
        f, dq, du, dQ = sim.dynamics.rate_derivatives(q, u, Q, moving)
        F_x = np.hstack([dq, du - dQ * c])      # ∂Q/∂u = −diag(c)
        F_tau = dQ @ self.B
        limits = sim.effects.effort_limits
        if limits is not None:
            efforts = np.concatenate([sim.wheel_efforts, sim.joint_efforts])
            F_tau[:, np.abs(efforts) >= limits] = 0.0
        return f, F_x, F_tau

    def step(self, q, u, h: float, method: str):
        """(x⁺, A, B) of one step of `method` of length h from (q, u) (module doc)."""
        nq, nx = self.nq, self.nq + self.nu
        x = np.concatenate([q, u])
        identity = np.eye(nx)
        if method == "euler":
            f, F_x, F_tau = self.rates(q, u)
            return x + h * f, identity + h * F_x, h * F_tau
        if method == "semi_implicit_euler":
            f, F_x, F_tau = self.rates(q, u)
            u_next = u + h * f[nq:]
            du_dx = identity[nq:] + h * F_x[nq:]
            du_dtau = h * F_tau[nq:]
            rate, P_x, _ = self.rates(q, u_next)   # q̇(q, u⁺): only its q rows are read
            q_next = q + h * rate[:nq]
            dq_dx = identity[:nq] + h * (P_x[:nq, :nq] @ identity[:nq] + P_x[:nq, nq:] @ du_dx)
            dq_dtau = h * (P_x[:nq, nq:] @ du_dtau)
            return (np.concatenate([q_next, u_next]), np.vstack([dq_dx, du_dx]),
                    np.vstack([dq_dtau, du_dtau]))
        k, dk_dx, dk_dtau = [], [], []
        for stage, offset in enumerate(RK4_OFFSETS):
            c = offset * h
            xs, dxs_dx, dxs_dtau = x, identity, np.zeros((nx, self.nu))
            if stage:
                xs = x + c * k[-1]
                dxs_dx = identity + c * dk_dx[-1]
                dxs_dtau = c * dk_dtau[-1]
            f, F_x, F_tau = self.rates(xs[:nq], xs[nq:])
            k.append(f)
            dk_dx.append(F_x @ dxs_dx)
            dk_dtau.append(F_x @ dxs_dtau + F_tau)
        weights = (1.0, 2.0, 2.0, 1.0)
        x_next = x + h / 6.0 * sum(w * ki for w, ki in zip(weights, k, strict=True))
        A = identity + h / 6.0 * sum(w * d for w, d in zip(weights, dk_dx, strict=True))
        B = h / 6.0 * sum(w * d for w, d in zip(weights, dk_dtau, strict=True))
        return x_next, A, B


def linearize(sim, q=None, u=None):
    """(∂f/∂x, ∂f/∂τ) of the simulation at (q, u) (default: its current state)."""
    check_effort_mode(sim, "linearize")
    q, u = _state(sim, q, u)
    _, F_x, F_tau = Linearization(sim).rates(q, u)
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
    _, A, B = Linearization(sim).step(q, u, h, method)
    return A, B


def _state(sim, q, u):
    """(q, u) given (checked as `Simulation.set_state` checks them), else the current ones."""
    q = sim.q.copy() if q is None else sim._state_vector(q, sim.nq, "q", ANGLE)
    u = sim.u.copy() if u is None else sim._state_vector(u, sim.nu, "u", SPEED)
    return q, u
