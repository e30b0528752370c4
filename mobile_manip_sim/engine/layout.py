"""Where each quantity sits in the state vector ``s = (q, u, e, W)`` — the one place that knows.

``q = (x, y, yaw, θ_R, θ_L, q_1, l_1, …, q_n, l_n)`` (n_q = 2n + 5),
``u = (v, ω, q̇_1, l̇_1, …, q̇_n, l̇_n)`` (n_u = 2n + 2), ``e = (e_R, e_L)`` the wheel-speed
controller's error integrals, ``W`` the work of efforts and dissipation. Rods are 1-based
(k = 1 … n) as in docs/model.md.

Where each coordinate sits in q and in u is `coordinates.py`'s (the one owner); its index
functions are re-exported here, so an index of q is its index in s and an index j of u is
``n_q + j`` in s. This module owns the rest (the C++ core's `layout` in core/include/mms/
system.hpp reads s in the same layout).
"""
from ..scene import coordinates
from ..scene.coordinates import q_slide as q_slide
from ..scene.coordinates import q_turn as q_turn
from ..scene.coordinates import u_slide as u_slide
from ..scene.coordinates import u_turn as u_turn


def state_size(nu):
    return 2 * nu + 6


def ld(nq, k):
    """Index of l̇_k in s."""
    return nq + u_slide(k)


def controller(nq, nu):
    """Index of e_R in s (e_L follows)."""
    return nq + nu


def work(nq, nu):
    """Index of W in s."""
    return nq + nu + 2


# --- the arm controller's states (engine/arm_control.py), after W and only when the arm is
# driven by a controller (not in effort mode): z_1 … z_{n_arm}, the PID's error integrals
# (rad·s or m·s, n_arm = n_u − 2), then τ, the reference clock (s since the last arm command).

def arm_integrals(nq, nu):
    """Index of z_1 in s (z_2 … z_{n_arm} follow)."""
    return nq + nu + 3


def reference_clock(nq, nu):
    """Index of τ, the arm reference's clock, in s (the last entry)."""
    return arm_integrals(nq, nu) + coordinates.arm_width(nu)


def arm_state_size(nu):
    """Entries the arm controller adds to s: n_arm integrals and the clock."""
    return coordinates.arm_width(nu) + 1


def arm_q(j):
    """Index in s (and q) of arm joint j = 0 … n_arm − 1 (q_1, l_1, q_2, …)."""
    return q_turn(1) + j
