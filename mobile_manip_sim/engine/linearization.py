"""Exact Jacobians of the simulated robot, by dual numbers through the compiled core.

Continuous time: ẋ = f(x, τ), x = (q, u) (n_q + n_u), τ = (τ_R, τ_L, τ_1, F_1, …) the commanded
wheel and joint efforts (n_u); f = (q̇(q, u), u̇), u̇ = M(q)⁻¹ (Q − h(q, u)) with
Q = B τ − c ⊙ u: B turns wheel torques into (Q_v, Q_ω) = ((τ_R + τ_L)/r, b (τ_R − τ_L)/r) and
passes the joint efforts on; c are the damping effect's coefficients. Pseudo-velocities that are
locked now (the scene's locked joints, rods resting at a stop) have u̇ ≡ 0: their rows are zero.
An effort held at its limit by the effort-limits effect has a zero column (the clamp is active).

One step: the exact derivative of the step map of each fixed-step method — the core's own step
(`core/include/mms/fixed_step.hpp`: euler, semi_implicit_euler, rk4) instantiated for dual
numbers, so that A and B are the derivatives of the very map the step computes. A step that holds
events — a rod reaching its stop (the impact, with its rebound or the rod coming to rest there), a
resting rod released — is differentiated through them (`core/include/mms/event_jacobians.hpp`):
the event time's dependence on the state (the saltation) and the impact law on the contact set the
step found are in A and B, which then equal the derivative of the step map wherever a perturbation
keeps the same events. `step_jacobians_many` differentiates the event-free step at each state.

With a controller driving the arm (position, velocity or joint_trajectory mode), a step's A and B
are those of the closed loop: x = (q, u, z), z the PID integrals (n_arm), and for sampled
controllers (controller.rate > 0) also the arm efforts they hold between updates (n_arm) — an
update due at the step's start is applied first, as the run applies it —; τ = (τ_R, τ_L), the
wheel efforts (the arm's efforts are its controller's). `reference_jacobian` gives ∂x⁺/∂r of
the held target r of position mode (the set-point q_ref) or velocity mode (q̇_ref, q_ref moving
with it from the command's instant).
"""
from __future__ import annotations

import numpy as np

from ..scene.errors import SimulationError, UserError
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


# the held targets whose derivatives `reference_jacobian` gives (core's TargetKind)
TARGETS = {"position": 1, "velocity": 2}


def check_effort_mode(sim, what: str, arm_controller: bool = False) -> None:
    """The Jacobians are of the robot driven by efforts (and, where `arm_controller`, of the arm
    driven by its controller): say so where a controller not differentiated drives it."""
    if sim.velocity_mode:
        raise UserError(what, "the base takes velocity commands (its wheel-speed loop is not "
                              "differentiated yet): give wheel efforts (set_efforts) first")
    if sim.arm_controller.active and not arm_controller:
        raise UserError(what, f"the arm is driven by its {sim.arm_controller.mode} controller: "
                              f"{what} is of the robot driven by efforts (step_jacobians gives "
                              f"the closed loop's)")


def moving_mask(sim) -> np.ndarray:
    """(n_u,) 1.0 for a free pseudo-velocity, 0.0 for one locked now."""
    moving = np.ones(sim.nu)
    moving[list(sim.system.locked)] = 0.0
    return moving


def efforts_in_force(sim, efforts):
    """(Q_cmd, B) of efforts τ = (τ_R, τ_L, τ_1, F_1, …) within the scene's limits, as
    `Simulation.set_efforts` applies them: the generalized forces, and ∂Q/∂τ with a zero column
    for each effort held at its limit."""
    B = effort_map(sim.model)
    limits = sim.effects.effort_limits
    efforts = sim.effects.saturate(efforts)
    if limits is not None:
        B[:, np.abs(efforts) >= limits] = 0.0
    Q = np.concatenate([sim.dynamics.wheel_forces(*efforts[:2]), efforts[2:]])
    return Q, B


def jacobians(sim, method: str, q, u, h: float = 0.0):
    """(value, ∂/∂x, ∂/∂τ) of the rates (method "") or of one step of `method`, at (q, u) with
    the simulation's efforts, damping and locks (module doc)."""
    _, B = efforts_in_force(sim, np.concatenate([sim.wheel_efforts, sim.joint_efforts]))
    s = np.concatenate([q, u, np.zeros(3)])
    return sim.dynamics.core.jacobians(method, s, float(h), sim.system.Q_cmd, B,
                                       sim.system.damping, moving_mask(sim), sim.dynamics.gravity)


def linearize(sim, q=None, u=None):
    """(∂f/∂x, ∂f/∂τ) of the simulation at (q, u) (default: its current state)."""
    check_effort_mode(sim, "linearize")
    q, u = _state(sim, q, u)
    _, F_x, F_tau = jacobians(sim, "", q, u)
    return F_x, F_tau


def _step_settings(sim, what: str, dt, arm_controller: bool = False) -> tuple[str, float]:
    """The run's method (one the core differentiates) and the step length (default the run's)."""
    check_effort_mode(sim, what, arm_controller)
    method = sim.settings.method
    if method not in DIFFERENTIATED:
        kind = "adaptive" if not METHODS[method].fixed_step else "not differentiated"
        raise UserError("integrator.method", f"{what} differentiates the steps of "
                                             f"{', '.join(DIFFERENTIATED)}; {method} is {kind}")
    h = sim.settings.dt if dt is None else float(dt)
    if not np.isfinite(h) or h <= 0.0:
        raise UserError("dt", f"must be a positive step in seconds, got {dt!r}")
    return method, h


def step_jacobians(sim, q=None, u=None, dt: float | None = None):
    """(A, B) = (∂x⁺/∂x, ∂x⁺/∂τ) of one step of the run's fixed-step method of length dt
    (default: the run's) from (q, u) (default: the current state) at the current time, with the
    run's efforts, locks, resting rods and controllers, through the events the step holds
    (module doc: x and τ of the closed loop where a controller drives the arm)."""
    A, B, _, _ = _step_jacobians(sim, "step_jacobians", q, u, dt)
    return A, B


def reference_jacobian(sim, q=None, u=None, dt: float | None = None) -> np.ndarray:
    """R = ∂x⁺/∂r (n_x × n_arm) of `step_jacobians`' step, r the target the arm controller holds:
    the position set-point of position mode, the velocity of velocity mode (module doc)."""
    mode = sim.arm_controller.mode
    if mode not in TARGETS:
        raise UserError("reference_jacobian", f"the arm is in {mode} mode: the derivative is "
                                              f"with respect to the held target of position or "
                                              f"velocity mode")
    return _step_jacobians(sim, "reference_jacobian", q, u, dt, TARGETS[mode])[2]


def _step_jacobians(sim, what: str, q, u, dt, target: int = 0):
    """(A, B, R, events): `step_jacobians`, `reference_jacobian` (None without a target), and
    how many events the step held (the compiled stepper's double run of the step finds them)."""
    controlled = sim.arm_controller.active
    method, h = _step_settings(sim, what, dt, arm_controller=True)
    q, u = _state(sim, q, u)
    _, B_tau = efforts_in_force(sim, np.concatenate([sim.wheel_efforts, sim.joint_efforts]))
    if controlled:
        B_tau = np.ascontiguousarray(B_tau[:, :2])
    s = sim.s.copy()
    s[:sim.nq], s[sim.nq:sim.nq + sim.nu] = q, u
    try:
        _, A, C, events = sim._stepper.step_jacobians(s, sim._clock, h, B_tau, target)
    except RuntimeError as error:
        raise SimulationError(f"t = {sim.t:.9g} s: {what}: the step from this state failed "
                              f"({error}); try a smaller dt") from None
    except ValueError as error:   # the core's invalid_argument: a step not on the update grid
        raise UserError("dt", str(error).removeprefix("h: ")) from None
    n_tau = B_tau.shape[1]
    return A, C[:, :n_tau], (C[:, n_tau:] if target else None), events


def step_jacobians_many(sim, q, u, efforts=None, dt: float | None = None):
    """(A, B) of one step at many states at once, for a trajectory's linearisation (an MPC's):
    q (m × n_q), u (m × n_u), efforts τ (m × n_u; default the simulation's at every state),
    with its damping and locks; A (m × n_x × n_x), B (m × n_x × n_u). One compiled loop."""
    method, h = _step_settings(sim, "step_jacobians_many", dt)
    q, u = np.atleast_2d(np.asarray(q, dtype=float)), np.atleast_2d(np.asarray(u, dtype=float))
    m = q.shape[0]
    for name, array, width in (("q", q, sim.nq), ("u", u, sim.nu)):
        if array.shape != (m, width) or not np.isfinite(array).all():
            raise UserError(name, f"expected {m} finite rows of {width} numbers, got shape "
                                  f"{array.shape}")
    if efforts is None:
        efforts = np.tile(np.concatenate([sim.wheel_efforts, sim.joint_efforts]), (m, 1))
    efforts = np.asarray(efforts, dtype=float)
    if efforts.shape != (m, sim.nu) or not np.isfinite(efforts).all():
        raise UserError("efforts", f"expected {m} finite rows of {sim.nu} numbers, got shape "
                                   f"{efforts.shape}")
    pairs = [efforts_in_force(sim, row) for row in efforts]
    Q_cmd, B_all = np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])
    s = np.hstack([q, u, np.zeros((m, 3))])
    moving = np.tile(moving_mask(sim), (m, 1))
    _, A, B = sim.dynamics.core.jacobians_many(method, s, h, Q_cmd, B_all, sim.system.damping,
                                               moving, sim.dynamics.gravity)
    return A, B


def jacobians_along(sim, t_end: float):
    """Advance the run to t_end step by step and return (t, A, B, event): the start time of every
    step (K), its (A, B) at the state it starts from (K × n_x × n_x, K × n_x × n_τ: the x and τ
    of `step_jacobians`, the closed loop's with an arm controller), and whether the step held an
    event (an impact, a rod coming to rest or leaving its stop) — A and B are then differentiated
    through it (module doc)."""
    method, h = _step_settings(sim, "jacobians_along", None, arm_controller=True)
    times, As, Bs, events = [], [], [], []
    k = int(round(sim.t / h))
    while (k + 1) * h <= t_end + 0.5 * h:
        A, B, _, held = _step_jacobians(sim, "jacobians_along", None, None, None)
        times.append(sim.t)
        sim.advance_to((k + 1) * h)
        As.append(A)
        Bs.append(B)
        events.append(held > 0)
        k += 1
    nx, n_tau = (As[0].shape[0], Bs[0].shape[1]) if As else (sim.nq + sim.nu, sim.nu)
    return (np.array(times), np.array(As).reshape(-1, nx, nx),
            np.array(Bs).reshape(-1, nx, n_tau), np.array(events, dtype=bool))


def _state(sim, q, u):
    """(q, u) given (checked as `Simulation.set_state` checks them), else the current ones."""
    q = sim.q.copy() if q is None else sim._state_vector(q, sim.nq, "q", ANGLE)
    u = sim.u.copy() if u is None else sim._state_vector(u, sim.nu, "u", SPEED)
    return q, u
