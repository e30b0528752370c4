"""The per-simulation scratch every kernel takes: ``ws``, a tuple of preallocated arrays.

One workspace per simulation (or thread); the model tuple is shared and never written. All
vectors are in the world frame `odom`, SI units; k = 0 is the base, k = 1 … n the arm links.
Spatial vectors are 6 numbers (angular part first), taken about A, the base's axle midpoint at
the current instant (see `spatial.py`).
"""
import numpy as np

# ws[...] indices
R, O, X, Z, F, N, S, V, C, U, D_INV, U_ART, I_ART, P_ART, MOVING = range(15)


def make_workspace(n_links: int) -> tuple:
    n = n_links
    return (
        np.zeros((n + 1, 3, 3)),  # R      orientation of joint frame k (R[0]: base_link)
        np.zeros((n + 2, 3)),     # O      O[0] = A, O[k] = O_k, O[n+1] = tip (distal end of rod n), m
        np.zeros((n + 1, 3)),     # X      x_k, the rod's axis (x[0]: base heading)
        np.zeros((n + 1, 3)),     # Z      z_k, the joint's rotation axis (z[0]: up)
        np.zeros((n + 2, 3)),     # F      Gibbs–Appell rod force Σμa, N (row n+1: payload)
        np.zeros((n + 2, 3)),     # N      … and moment about O_k, N·m
        np.zeros((n + 1, 6, 2)),  # S      motion subspace about A: pair k's columns (q̇_k, l̇_k); S[0]: (v, ω)
        np.zeros((n + 1, 6)),     # V      spatial velocity of rod k (V[0]: base)
        np.zeros((n + 1, 6)),     # C      velocity-product acceleration of pair k, Ṡ_k u_k
        np.zeros((n + 1, 6, 2)),  # U      I^A_k S_k, articulated inertia times subspace
        np.zeros((n + 1, 3)),     # D_INV  (S_kᵀ I^A_k S_k)⁻¹, symmetric 2×2 as (00, 11, 01)
        np.zeros((n + 1, 2)),     # U_ART  Q_k − S_kᵀ p^A_k
        np.zeros((6, 6)),         # I_ART  articulated inertia of the subchain being accumulated
        np.zeros(6),              # P_ART  … and its bias force
        np.zeros(2 * n + 2),      # MOVING 1.0 for a free pseudo-velocity, 0.0 for a locked one
    )
