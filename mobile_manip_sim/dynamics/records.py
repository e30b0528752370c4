"""The records every kernel takes: ``model`` (`Model`, the robot's constants, shared and never
written) and ``ws`` (`Workspace`, one simulation's preallocated scratch).

Both are namedtuples, which numba compiles as records: ``model.base.wheel_radius`` and ``ws.S``
compile exactly like positional indices and read like the physics.

Workspace vectors are in the world frame `odom`, SI units; k = 0 is the base, k = 1 … n the arm
links. Spatial vectors are 6 numbers (angular part first), taken about A, the base's axle
midpoint at the current instant (see `spatial.py`).
"""
from collections import namedtuple

import numpy as np

from ..scene.coordinates import u_size

BaseParameters = namedtuple("BaseParameters", [
    "mass",           # M_pw, kg: base + wheels
    "yaw_inertia",    # I_pw, kg·m²: about the vertical through G
    "com_offset",     # d, m: from A forward to G
    "wheel_radius",   # r, m
    "half_track",     # b, m: from A to each wheel centre
    "wheel_inertia",  # I_w, kg·m²: spin inertia of one wheel (0.0 when the effect is off)
])

Model = namedtuple("Model", [
    "base",      # BaseParameters of the differential-drive base
    "mount",     # (3,) m: O_1 in base_link
    "R0",        # (n, 3, 3) R0_k: parent joint frame → joint frame k before Rz(q_k)
    "L",         # (n,) m: rod lengths L_k
    "mu",        # (n,) kg/m: rod mass per length μ_k
    "J",         # (n, 3, 3) kg·m: cross-section inertia per length J_k, link frame
    "tip_mass",  # kg: point payload at the distal end of rod n
])

Workspace = namedtuple("Workspace", [
    "R",        # (n+1, 3, 3) orientation of joint frame k (R[0]: base_link)
    "O",        # (n+2, 3) m: O[0] = A, O[k] = O_k, O[n+1] = tip (distal end of rod n)
    "x",        # (n+1, 3) x_k, the rod's axis (x[0]: base heading)
    "z",        # (n+1, 3) z_k, the joint's rotation axis (z[0]: up)
    "F",        # (n+2, 3) N: Gibbs–Appell rod force Σμa (row n+1: payload)
    "N",        # (n+2, 3) N·m: … and moment about O_k (Σ η x × μ a + J α + ω × J ω)
    "S",        # (n+1, 6, 2) motion subspace about A: pair k's columns (q̇_k, l̇_k); S[0]: (v, ω)
    "V",        # (n+1, 6) spatial velocity of rod k (V[0]: base)
    "C",        # (n+1, 6) velocity-product acceleration of pair k, Ṡ_k u_k
    "U",        # (n+1, 6, 2) I^A_k S_k, articulated inertia times subspace
    "D_inv",    # (n+1, 3) (S_kᵀ I^A_k S_k)⁻¹, symmetric 2×2 as (00, 11, 01)
    "u_art",    # (n+1, 2) Q_k − S_kᵀ p^A_k
    "I_art",    # (6, 6) articulated inertia of the subchain being accumulated
    "p_art",    # (6,) … and its bias force
    "moving",   # (2n+2,) 1.0 for a free pseudo-velocity, 0.0 for a locked one
    "slide",    # (n+1, 7) s_lᵀ I^A_k (6), then s_lᵀ p^A_k: what a locked slide transmits
    "slide_force",  # (n+1,) N: s_lᵀ (I^A_k a_k + p^A_k), the force a locked slide k transmits
])


def make_model(robot, tip_mass: float = 0.0, wheel_inertia: bool = True) -> Model:
    """The kernels' record of a `RobotModel`; ``wheel_inertia=False`` zeroes I_w."""
    b = robot.base
    base = BaseParameters(float(b.mass), float(b.yaw_inertia), float(b.com_offset),
                          float(b.wheel_radius), float(b.half_track),
                          float(b.wheel_inertia) if wheel_inertia else 0.0)
    return Model(base, np.array(robot.mount), np.array(robot.joint_rotation),
                 np.array(robot.length), np.array(robot.mass_per_length),
                 np.array(robot.inertia_per_length), float(tip_mass))


def make_workspace(n_links: int) -> Workspace:
    n = n_links
    return Workspace(
        R=np.zeros((n + 1, 3, 3)), O=np.zeros((n + 2, 3)), x=np.zeros((n + 1, 3)),
        z=np.zeros((n + 1, 3)), F=np.zeros((n + 2, 3)), N=np.zeros((n + 2, 3)),
        S=np.zeros((n + 1, 6, 2)), V=np.zeros((n + 1, 6)), C=np.zeros((n + 1, 6)),
        U=np.zeros((n + 1, 6, 2)), D_inv=np.zeros((n + 1, 3)), u_art=np.zeros((n + 1, 2)),
        I_art=np.zeros((6, 6)), p_art=np.zeros(6), moving=np.zeros(u_size(n)),
        slide=np.zeros((n + 1, 7)), slide_force=np.zeros(n + 1))
