"""The dynamics core: no ROS, no I/O. Model + state → forces, accelerations, energy, kinematics.

`Dynamics` answers from the compiled core (`mobile_manip_sim.core`, C++ generic in its scalar):
this module only checks and converts arrays and names the calls.

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

from ..core import compiled_dynamics
from ..scene.coordinates import WHEEL_L, WHEEL_R, YAW, X, Y
from ..scene.model import RobotModel


class Dynamics:
    """One robot's dynamics with its own preallocated workspace (one per simulation/thread).

    ``tip_mass`` (kg) is a point payload at the distal end of the last rod;
    ``wheel_inertia=False`` treats the wheels' spin inertia as zero.
    """

    def __init__(self, model: RobotModel, gravity: float = 0.0, tip_mass: float = 0.0,
                 wheel_inertia: bool = True):
        self.model = model
        self.gravity = float(gravity)
        self.tip_mass, self.wheel_inertia = float(tip_mass), bool(wheel_inertia)
        self._core = None
        self._zeros = np.zeros(model.n_u)
        self._moving = np.ones(model.n_u)

    @property
    def core(self):
        """This robot's compiled dynamics (`mobile_manip_sim.core`), built on first use: it holds
        the workspaces of its evaluations, so each simulation (each batch lane) has its own."""
        if self._core is None:
            self._core = compiled_dynamics(self.model, self.tip_mass, self.wheel_inertia)
        return self._core

    def for_lane(self, robot: RobotModel) -> None:
        """Make a copy of a template's dynamics a batch lane's own: the lane's robot (the same
        but for the masses per length) and a compiled core of its own, built when first used."""
        self.model = robot
        self._core = None

    def inverse_dynamics(self, q, u, ud, gravity: float | None = None) -> np.ndarray:
        """Q = M(q) u̇ + h(q, u): the recursive Gibbs–Appell pass (docs/model.md ∂S/∂u̇_k = Q_k)."""
        g = self.gravity if gravity is None else gravity
        return self.core.inverse_dynamics(_vector(q), _vector(u), _vector(ud), float(g))

    def bias(self, q, u, gravity: float | None = None) -> np.ndarray:
        """h(q, u): velocity products and gravity."""
        return self.inverse_dynamics(q, u, self._zeros, gravity)

    def mass_matrix(self, q) -> np.ndarray:
        """M(q) by composite rigid bodies, O(n²)."""
        return self.core.mass_matrix(_vector(q))

    def forward_dynamics(self, q, u, Q, moving=None) -> np.ndarray:
        """u̇ = M(q)⁻¹ (Q − h(q, u)) by the articulated-body recursion, O(n); ``moving`` (n_u,
        1.0 free, 0.0 locked; all free by default) gives locked pseudo-velocities u̇ = 0."""
        moving = self._moving if moving is None else _vector(moving)
        return self.core.forward_dynamics(_vector(q), _vector(u), _vector(Q), self.gravity,
                                          moving)

    def forward_dynamics_by_cholesky(self, q, u, Q) -> np.ndarray:
        """The same u̇ from the mass matrix and the bias: M(q)⁻¹ (Q − h(q, u)), by Cholesky
        (NumPy's factor, two triangular solves): an independent path to the recursion's."""
        L = np.linalg.cholesky(self.mass_matrix(q))
        rhs = np.asarray(Q, dtype=float) - self.bias(q, u)
        return np.linalg.solve(L.T, np.linalg.solve(L, rhs))

    def energy(self, q, u) -> tuple[float, float]:
        """(T, V) in J: kinetic energy from the velocities, potential g Σ μ ∫ z dη."""
        return self.core.energy(_vector(q), _vector(u), self.gravity)

    def joint_origins(self, q) -> np.ndarray:
        """(n+2, 3) world positions: A, O_1 … O_n, then the tip (distal end of rod n)."""
        return self.core.joint_origins(_vector(q))

    def link_rotations(self, q) -> np.ndarray:
        """(n+1, 3, 3) world orientations: base_link, then joint frames 1 … n."""
        return self.core.link_rotations(_vector(q))

    def tip_position(self, q) -> np.ndarray:
        return self.joint_origins(q)[-1]

    def configuration_rate(self, q, u) -> np.ndarray:
        """q̇ from u (the nonholonomic constraints are built in)."""
        return self.core.configuration_rate(_vector(q), _vector(u))

    def wheel_forces(self, tau_R: float, tau_L: float) -> tuple[float, float]:
        """(Q_v, Q_ω) of wheel torques: ((τ_R + τ_L)/r, b (τ_R − τ_L)/r)."""
        r, b = self.model.base.wheel_radius, self.model.base.half_track
        return (tau_R + tau_L) / r, b * (tau_R - tau_L) / r


def _vector(values) -> np.ndarray:
    """A C-ordered float64 copy or view, as the compiled core takes its arrays."""
    return np.ascontiguousarray(values, dtype=float)


def constraint_residuals(model: RobotModel, q, qdot) -> tuple[float, float]:
    """docs/model.md's checks: no skid ẋ sin yaw − ẏ cos yaw, no slip
    ẋ cos yaw + ẏ sin yaw − r(θ̇_R + θ̇_L)/2."""
    s, c = np.sin(q[YAW]), np.cos(q[YAW])
    r = model.base.wheel_radius
    return (qdot[X] * s - qdot[Y] * c,
            qdot[X] * c + qdot[Y] * s - r * (qdot[WHEEL_R] + qdot[WHEEL_L]) / 2.0)
