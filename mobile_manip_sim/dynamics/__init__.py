"""The dynamics core: no ROS, no I/O. Model + state → forces, accelerations, energy, kinematics.

    from mobile_manip_sim.dynamics import Dynamics
    dyn = Dynamics(model, gravity=10.0)
    Q = dyn.inverse_dynamics(q, u, ud)   # M(q) u̇ + h(q, u), gravity included
    ud = dyn.forward_dynamics(q, u, Q)   # u̇ = M⁻¹ (Q − h), articulated bodies, O(n)
    M = dyn.mass_matrix(q); h = dyn.bias(q, u)   # composite rigid bodies, O(n²)
    dyn.energy(q, u) -> (T, V)

Vectors follow docs/model.md: ``q = (x, y, yaw, θ_R, θ_L, q_1, l_1, …)`` (m, rad),
``u = (v, ω, q̇_1, l̇_1, …)`` (m/s, rad/s); generalized forces ``Q = (Q_v, Q_ω, τ_1, F_1, …)``
with ``Q_v = (τ_R + τ_L)/r`` and ``Q_ω = b (τ_R − τ_L)/r`` (see `wheel_forces`).
"""
from __future__ import annotations

import numpy as np

from ..scene.coordinates import WHEEL_L, WHEEL_R, YAW, X, Y
from ..scene.model import RobotModel
from . import articulated, kernels
from .records import make_model, make_workspace


class Dynamics:
    """One robot's dynamics with its own preallocated workspace (one per simulation/thread).

    ``tip_mass`` (kg) is a point payload at the distal end of the last rod;
    ``wheel_inertia=False`` treats the wheels' spin inertia as zero.
    """

    def __init__(self, model: RobotModel, gravity: float = 0.0, tip_mass: float = 0.0,
                 wheel_inertia: bool = True):
        self.model = model
        self.gravity = float(gravity)
        self.model_record = make_model(model, tip_mass, wheel_inertia)   # what the kernels take
        n, nu = model.n_links, model.n_u
        self.ws = make_workspace(n)
        self._zeros = np.zeros(nu)
        self._unit = np.zeros(nu)
        self._column = np.zeros(nu)
        self._cholesky = np.zeros((nu, nu))
        self._all = np.arange(nu)

    def _frames(self, q) -> None:
        kernels.frames(self.model_record, np.asarray(q, dtype=float), self.ws)

    def inverse_dynamics(self, q, u, ud, gravity: float | None = None) -> np.ndarray:
        """Q = M(q) u̇ + h(q, u): the recursive Gibbs–Appell pass (docs/model.md ∂S/∂u̇_k = Q_k)."""
        q = np.asarray(q, dtype=float)
        g = self.gravity if gravity is None else gravity
        Q = np.empty(self.model.n_u)
        kernels.frames(self.model_record, q, self.ws)
        kernels.gibbs_appell(self.model_record, q, np.asarray(u, dtype=float),
                             np.asarray(ud, dtype=float), g, self.ws, Q)
        return Q

    def bias(self, q, u, gravity: float | None = None) -> np.ndarray:
        """h(q, u): velocity products and gravity."""
        return self.inverse_dynamics(q, u, self._zeros, gravity)

    def mass_matrix(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        M = np.empty((self.model.n_u, self.model.n_u))
        kernels.frames(self.model_record, q, self.ws)
        kernels.mass_matrix(self.model_record, q, self.ws, self._zeros, self._unit, self._column, M)
        return M

    def forward_dynamics(self, q, u, Q) -> np.ndarray:
        """u̇ = M(q)⁻¹ (Q − h(q, u)) by the articulated-body recursion, O(n) (`articulated.py`)."""
        ud = np.empty(self.model.n_u)
        articulated.forward_dynamics(self.model_record, np.asarray(q, dtype=float),
                                     np.asarray(u, dtype=float), np.asarray(Q, dtype=float),
                                     self.gravity, self._all, self.ws, ud)
        return ud

    def forward_dynamics_by_cholesky(self, q, u, Q) -> np.ndarray:
        """The same u̇ from the mass matrix and the bias: M(q)⁻¹ (Q − h(q, u)), by Cholesky."""
        M = self.mass_matrix(q)
        rhs = np.asarray(Q, dtype=float) - self.bias(q, u)
        ud = np.empty(self.model.n_u)
        kernels.cholesky_solve(M, rhs, self._all, len(self._all), self._cholesky, ud)
        return ud

    def energy(self, q, u) -> tuple[float, float]:
        """(T, V) in J: kinetic energy from the velocities, potential g Σ μ ∫ z dη."""
        q = np.asarray(q, dtype=float)
        self._frames(q)
        T = kernels.kinetic_energy(self.model_record, q, np.asarray(u, dtype=float), self.ws)
        return T, kernels.potential_energy(self.model_record, q, self.gravity, self.ws)

    def joint_origins(self, q) -> np.ndarray:
        """(n+2, 3) world positions: A, O_1 … O_n, then the tip (distal end of rod n)."""
        self._frames(q)
        return self.ws.O.copy()

    def link_rotations(self, q) -> np.ndarray:
        """(n+1, 3, 3) world orientations: base_link, then joint frames 1 … n."""
        self._frames(q)
        return self.ws.R.copy()

    def tip_position(self, q) -> np.ndarray:
        return self.joint_origins(q)[-1]

    def configuration_rate(self, q, u) -> np.ndarray:
        """q̇ from u (the nonholonomic constraints are built in)."""
        qdot = np.empty(self.model.n_q)
        kernels.configuration_rate(self.model_record, np.asarray(q, float), np.asarray(u, float),
                                   qdot)
        return qdot

    def wheel_forces(self, tau_R: float, tau_L: float) -> tuple[float, float]:
        """(Q_v, Q_ω) of wheel torques: ((τ_R + τ_L)/r, b (τ_R − τ_L)/r)."""
        r, b = self.model.base.wheel_radius, self.model.base.half_track
        return (tau_R + tau_L) / r, b * (tau_R - tau_L) / r


def constraint_residuals(model: RobotModel, q, qdot) -> tuple[float, float]:
    """docs/model.md's checks: no skid ẋ sin yaw − ẏ cos yaw, no slip
    ẋ cos yaw + ẏ sin yaw − r(θ̇_R + θ̇_L)/2."""
    s, c = np.sin(q[YAW]), np.cos(q[YAW])
    r = model.base.wheel_radius
    return (qdot[X] * s - qdot[Y] * c,
            qdot[X] * c + qdot[Y] * s - r * (qdot[WHEEL_R] + qdot[WHEEL_L]) / 2.0)
