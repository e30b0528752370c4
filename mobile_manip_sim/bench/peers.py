"""The peer: docs/model.md's projected Pinocchio model, driven from Python as a user would.

The robot as an ordinary multibody (planar base joint at A, two wheel spin joints, per link a
revolute then a prismatic joint carrying the rod), with the constant map S from u to the full
velocity: ``M = Sᵀ M_full S`` (``crba``), ``h = Sᵀ h_full(q, S u)`` (``rnea`` at zero
acceleration), ``u̇ = M⁻¹ (Q − h)`` (numpy). It is the same construction as the test reference
``test/helpers/pinocchio_reference.py``, kept separate so that the tests stay independent of the
package;
`agreement` checks both against our dynamics in every bench run.
"""
from __future__ import annotations

import numpy as np

from ..scene.coordinates import (
    ARM_Q,
    ARM_U,
    JOINTS,
    OMEGA,
    SLIDES_Q,
    WHEELS,
    YAW,
    V,
    X,
    Y,
    arm_size,
)

try:
    import pinocchio as pin
except ImportError:  # the bench reports the peer sections as skipped
    pin = None


def available() -> bool:
    return pin is not None


class ProjectedPinocchio:
    def __init__(self, robot_model, gravity: float, tip_mass: float = 0.0,
                 wheel_inertia: bool = True):
        base, n = robot_model.base, robot_model.n_links
        model = pin.Model()
        model.gravity = pin.Motion(np.array([0.0, 0.0, -float(gravity)]), np.zeros(3))
        root = model.addJoint(0, pin.JointModelPlanar(), pin.SE3.Identity(), "base")
        model.appendBodyToJoint(root, pin.Inertia(base.mass, np.array([base.com_offset, 0.0, 0.0]),
                                                  base.yaw_inertia * np.eye(3)), pin.SE3.Identity())
        I_w = base.wheel_inertia if wheel_inertia else 0.0
        for name, side in (("right_wheel", -1.0), ("left_wheel", 1.0)):
            wheel = model.addJoint(root, pin.JointModelRY(),
                                   pin.SE3(np.eye(3),
                                           np.array([0.0, side * base.half_track, 0.0])), name)
            model.appendBodyToJoint(wheel, pin.Inertia(0.0, np.zeros(3), np.diag([0.0, I_w, 0.0])),
                                    pin.SE3.Identity())
        parent = root
        for k in range(n):
            placement = pin.SE3(np.array(robot_model.joint_rotation[k], dtype=float),
                                np.array(robot_model.mount, dtype=float) if k == 0 else np.zeros(3))
            revolute = model.addJoint(parent, pin.JointModelRZ(), placement, f"revolute_{k + 1}")
            prismatic = model.addJoint(revolute, pin.JointModelPX(), pin.SE3.Identity(),
                                       f"prismatic_{k + 1}")
            L, mu = float(robot_model.length[k]), float(robot_model.mass_per_length[k])
            about_com = (np.diag([0.0, 1.0, 1.0]) * mu * L ** 3 / 12.0
                         + np.array(robot_model.inertia_per_length[k]) * L)
            inertia = pin.Inertia(mu * L, np.array([-0.5 * L, 0.0, 0.0]), about_com)
            if k == n - 1 and tip_mass > 0.0:
                inertia = inertia + pin.Inertia(float(tip_mass), np.zeros(3), np.zeros((3, 3)))
            model.appendBodyToJoint(prismatic, inertia, pin.SE3.Identity())
            parent = prismatic
        self.model, self.data = model, model.createData()
        r, b = base.wheel_radius, base.half_track
        S = np.zeros((model.nv, robot_model.n_u))
        S[0, 0], S[2, 1] = 1.0, 1.0
        S[3, 0], S[3, 1] = 1.0 / r, b / r
        S[4, 0], S[4, 1] = 1.0 / r, -b / r
        S[ARM_Q.start:, ARM_U] = np.eye(arm_size(n))   # the arm: the same coordinates in both
        self.S, self.St = S, S.T.copy()
        self.nq, self.nu, self.r, self.b = robot_model.n_q, robot_model.n_u, r, b
        self._zero = np.zeros(model.nv)
        self._q_full = np.zeros(model.nq)

    def full_configuration(self, q) -> np.ndarray:
        qf = self._q_full
        qf[0], qf[1], qf[2], qf[3] = q[X], q[Y], np.cos(q[YAW]), np.sin(q[YAW])
        qf[4:] = q[JOINTS]
        return qf

    def mass_matrix_and_bias(self, q, u):
        """(M, h): crba + rnea + projection, from Python."""
        qf = self.full_configuration(q)
        M_full = pin.crba(self.model, self.data, qf)
        M_full = np.triu(M_full) + np.triu(M_full, 1).T
        h_full = pin.rnea(self.model, self.data, qf, self.S @ u, self._zero)
        return self.St @ M_full @ self.S, self.St @ h_full

    def forward_dynamics(self, q, u, Q) -> np.ndarray:
        """u̇ = M⁻¹ (Q − h): crba + rnea + projection + solve, all from Python."""
        M, h = self.mass_matrix_and_bias(q, u)
        return np.linalg.solve(M, Q - h)

    def crba_and_rnea(self, q, u) -> None:
        """The two Pinocchio calls alone (the peer's floor: no projection, no solve)."""
        qf = self.full_configuration(q)
        pin.crba(self.model, self.data, qf)
        pin.rnea(self.model, self.data, qf, self.S @ u, self._zero)

    def rhs(self, Q):
        """f(t, y) for SciPy's solve_ivp, y = (q, u): q̇ from the constraints, u̇ from above."""
        nq, r, b = self.nq, self.r, self.b

        def f(_t, y):
            q, u = y[:nq], y[nq:]
            qd = np.empty(nq)
            v, om = u[V], u[OMEGA]
            qd[X], qd[Y], qd[YAW] = v * np.cos(q[YAW]), v * np.sin(q[YAW]), om
            qd[WHEELS] = (v + b * om) / r, (v - b * om) / r
            qd[ARM_Q] = u[ARM_U]
            return np.concatenate([qd, self.forward_dynamics(q, u, Q)])
        return f


def agreement(dynamics, peer: ProjectedPinocchio, rng, trials: int = 20) -> float:
    """Largest relative difference of (M, h) between our dynamics and the peer on random states."""
    worst = 0.0
    n = dynamics.model.n_links
    for _ in range(trials):
        q = rng.normal(size=dynamics.model.n_q)
        q[SLIDES_Q] = rng.uniform(0.0, 1.0, n) * np.array(dynamics.model.length)
        u = rng.normal(size=dynamics.model.n_u)
        M, h = peer.mass_matrix_and_bias(q, u)
        worst = max(worst, np.abs(dynamics.mass_matrix(q) - M).max() / np.abs(M).max(),
                    np.abs(dynamics.bias(q, u) - h).max() / max(np.abs(h).max(), 1.0))
    return float(worst)
