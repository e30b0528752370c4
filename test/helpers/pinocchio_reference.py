"""An independent formulation of docs/model.md's robot with Pinocchio (PyPI ``pin``).

The robot is built as an ordinary tree multibody, with no knowledge of the Gibbs–Appell core:

- ``base``: a planar joint (Pinocchio's ``JointModelPlanar``: configuration ``(x, y, cos yaw,
  sin yaw)``, velocity ``(v_x, v_y, ω_z)`` expressed in the moving frame, i.e. in base_link; its
  origin is A). Body: mass M_pw at G = (d, 0, 0), rotational inertia I_pw·1 about G (only the
  yaw component matters for planar motion).
- two wheel spin joints, revolute about base_link +y at (0, −b, 0) (right) and (0, +b, 0) (left),
  massless bodies with inertia I_w about the spin axis only (their mass and yaw inertia are part
  of M_pw, I_pw). With spin axis +y a positive wheel rate rolls the robot forward:
  v_contact = v x + θ̇ y × (−r z) = (v − r θ̇) x = 0.
- per arm link k: a massless revolute joint about z (placement R0_k, translated by the mount
  for k = 1, at the distal end of rod k−1 for k > 1), then a prismatic joint along x carrying
  rod k. The rod body's frame origin is the rod's distal end (η = l_k), so the prismatic
  coordinate is l_k and the rod occupies x ∈ [−L_k, 0] in its own frame: a uniform slender rod of
  mass μ L centred at (−L/2, 0, 0), plus the cross-section inertia J·L about that centre.
- the payload: a point mass at the distal end of the last rod.

The pseudo-velocities u map to the full velocity by a constant matrix,
``v_full = S u = (v, 0, ω, (v + bω)/r, (v − bω)/r, q̇_1, l̇_1, …)``, and
``M = Sᵀ M_full S``, ``h = Sᵀ h_full(q_full, S u)``.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from mobile_manip_sim.scene.coordinates import ARM_Q, ARM_U, JOINTS, YAW, X, Y


def _rod_inertia(length: float, mass_per_length: float, J: np.ndarray) -> pin.Inertia:
    """Uniform slender rod on x ∈ [−L, 0] plus the cross-section inertia J·L about its centre."""
    mass = mass_per_length * length
    bending = mass * length ** 2 / 12.0
    about_com = np.diag([0.0, bending, bending]) + np.asarray(J, dtype=float) * length
    return pin.Inertia(mass, np.array([-0.5 * length, 0.0, 0.0]), about_com)


class ProjectedModel:
    """The Pinocchio multibody plus the constant map S from u to v_full."""

    def __init__(self, robot_model, gravity: float, tip_mass: float = 0.0,
                 wheel_inertia: bool = True):
        self.robot_model = robot_model
        base = robot_model.base
        n = robot_model.n_links
        self.n_links = n
        model = pin.Model()
        model.gravity = pin.Motion(np.array([0.0, 0.0, -float(gravity)]), np.zeros(3))

        # Base: planar joint at A; body = base + wheels (mass at G, yaw inertia about G).
        base_joint = model.addJoint(0, pin.JointModelPlanar(), pin.SE3.Identity(), "base")
        model.appendBodyToJoint(
            base_joint,
            pin.Inertia(base.mass, np.array([base.com_offset, 0.0, 0.0]),
                        base.yaw_inertia * np.eye(3)),
            pin.SE3.Identity())

        # Wheels: spin about +y, right at y = −b, left at y = +b.
        I_w = base.wheel_inertia if wheel_inertia else 0.0
        for name, side in (("right_wheel", -1.0), ("left_wheel", 1.0)):
            wheel = model.addJoint(base_joint, pin.JointModelRY(),
                                   pin.SE3(np.eye(3), np.array([0.0, side * base.half_track, 0.0])),
                                   name)
            model.appendBodyToJoint(wheel, pin.Inertia(0.0, np.zeros(3), np.diag([0.0, I_w, 0.0])),
                                    pin.SE3.Identity())

        # Arm: revolute (massless) → prismatic (rod, frame at the distal end).
        parent = base_joint
        for k in range(n):
            R0 = np.array(robot_model.joint_rotation[k], dtype=float)
            placement = pin.SE3(R0, np.array(robot_model.mount, dtype=float) if k == 0
                                else np.zeros(3))
            revolute = model.addJoint(parent, pin.JointModelRZ(), placement,
                                      f"arm_revolute_{k + 1}")
            prismatic = model.addJoint(revolute, pin.JointModelPX(), pin.SE3.Identity(),
                                       f"arm_prismatic_{k + 1}")
            inertia = _rod_inertia(float(robot_model.length[k]),
                                   float(robot_model.mass_per_length[k]),
                                   np.array(robot_model.inertia_per_length[k]))
            if k == n - 1 and tip_mass > 0.0:
                inertia = inertia + pin.Inertia(float(tip_mass), np.zeros(3), np.zeros((3, 3)))
            model.appendBodyToJoint(prismatic, inertia, pin.SE3.Identity())
            parent = prismatic

        # The tip: distal end of the last rod (O_1, the mount point, when there is no arm).
        tip_placement = pin.SE3.Identity() if n else pin.SE3(np.eye(3), np.array(robot_model.mount,
                                                                                 dtype=float))
        self.tip_frame = model.addFrame(pin.Frame("tip", parent, 0, tip_placement,
                                                  pin.FrameType.OP_FRAME))
        if n == 0 and tip_mass > 0.0:
            model.appendBodyToJoint(base_joint,
                                    pin.Inertia(float(tip_mass), np.zeros(3), np.zeros((3, 3))),
                                    tip_placement)

        self.model = model
        self.data = model.createData()
        assert model.nq == 6 + 2 * n and model.nv == 5 + 2 * n

        r, b = base.wheel_radius, base.half_track
        S = np.zeros((model.nv, robot_model.n_u))
        S[0, 0] = 1.0                        # v_x (base_link) = v
        S[2, 1] = 1.0                        # ω_z = ω
        S[3, 0], S[3, 1] = 1.0 / r, b / r    # θ̇_R = (v + bω)/r
        S[4, 0], S[4, 1] = 1.0 / r, -b / r   # θ̇_L = (v − bω)/r
        S[ARM_Q.start:, ARM_U] = np.eye(2 * n)   # the arm: the same coordinates in both
        self.S = S

    def full_configuration(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        return np.concatenate([[q[X], q[Y], np.cos(q[YAW]), np.sin(q[YAW])], q[JOINTS]])

    def full_velocity(self, u) -> np.ndarray:
        return self.S @ np.asarray(u, dtype=float)

    def full_mass_matrix(self, q) -> np.ndarray:
        M = pin.crba(self.model, self.data, self.full_configuration(q)).copy()
        return np.triu(M) + np.triu(M, 1).T

    def mass_matrix(self, q) -> np.ndarray:
        return self.S.T @ self.full_mass_matrix(q) @ self.S

    def bias(self, q, u) -> np.ndarray:
        h_full = pin.rnea(self.model, self.data, self.full_configuration(q), self.full_velocity(u),
                          np.zeros(self.model.nv))
        return self.S.T @ h_full

    def inverse_dynamics(self, q, u, ud) -> np.ndarray:
        """Sᵀ τ_full(q, S u, S u̇) (S is constant, so a_full = S u̇)."""
        tau = pin.rnea(self.model, self.data, self.full_configuration(q), self.full_velocity(u),
                       self.full_velocity(ud))
        return self.S.T @ tau

    def tip_position(self, q) -> np.ndarray:
        pin.framesForwardKinematics(self.model, self.data, self.full_configuration(q))
        return self.data.oMf[self.tip_frame].translation.copy()

    def kinetic_energy(self, q, u) -> float:
        return float(pin.computeKineticEnergy(self.model, self.data, self.full_configuration(q),
                                              self.full_velocity(u)))

    def potential_energy(self, q) -> float:
        return float(pin.computePotentialEnergy(self.model, self.data, self.full_configuration(q)))


def build_projected_model(robot_model, gravity: float, tip_mass: float = 0.0,
                          wheel_inertia: bool = True) -> ProjectedModel:
    """The Pinocchio reference for `robot_model`: `.mass_matrix(q)`, `.bias(q, u)`, …"""
    return ProjectedModel(robot_model, gravity, tip_mass, wheel_inertia)
