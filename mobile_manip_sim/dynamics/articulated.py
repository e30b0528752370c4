"""Forward dynamics in O(n): the articulated-body algorithm (Featherstone, *Rigid Body Dynamics
Algorithms*, §7.3; Pinocchio's ``aba.hxx``) for docs/model.md's chain.

Bodies and joints, spatial vectors in the world frame about A (see `spatial.py`), so that no
coordinate transform is ever needed:

- body k (1 … n) is rod k (the payload rides on rod n); its joint is the R-P pair, one 2-DoF
  joint with motion subspace ``S_k = [s_q, s_l]``: ``s_q = (z_k, (O_k − A) × z_k)``, the turn about
  z_k through O_k (fixed in the parent), and ``s_l = (0, x_k)``, the slide along the rod (fixed in
  rod k). Their rates: ``Ṡ_k u_k = v_{k−1} × s_q q̇_k + v_k × s_l l̇_k =: c_k``;
- the root is the base: 2 DoF (v, ω), ``S_0 = [(0, x_0), (z, 0)]``, constant in base_link, so
  ``c_0 = v_0 × v_0 = 0``; its own mass, yaw inertia and wheels enter as the 2×2 block of
  `kernels.gibbs_appell` (they never leave the plane);
- gravity is an upward acceleration ``(0, g z)`` of the root, as in `gibbs_appell`.

Three passes, each a short loop:

1. outward: ``v_k = v_{k−1} + S_k u_k`` and ``c_k``;
2. inward: ``I^A_k = I_k + I^a_{k+1}``, ``p^A_k = v_k ×* I_k v_k + p^a_{k+1}``;
   ``U = I^A S``, ``D = Sᵀ U``, ``u = Q_k − Sᵀ p^A``;
   ``I^a = I^A − U D⁻¹ Uᵀ``, ``p^a = p^A + I^a c_k + U D⁻¹ u`` go to the parent;
3. root: ``(D_base + S_0ᵀ I^A_0 S_0) u̇_0 = Q_0 − h_base − S_0ᵀ (I^A_0 a_g + p^A_0)``; then
   outward: ``u̇_k = D⁻¹ (u − Uᵀ (a_{k−1} + c_k))``, ``a_k = a_{k−1} + c_k + S_k u̇_k``.

A locked pseudo-velocity (a rod resting at its stop, a locked joint, a fixed base) has its
column of S set to zero and its pivot to one: the joint is rigid for accelerations, and its
u̇ comes out exactly zero; its velocity, if any, still enters the kinematics, as in the
Cholesky path (`kernels.mass_matrix` + `kernels.cholesky_solve`) this replaces.

The force a locked slide transmits comes with it: the force across joint k is
``f_k = I^A_k a_k + p^A_k`` (I^A_k, p^A_k before the downdate), and a locked slide carries its
component ``s_lᵀ f_k`` (``ws.slide_force[k]``, N), the generalized force M u̇ + h of that
pseudo-velocity. The stop holding a resting rod pushes with it minus the applied force
(`engine.system.slide_holding_forces`): no second, inverse-dynamics pass.
"""
from ..scene.coordinates import OMEGA, V
from .indices import u_slide, u_turn
from .jit import jit, jit_inline
from .kernels import frames, motion_subspaces, payload_inertia, rod_inertia
from .spatial import force_cross, inertia_times, motion_cross
from .vec3 import add, axpy, row, scale


@jit_inline
def add_body(IA, pA, m, h, I, V, k):
    """I^A += the rigid inertia (m, h, I); p^A += v ×* (I v), v = V[k] the body's twist."""
    IA[0, 0] += I[0]
    IA[1, 1] += I[1]
    IA[2, 2] += I[2]
    IA[0, 1] += I[3]
    IA[1, 0] += I[3]
    IA[0, 2] += I[4]
    IA[2, 0] += I[4]
    IA[1, 2] += I[5]
    IA[2, 1] += I[5]
    # [h×] above the diagonal, its transpose below
    IA[0, 4] -= h[2]
    IA[0, 5] += h[1]
    IA[1, 3] += h[2]
    IA[1, 5] -= h[0]
    IA[2, 3] -= h[1]
    IA[2, 4] += h[0]
    IA[4, 0] -= h[2]
    IA[5, 0] += h[1]
    IA[3, 1] += h[2]
    IA[5, 1] -= h[0]
    IA[3, 2] -= h[1]
    IA[4, 2] += h[0]
    IA[3, 3] += m
    IA[4, 4] += m
    IA[5, 5] += m
    w, v = (V[k, 0], V[k, 1], V[k, 2]), (V[k, 3], V[k, 4], V[k, 5])
    n, f = inertia_times(m, h, I, w, v)
    p_n, p_f = force_cross(w, v, n, f)
    for i in range(3):
        pA[i] += p_n[i]
        pA[3 + i] += p_f[i]


@jit_inline
def set_moving(free, moving):
    """moving[k] = 1.0 when pseudo-velocity k is in `free` (padded with −1), else 0.0."""
    for k in range(moving.shape[0]):
        moving[k] = 0.0
    for a in range(free.shape[0]):
        if free[a] < 0:
            break
        moving[free[a]] = 1.0


@jit_inline
def articulated_forward_dynamics(model, q, u, Q, g, free, ws, ud):
    """u̇ = M(q)⁻¹ (Q − h(q, u)) in O(n) (module doc), gravity g (m/s², along −z) included.

    ``Q`` (n_u) are the applied generalized forces (efforts, damping); ``free`` lists the free
    pseudo-velocities, padded with −1; locked ones get u̇ = 0. ``ud`` (n_u) receives u̇.
    Needs `kernels.frames(model, q, ws)`.
    """
    base = model.base
    Sk, Vk, Ck, Uk, Dinv, ua, IA, pA, moving, slide = (ws.S, ws.V, ws.C, ws.U, ws.D_inv, ws.u_art,
                                                       ws.I_art, ws.p_art, ws.moving, ws.slide)
    n = Sk.shape[0] - 1
    set_moving(free, moving)
    motion_subspaces(ws)

    # 1. outward: twists and velocity-product accelerations (all with the true velocities)
    x0 = row(ws.x, 0)
    w, v = (0.0, 0.0, u[OMEGA]), scale(u[V], x0)
    for i in range(3):
        Vk[0, i], Vk[0, 3 + i] = w[i], v[i]
    for k in range(1, n + 1):
        qd, ld = u[u_turn(k)], u[u_slide(k)]
        sq_w = (Sk[k, 0, 0] * qd, Sk[k, 1, 0] * qd, Sk[k, 2, 0] * qd)
        sq_v = (Sk[k, 3, 0] * qd, Sk[k, 4, 0] * qd, Sk[k, 5, 0] * qd)
        c_w, c_v = motion_cross(w, v, sq_w, sq_v)
        w, v = add(w, sq_w), add(v, sq_v)
        sl_v = (Sk[k, 3, 1] * ld, Sk[k, 4, 1] * ld, Sk[k, 5, 1] * ld)
        v = add(v, sl_v)
        c_v = add(c_v, motion_cross(w, v, (0.0, 0.0, 0.0), sl_v)[1])
        for i in range(3):
            Vk[k, i], Vk[k, 3 + i] = w[i], v[i]
            Ck[k, i], Ck[k, 3 + i] = c_w[i], c_v[i]
    for k in range(n + 1):  # locked columns out of the subspaces
        for c in range(2):
            if moving[u_turn(k) + c] == 0.0:
                for i in range(6):
                    Sk[k, i, c] = 0.0

    # 2. inward: articulated inertias and bias forces
    for i in range(6):
        pA[i] = 0.0
        for j in range(6):
            IA[i, j] = 0.0
    m, h, I = payload_inertia(model, ws)
    add_body(IA, pA, m, h, I, Vk, n)
    for k in range(n, 0, -1):
        m, h, I = rod_inertia(model, q, ws, k)
        add_body(IA, pA, m, h, I, Vk, k)
        # U = I^A S. The slide's s_l = (0, x_k) has no angular part: I^A s_l is U's slide column
        # when the slide moves; a locked one (column zero) transmits s_lᵀ f_k, f_k = I^A_k a_k +
        # p^A_k, so I^A s_l (= s_lᵀ I^A, symmetric) and s_lᵀ p^A are kept for the outward pass.
        x_k = (ws.x[k, 0], ws.x[k, 1], ws.x[k, 2])
        for i in range(6):
            s = 0.0
            for j in range(6):
                s += IA[i, j] * Sk[k, j, 0]
            Uk[k, i, 0] = s
            slide[k, i] = IA[i, 3] * x_k[0] + IA[i, 4] * x_k[1] + IA[i, 5] * x_k[2]
            Uk[k, i, 1] = slide[k, i] if moving[u_slide(k)] != 0.0 else 0.0
        slide[k, 6] = pA[3] * x_k[0] + pA[4] * x_k[1] + pA[5] * x_k[2]
        D00, D11, D01, u0, u1 = 0.0, 0.0, 0.0, Q[u_turn(k)], Q[u_slide(k)]
        for i in range(6):
            D00 += Sk[k, i, 0] * Uk[k, i, 0]
            D01 += Sk[k, i, 0] * Uk[k, i, 1]
            u0 -= Sk[k, i, 0] * pA[i]
        for i in range(3, 6):
            D11 += Sk[k, i, 1] * Uk[k, i, 1]
            u1 -= Sk[k, i, 1] * pA[i]
        if moving[u_turn(k)] == 0.0:
            D00, u0 = 1.0, 0.0
        if moving[u_slide(k)] == 0.0:
            D11, u1 = 1.0, 0.0
        det = D00 * D11 - D01 * D01
        d00, d11, d01 = D11 / det, D00 / det, -D01 / det
        Dinv[k, 0], Dinv[k, 1], Dinv[k, 2] = d00, d11, d01
        ua[k, 0], ua[k, 1] = u0, u1
        for i in range(6):  # I^a = I^A − U D⁻¹ Uᵀ, symmetric: the upper triangle, mirrored
            W0 = Uk[k, i, 0] * d00 + Uk[k, i, 1] * d01
            W1 = Uk[k, i, 0] * d01 + Uk[k, i, 1] * d11
            for j in range(i, 6):
                IA[i, j] -= W0 * Uk[k, j, 0] + W1 * Uk[k, j, 1]
                IA[j, i] = IA[i, j]
        Dinv_u0 = d00 * u0 + d01 * u1
        Dinv_u1 = d01 * u0 + d11 * u1
        for i in range(6):  # p^a = p^A + I^a c + U D⁻¹ u
            s = Uk[k, i, 0] * Dinv_u0 + Uk[k, i, 1] * Dinv_u1
            for j in range(6):
                s += IA[i, j] * Ck[k, j]
            pA[i] += s

    # 3. the root: base (v, ω) with its own mass, yaw inertia and wheels
    M_pw, I_pw, d = base.mass, base.yaw_inertia, base.com_offset
    r, half_track, I_w = base.wheel_radius, base.half_track, base.wheel_inertia
    wheels = 2.0 * I_w / (r * r)
    vv, om = u[V], u[OMEGA]
    # S_0ᵀ I^A S_0 with s_v = (0, x_0), s_ω = (z, 0); a_g = (0, g z)
    K00 = M_pw + wheels
    K11 = I_pw + M_pw * d * d + wheels * half_track ** 2 + IA[2, 2]
    K01 = 0.0
    r0 = Q[V] + M_pw * d * om * om
    r1 = Q[OMEGA] - M_pw * d * vv * om - pA[2] - IA[2, 5] * g
    for i in range(3):
        K01 += x0[i] * IA[3 + i, 2]
        r0 -= x0[i] * (pA[3 + i] + IA[3 + i, 5] * g)
        for j in range(3):
            K00 += x0[i] * IA[3 + i, 3 + j] * x0[j]
    if moving[V] == 0.0:
        K00, K01, r0 = 1.0, 0.0, 0.0
    if moving[OMEGA] == 0.0:
        K11, K01, r1 = 1.0, 0.0, 0.0
    det = K00 * K11 - K01 * K01
    ud[V] = (K11 * r0 - K01 * r1) / det
    ud[OMEGA] = (K00 * r1 - K01 * r0) / det

    # outward: joint accelerations
    a_w = (0.0, 0.0, ud[OMEGA])
    a_v = axpy(ud[V], x0, (0.0, 0.0, g))
    for k in range(1, n + 1):
        a_w = add(a_w, (Ck[k, 0], Ck[k, 1], Ck[k, 2]))
        a_v = add(a_v, (Ck[k, 3], Ck[k, 4], Ck[k, 5]))
        b0, b1 = ua[k, 0], ua[k, 1]
        for i in range(3):
            b0 -= Uk[k, i, 0] * a_w[i] + Uk[k, 3 + i, 0] * a_v[i]
            b1 -= Uk[k, i, 1] * a_w[i] + Uk[k, 3 + i, 1] * a_v[i]
        qdd = Dinv[k, 0] * b0 + Dinv[k, 2] * b1
        ldd = Dinv[k, 2] * b0 + Dinv[k, 1] * b1
        ud[u_turn(k)], ud[u_slide(k)] = qdd, ldd
        a_w = add(a_w, scale(qdd, (Sk[k, 0, 0], Sk[k, 1, 0], Sk[k, 2, 0])))
        a_v = add(a_v, add(scale(qdd, (Sk[k, 3, 0], Sk[k, 4, 0], Sk[k, 5, 0])),
                           scale(ldd, (Sk[k, 3, 1], Sk[k, 4, 1], Sk[k, 5, 1]))))
        if moving[u_slide(k)] == 0.0:
            f = slide[k, 6]
            for i in range(3):
                f += slide[k, i] * a_w[i] + slide[k, 3 + i] * a_v[i]
            ws.slide_force[k] = f


@jit
def forward_dynamics(model, q, u, Q, g, free, ws, ud):
    """`kernels.frames` then `articulated_forward_dynamics`: one call from Python."""
    frames(model, q, ws)
    articulated_forward_dynamics(model, q, u, Q, g, free, ws, ud)
