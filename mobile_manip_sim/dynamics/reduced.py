"""Two passes of the Gibbs–Appell kernels that the arm controller's feed-forwards use (engine/
arm_control.py), each a reduced or repeated `kernels.gibbs_appell`:

- `gravity_efforts`: G(q) on the arm joints, the inverse dynamics at u = u̇ = 0 in closed form;
- `base_acceleration`: the base's (v̇*, ω̇*) that the base rows of the equations give when the arm
  follows a commanded acceleration, from two unit-acceleration passes.

Compiled to inline into the engine's right-hand side, as the kernels are.
"""
from . import kernels
from .indices import arm_slide, arm_turn, q_slide
from .jit import jit_inline


@jit_inline
def gravity_efforts(model, q, g, ws, out):
    """G(q) on the arm joints into out (n_arm): `kernels.gibbs_appell` at u = u̇ = 0, where
    ω = α = 0 and every point accelerates by g ẑ, so rod k's force is μ_k L_k g ẑ, its moment
    about O_k μ_k s1 g x_k × ẑ (s1 = ∫η dη), the payload's force m g ẑ; the inward pass keeps
    f vertical and m horizontal. Needs `kernels.frames`."""
    L, mu, x, z = model.L, model.mu, ws.x, ws.z
    f_z = model.tip_mass * g
    m_x, m_y = 0.0, 0.0
    for k in range(L.shape[0], 0, -1):
        l = q[q_slide(k)]
        s1, _ = kernels.rod_moments(l, L[k - 1])
        lever = mu[k - 1] * s1 * g + l * f_z   # N_k + l x_k × f, per unit of x_k × ẑ
        m_x += lever * x[k, 1]
        m_y -= lever * x[k, 0]
        f_z += mu[k - 1] * L[k - 1] * g
        out[arm_turn(k)] = z[k, 0] * m_x + z[k, 1] * m_y
        out[arm_slide(k)] = x[k, 2] * f_z


@jit_inline
def base_acceleration(model, ws, q, Qb0, Qb1, Q_id, unit, zero, col_v, col_w):
    """(v̇*, ω̇*): the base rows M_bb u̇_b = Q_b − (M_ba q̈* + h_b), with Q_id holding the inverse
    dynamics at u̇ = (0, 0, q̈*); the unit-base-acceleration columns M e_v, M e_ω are written into
    col_v, col_w (``unit`` and ``zero``: n_u scratch, zero all zeros); a locked base
    pseudo-velocity (ws.moving) has u̇ = 0."""
    moving = ws.moving
    if moving[0] == 0.0 and moving[1] == 0.0:
        return 0.0, 0.0
    for k in range(unit.shape[0]):
        unit[k] = 0.0
    unit[0] = 1.0
    kernels.gibbs_appell(model, q, zero, unit, 0.0, ws, col_v)
    unit[0], unit[1] = 0.0, 1.0
    kernels.gibbs_appell(model, q, zero, unit, 0.0, ws, col_w)
    K00, K01, K11 = col_v[0], col_w[0], col_w[1]
    r0, r1 = Qb0 - Q_id[0], Qb1 - Q_id[1]
    if moving[0] == 0.0:
        K00, K01, r0 = 1.0, 0.0, 0.0
    if moving[1] == 0.0:
        K11, K01, r1 = 1.0, 0.0, 0.0
    det = K00 * K11 - K01 * K01
    return (K11 * r0 - K01 * r1) / det, (K00 * r1 - K01 * r0) / det
