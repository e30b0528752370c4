"""The right-hand side of the simulated ODE, assembled from the effects a scene turns on.

State vector ``s = (q, u, W)``: configuration (n_q), pseudo-velocities (n_u) and W, the work done
on the robot so far by commanded efforts and dissipation (J), so that the energy balance
``T + V − W = const`` (minus impact losses) can be checked on any run.

Generalized forces are kept by source, as in MODEL.md: ``Q_cmd`` (commanded efforts, already
saturated by `effort_limits`), ``Q_damp = −c ⊙ u`` (joint and wheel damping), and ``h`` (velocity
products, gravity). An effect that is off adds no stage: no damping pass, no payload term,
no locked-joint bookkeeping. ``counters`` counts the stages actually run (tests use it to prove
that an effect that is off costs nothing).
"""
from __future__ import annotations

import numpy as np

from ..dynamics import kernels
from ..dynamics.jit import jit

# counters[...] indices
RHS_EVALS, DAMPING_STAGE, REDUCED_SOLVE, CROSSING_CHECKS = 0, 1, 2, 3
N_COUNTERS = 4


@jit
def derivative(system, s, ds):
    """ds/dt for s = (q, u, W): q̇ from the constraints, u̇ = M⁻¹(Q_cmd + Q_damp − h), Ẇ = (Q_cmd + Q_damp)·u."""
    model, g, damping, free, Q_cmd, ws, scratch, counters = system
    n_free = system_n_free(system)
    nu = Q_cmd.shape[0]
    nq = nu + 3
    q = s[:nq]
    u = s[nq:nq + nu]
    zeros, unit, column, h, rhs, ud, M, L = scratch
    counters[RHS_EVALS] += 1
    kernels.frames(model, q, ws)
    kernels.configuration_rate(model, q, u, ds[:nq])
    kernels.gibbs_appell(model, q, u, zeros, g, ws, h)
    power = 0.0
    for k in range(nu):
        rhs[k] = Q_cmd[k] - h[k]
        power += Q_cmd[k] * u[k]
    if damping.shape[0] > 0:
        counters[DAMPING_STAGE] += 1
        for k in range(nu):
            rhs[k] -= damping[k] * u[k]
            power -= damping[k] * u[k] * u[k]
    kernels.mass_matrix(model, q, ws, zeros, unit, column, M)
    if n_free < nu:
        counters[REDUCED_SOLVE] += 1
    kernels.cholesky_solve(M, rhs, free, n_free, L, ud)
    for k in range(nu):
        ds[nq + k] = 0.0
    for a in range(n_free):
        ds[nq + free[a]] = ud[a]
    ds[nq + nu] = power


@jit
def system_n_free(system):
    """How many pseudo-velocities are free: `free` is padded with −1 after the last free index."""
    free = system[3]
    n = 0
    while n < free.shape[0] and free[n] >= 0:
        n += 1
    return n


@jit
def constraint_forces(system, s, out):
    """Generalized force each locked pseudo-velocity needs to stay locked: M u̇ + h − Q (per DOF).

    Call right after `derivative` at the same state (it reuses h, M and the solved u̇).
    """
    model, g, damping, free, Q_cmd, ws, scratch, counters = system
    zeros, unit, column, h, rhs, ud, M, L = scratch
    nu = Q_cmd.shape[0]
    nq = nu + 3
    u = s[nq:nq + nu]
    for k in range(nu):
        total = h[k] - Q_cmd[k]
        if damping.shape[0] > 0:
            total += damping[k] * u[k]
        out[k] = total
    n_free = system_n_free(system)
    for k in range(nu):
        for a in range(n_free):
            out[k] += M[k, free[a]] * ud[a]


class System:
    """Holds the compiled system tuple and the Python-side view of the effects."""

    def __init__(self, dynamics, damping: np.ndarray | None, locked: list[int]):
        self.dynamics = dynamics
        nu = dynamics.model.n_u
        self.Q_cmd = np.zeros(nu)
        self.damping = np.zeros(0) if damping is None else np.asarray(damping, dtype=float)
        self.free = np.full(nu, -1, dtype=np.int64)
        self.counters = np.zeros(N_COUNTERS, dtype=np.int64)
        self.scratch = (np.zeros(nu), np.zeros(nu), np.zeros(nu), np.zeros(nu), np.zeros(nu),
                        np.zeros(nu), np.zeros((nu, nu)), np.zeros((nu, nu)))
        self.permanently_locked = tuple(sorted(locked))
        self.set_locked(())
        self.forces = np.zeros(nu)

    def set_locked(self, extra: tuple) -> None:
        """Lock the scene's locked DOFs plus `extra` (rods resting at a stop)."""
        locked = set(self.permanently_locked) | set(extra)
        free = [k for k in range(len(self.Q_cmd)) if k not in locked]
        self.free[:] = -1
        self.free[:len(free)] = free
        self.locked = tuple(sorted(locked))
        self.tuple = (self.dynamics.model_arrays, self.dynamics.gravity, self.damping, self.free,
                      self.Q_cmd, self.dynamics.ws, self.scratch, self.counters)

    def derivative(self, s: np.ndarray) -> np.ndarray:
        ds = np.empty_like(s)
        derivative(self.tuple, s, ds)
        return ds

    def constraint_forces(self, s: np.ndarray) -> np.ndarray:
        """M u̇ + h − Q_cmd − Q_damp at s with the current locks (nonzero only on locked DOFs)."""
        ds = np.empty_like(s)
        derivative(self.tuple, s, ds)
        constraint_forces(self.tuple, s, self.forces)
        return self.forces.copy()
