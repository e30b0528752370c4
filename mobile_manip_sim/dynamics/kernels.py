"""The recursive Gibbs–Appell dynamics of docs/model.md, as compiled kernels.

Notation follows docs/model.md, with links numbered 1..n and index 0 for the base:
``q = (x, y, yaw, θ_R, θ_L, q_1, l_1, …, q_n, l_n)``, ``u = (v, ω, q̇_1, l̇_1, …)``.

The kernels take the model record ``model`` (`records.Model`: base, mount, R0, L, mu, J,
tip_mass) and the workspace record ``ws`` of preallocated arrays (`records.Workspace`, where
every field's frame and shape is declared); the first six, all in the world frame `odom`:

- ``R[k]``  (n+1, 3, 3) orientation of joint frame k (R[0]: base_link);
- ``O[k]``  (n+2, 3) joint origins: O[0] = A, O[k] = O_k, O[n+1] = distal end of rod n (tip);
- ``x[k]``, ``z[k]`` (n+1, 3) frame axes (x[0]: base heading, z[0]: up);
- ``F[k]``, ``N[k]`` (n+2, 3) per-rod Gibbs–Appell force Σμ·a and moment about O_k
  (Σ η x × μ a + J α + ω × J ω); row n+1 holds the tip payload.

Nothing here allocates per call except what numba keeps in registers (tuples).
The forward dynamics in O(n) is in `articulated.py`.
"""
import math

from ..scene.coordinates import OMEGA, WHEEL_L, WHEEL_R, YAW, V, X, Y
from .indices import q_joint, q_slide, q_turn, u_slide, u_turn
from .jit import jit, jit_inline
from .spatial import inertia_times, sym_add
from .vec3 import add, axpy, cross, dot, matvec, put, row, scale, sub, tmatvec


@jit_inline
def frames(model, q, ws):
    """Position pass: R_k = R_{k−1} · R0_k · Rz(q_k), O_{k+1} = O_k + l_k x_k (docs/model.md
    frames)."""
    mount, R0 = model.mount, model.R0
    R, O, x, z = ws.R, ws.O, ws.x, ws.z
    n = R0.shape[0]
    c, s = math.cos(q[YAW]), math.sin(q[YAW])
    R[0, 0, 0], R[0, 0, 1], R[0, 0, 2] = c, -s, 0.0
    R[0, 1, 0], R[0, 1, 1], R[0, 1, 2] = s, c, 0.0
    R[0, 2, 0], R[0, 2, 1], R[0, 2, 2] = 0.0, 0.0, 1.0
    put(x, 0, (c, s, 0.0))
    put(z, 0, (0.0, 0.0, 1.0))
    put(O, 0, (q[X], q[Y], 0.0))
    put(O, 1, add(row(O, 0), matvec(R[0], (mount[0], mount[1], mount[2]))))
    for k in range(1, n + 1):
        cq, sq = math.cos(q[q_turn(k)]), math.sin(q[q_turn(k)])
        for i in range(3):
            # (R_{k−1} · R0_k) row i, then · Rz(q_k)
            a0 = (R[k - 1, i, 0] * R0[k - 1, 0, 0] + R[k - 1, i, 1] * R0[k - 1, 1, 0]
                  + R[k - 1, i, 2] * R0[k - 1, 2, 0])
            a1 = (R[k - 1, i, 0] * R0[k - 1, 0, 1] + R[k - 1, i, 1] * R0[k - 1, 1, 1]
                  + R[k - 1, i, 2] * R0[k - 1, 2, 1])
            a2 = (R[k - 1, i, 0] * R0[k - 1, 0, 2] + R[k - 1, i, 1] * R0[k - 1, 1, 2]
                  + R[k - 1, i, 2] * R0[k - 1, 2, 2])
            R[k, i, 0] = a0 * cq + a1 * sq
            R[k, i, 1] = -a0 * sq + a1 * cq
            R[k, i, 2] = a2
        put(x, k, (R[k, 0, 0], R[k, 1, 0], R[k, 2, 0]))
        put(z, k, (R[k, 0, 2], R[k, 1, 2], R[k, 2, 2]))
        put(O, k + 1, axpy(q[q_slide(k)], row(x, k), row(O, k)))


@jit_inline
def rod_moments(l, L):
    """∫η dη and ∫η² dη over the rod, η ∈ [l − L, l]."""
    s1 = L * (l - 0.5 * L)
    s2 = (l * l * l - (l - L) ** 3) / 3.0
    return s1, s2


@jit_inline
def cross_section_moment(Rk, Jk, Lk, alpha, omega):
    """L·(J α + ω × J ω) in the world frame, J (kg·m, link frame) per unit length."""
    ab = tmatvec(Rk, alpha)
    wb = tmatvec(Rk, omega)
    return scale(Lk, matvec(Rk, add(matvec(Jk, ab), cross(wb, matvec(Jk, wb)))))


@jit
def gibbs_appell(model, q, u, ud, g, ws, Q):
    """Inverse dynamics Q = ∂S/∂u̇ = M(q) u̇ + h(q, u), gravity g (m/s², along −z) included.

    Needs `frames(model, q, ws)` first. One outward pass (ω_k, α_k, a_{O_k}; rod forces F_k and
    moments N_k) and one inward pass (accumulated f, n projected on z_k, x_k, then the base).
    """
    base, L, mu, J, tip_mass = model.base, model.L, model.mu, model.J, model.tip_mass
    R, O, x, z, F, N = ws.R, ws.O, ws.x, ws.z, ws.F, ws.N
    n = L.shape[0]
    v, om, vd, omd = u[V], u[OMEGA], ud[V], ud[OMEGA]
    x0 = row(x, 0)
    y0 = (-x0[1], x0[0], 0.0)
    omega = (0.0, 0.0, om)
    alpha = (0.0, 0.0, omd)
    # a_A = v̇ x + v ω y, plus g z: gravity as an acceleration of the root (docs/model.md).
    a_A = axpy(vd, x0, scale(v * om, y0))
    a_A = (a_A[0], a_A[1], a_A[2] + g)
    m_w = sub(row(O, 1), row(O, 0))
    a_O = add(a_A, add(cross(alpha, m_w), cross(omega, cross(omega, m_w))))
    for k in range(1, n + 1):
        j, i = u_turn(k), u_slide(k)
        qd, ld, qdd, ldd = u[j], u[i], ud[j], ud[i]
        l, Lk, muk = q[q_slide(k)], L[k - 1], mu[k - 1]
        xk, zk = row(x, k), row(z, k)
        alpha = add(alpha, axpy(qdd, zk, cross(omega, scale(qd, zk))))
        omega = axpy(qd, zk, omega)
        # a(η) = b + η c along the rod (docs/model.md kinematics of a rod point)
        b = add(a_O, axpy(2.0 * ld, cross(omega, xk), scale(ldd, xk)))
        c = add(cross(alpha, xk), cross(omega, cross(omega, xk)))
        s1, s2 = rod_moments(l, Lk)
        put(F, k, scale(muk, axpy(Lk, b, scale(s1, c))))
        N_rod = scale(muk, axpy(s1, cross(xk, b), scale(s2, cross(xk, c))))
        put(N, k, add(N_rod, cross_section_moment(R[k], J[k - 1], Lk, alpha, omega)))
        a_O = axpy(l, c, b)
    put(F, n + 1, scale(tip_mass, a_O))
    put(N, n + 1, (0.0, 0.0, 0.0))
    f = row(F, n + 1)
    m = (0.0, 0.0, 0.0)  # moment about O_{k+1}
    for k in range(n, 0, -1):
        xk = row(x, k)
        m = add(add(row(N, k), m), cross(scale(q[q_slide(k)], xk), f))
        f = add(row(F, k), f)
        Q[u_turn(k)] = dot(row(z, k), m)
        Q[u_slide(k)] = dot(xk, f)
    m_A = add(m, cross(m_w, f))
    M_pw, I_pw, d = base.mass, base.yaw_inertia, base.com_offset
    r, half_track, I_w = base.wheel_radius, base.half_track, base.wheel_inertia
    wheels = 2.0 * I_w / (r * r)
    Q[V] = dot(x0, f) + M_pw * (vd - d * om * om) + wheels * vd
    Q[OMEGA] = m_A[2] + M_pw * d * (v * om + d * omd) + I_pw * omd + wheels * half_track ** 2 * omd


@jit_inline
def rod_inertia(model, q, ws, k):
    """Rigid-body inertia (m, h, I) of rod k (1 … n) about A (see `spatial.py`):
    ∫ over η ∈ [l_k − L_k, l_k] of μ_k at p = O_k + η x_k, plus L_k R J Rᵀ. Needs `frames`."""
    L, mu, J = model.L, model.mu, model.J
    R, O, x = ws.R, ws.O, ws.x
    Lk, muk = L[k - 1], mu[k - 1]
    s1, s2 = rod_moments(q[q_slide(k)], Lk)
    A = row(O, 0)
    r = sub(row(O, k), A)
    xk = row(x, k)
    m = muk * Lk
    h = scale(muk, axpy(Lk, r, scale(s1, xk)))
    rr, rx = dot(r, r), dot(r, xk)
    # μ [L (|r|² 1 − r rᵀ) + s1 (2 r·x 1 − r xᵀ − x rᵀ) + s2 (1 − x xᵀ)]
    a, b, c = muk * Lk, muk * s1, muk * s2
    diag = a * rr + 2.0 * b * rx + c
    Ixx = diag - a * r[0] * r[0] - 2.0 * b * r[0] * xk[0] - c * xk[0] * xk[0]
    Iyy = diag - a * r[1] * r[1] - 2.0 * b * r[1] * xk[1] - c * xk[1] * xk[1]
    Izz = diag - a * r[2] * r[2] - 2.0 * b * r[2] * xk[2] - c * xk[2] * xk[2]
    Ixy = -a * r[0] * r[1] - b * (r[0] * xk[1] + xk[0] * r[1]) - c * xk[0] * xk[1]
    Ixz = -a * r[0] * r[2] - b * (r[0] * xk[2] + xk[0] * r[2]) - c * xk[0] * xk[2]
    Iyz = -a * r[1] * r[2] - b * (r[1] * xk[2] + xk[1] * r[2]) - c * xk[1] * xk[2]
    # the cross-section: L R J Rᵀ, the same about any point
    Jk, Rk = J[k - 1], R[k]
    RJ = ((Rk[0, 0] * Jk[0, 0] + Rk[0, 1] * Jk[1, 0] + Rk[0, 2] * Jk[2, 0],
           Rk[0, 0] * Jk[0, 1] + Rk[0, 1] * Jk[1, 1] + Rk[0, 2] * Jk[2, 1],
           Rk[0, 0] * Jk[0, 2] + Rk[0, 1] * Jk[1, 2] + Rk[0, 2] * Jk[2, 2]),
          (Rk[1, 0] * Jk[0, 0] + Rk[1, 1] * Jk[1, 0] + Rk[1, 2] * Jk[2, 0],
           Rk[1, 0] * Jk[0, 1] + Rk[1, 1] * Jk[1, 1] + Rk[1, 2] * Jk[2, 1],
           Rk[1, 0] * Jk[0, 2] + Rk[1, 1] * Jk[1, 2] + Rk[1, 2] * Jk[2, 2]),
          (Rk[2, 0] * Jk[0, 0] + Rk[2, 1] * Jk[1, 0] + Rk[2, 2] * Jk[2, 0],
           Rk[2, 0] * Jk[0, 1] + Rk[2, 1] * Jk[1, 1] + Rk[2, 2] * Jk[2, 1],
           Rk[2, 0] * Jk[0, 2] + Rk[2, 1] * Jk[1, 2] + Rk[2, 2] * Jk[2, 2]))
    Ixx += Lk * (RJ[0][0] * Rk[0, 0] + RJ[0][1] * Rk[0, 1] + RJ[0][2] * Rk[0, 2])
    Iyy += Lk * (RJ[1][0] * Rk[1, 0] + RJ[1][1] * Rk[1, 1] + RJ[1][2] * Rk[1, 2])
    Izz += Lk * (RJ[2][0] * Rk[2, 0] + RJ[2][1] * Rk[2, 1] + RJ[2][2] * Rk[2, 2])
    Ixy += Lk * (RJ[0][0] * Rk[1, 0] + RJ[0][1] * Rk[1, 1] + RJ[0][2] * Rk[1, 2])
    Ixz += Lk * (RJ[0][0] * Rk[2, 0] + RJ[0][1] * Rk[2, 1] + RJ[0][2] * Rk[2, 2])
    Iyz += Lk * (RJ[1][0] * Rk[2, 0] + RJ[1][1] * Rk[2, 1] + RJ[1][2] * Rk[2, 2])
    return m, h, (Ixx, Iyy, Izz, Ixy, Ixz, Iyz)


@jit_inline
def payload_inertia(model, ws):
    """Rigid-body inertia (m, h, I) about A of the payload, a point mass at the tip O_{n+1}
    (carried by rod n, or by the base when n = 0). Needs `frames`."""
    m, O = model.tip_mass, ws.O
    t = sub(row(O, O.shape[0] - 1), row(O, 0))
    tt = dot(t, t)
    return m, scale(m, t), (m * (tt - t[0] * t[0]), m * (tt - t[1] * t[1]), m * (tt - t[2] * t[2]),
                            -m * t[0] * t[1], -m * t[0] * t[2], -m * t[1] * t[2])


@jit_inline
def motion_subspaces(ws):
    """S[k] (6 × 2, about A): columns (z_k, (O_k − A) × z_k) for q̇_k and (0, x_k) for l̇_k;
    S[0]: (0, x_0) for v and (z, 0) for ω (constant in base_link). Needs `frames`."""
    O, x, z, S = ws.O, ws.x, ws.z, ws.S
    n = S.shape[0] - 1
    A = row(O, 0)
    for i in range(6):
        S[0, i, 0] = 0.0
        S[0, i, 1] = 0.0
    S[0, 3, 0], S[0, 4, 0] = x[0, 0], x[0, 1]
    S[0, 2, 1] = 1.0
    for k in range(1, n + 1):
        zk = row(z, k)
        lin = cross(sub(row(O, k), A), zk)
        for i in range(3):
            S[k, i, 0] = zk[i]
            S[k, 3 + i, 0] = lin[i]
            S[k, i, 1] = 0.0
            S[k, 3 + i, 1] = x[k, i]


@jit
def mass_matrix(model, q, ws, zeros, unit, column, M):
    """M(q) by composite rigid bodies, O(n²) (`zeros`, `unit`, `column` are unused). Needs `frames`.

    The u̇-quadratic part of the Gibbs function is ½ Σ_b (S u̇)ᵀ I_b (S u̇) over the bodies, so
    M_ij = ∂²S/∂u̇_i∂u̇_j = s_iᵀ I^c_{max(i,j)} s_j, with I^c_k the composite inertia of rods
    k … n about A (one inward pass) and s_i the motion subspace columns about A; the base and
    wheels add their own terms to the (v, ω) block, as in `gibbs_appell`.
    """
    base = model.base
    S = ws.S
    n = S.shape[0] - 1
    motion_subspaces(ws)
    m_c, h_c, I_c = payload_inertia(model, ws)
    for k in range(n, 0, -1):
        m, h, I = rod_inertia(model, q, ws, k)
        m_c, h_c, I_c = m_c + m, add(h_c, h), sym_add(I_c, I)
        for c in range(2):
            # f = I^c_k s, then M[j, u_turn(k) + c] = s_jᵀ f for every column s_j at or before it
            w, v = (S[k, 0, c], S[k, 1, c], S[k, 2, c]), (S[k, 3, c], S[k, 4, c], S[k, 5, c])
            f_n, f_f = inertia_times(m_c, h_c, I_c, w, v)
            col = u_turn(k) + c
            for j in range(k + 1):
                for d in range(2 if j < k else c + 1):
                    value = (S[j, 0, d] * f_n[0] + S[j, 1, d] * f_n[1] + S[j, 2, d] * f_n[2]
                             + S[j, 3, d] * f_f[0] + S[j, 4, d] * f_f[1] + S[j, 5, d] * f_f[2])
                    M[u_turn(j) + d, col] = value
                    M[col, u_turn(j) + d] = value
    M_pw, I_pw, d = base.mass, base.yaw_inertia, base.com_offset
    r, half_track, I_w = base.wheel_radius, base.half_track, base.wheel_inertia
    wheels = 2.0 * I_w / (r * r)
    x0 = row(ws.x, 0)
    M[V, V] = m_c + M_pw + wheels
    M[V, OMEGA] = M[OMEGA, V] = dot(x0, cross((0.0, 0.0, 1.0), h_c))
    M[OMEGA, OMEGA] = I_c[2] + I_pw + M_pw * d * d + wheels * half_track ** 2


@jit
def mass_matrix_by_columns(model, q, ws, zeros, unit, column, M):
    """M(q) column by column: M e_k = gibbs_appell(q, u = 0, u̇ = e_k, g = 0), O(n²) by n_u
    inverse-dynamics passes. The baseline `mass_matrix` is checked against. Needs `frames`."""
    nu = M.shape[0]
    for k in range(nu):
        unit[:] = 0.0
        unit[k] = 1.0
        gibbs_appell(model, q, zeros, unit, 0.0, ws, column)
        for i in range(nu):
            M[i, k] = column[i]


@jit
def kinetic_energy(model, q, u, ws):
    """T = Σ ½∫μ|v|² + ½ ω·(J L) ω over rods, plus the base and wheels. Needs `frames`."""
    base, L, mu, J, tip_mass = model.base, model.L, model.mu, model.J, model.tip_mass
    R, O, x = ws.R, ws.O, ws.x
    n = L.shape[0]
    M_pw, I_pw, d = base.mass, base.yaw_inertia, base.com_offset
    r, half_track, I_w = base.wheel_radius, base.half_track, base.wheel_inertia
    v, om = u[V], u[OMEGA]
    T = 0.5 * M_pw * (v * v + d * d * om * om) + 0.5 * I_pw * om * om
    T += 0.5 * I_w * ((v + half_track * om) ** 2 + (v - half_track * om) ** 2) / (r * r)
    omega = (0.0, 0.0, om)
    v_O = add(scale(v, row(x, 0)), cross(omega, sub(row(O, 1), row(O, 0))))
    for k in range(1, n + 1):
        xk = row(x, k)
        omega = axpy(u[u_turn(k)], (R[k, 0, 2], R[k, 1, 2], R[k, 2, 2]), omega)
        l, Lk = q[q_slide(k)], L[k - 1]
        s1, s2 = rod_moments(l, Lk)
        b = axpy(u[u_slide(k)], xk, v_O)     # v(η) = b + η c
        c = cross(omega, xk)
        T += 0.5 * mu[k - 1] * (Lk * dot(b, b) + 2.0 * s1 * dot(b, c) + s2 * dot(c, c))
        wb = tmatvec(R[k], omega)
        T += 0.5 * Lk * dot(wb, matvec(J[k - 1], wb))
        v_O = axpy(l, c, b)
    return T + 0.5 * tip_mass * dot(v_O, v_O)


@jit
def potential_energy(model, q, g, ws):
    """V = g Σ μ ∫ z(η) dη + g m_tip z_tip (the base moves in the plane). Needs `frames`."""
    L, mu, tip_mass = model.L, model.mu, model.tip_mass
    O, x = ws.O, ws.x
    n = L.shape[0]
    V = 0.0
    for k in range(1, n + 1):
        s1, _ = rod_moments(q[q_slide(k)], L[k - 1])
        V += mu[k - 1] * (L[k - 1] * O[k, 2] + s1 * x[k, 2])
    return g * (V + tip_mass * O[n + 1, 2])


@jit_inline
def configuration_rate(model, q, u, qdot):
    """q̇ from u with the nonholonomic constraints built in: ẋ = v cos yaw, θ̇_R = (v + bω)/r, …"""
    r, half_track = model.base.wheel_radius, model.base.half_track
    v, om = u[V], u[OMEGA]
    qdot[X] = v * math.cos(q[YAW])
    qdot[Y] = v * math.sin(q[YAW])
    qdot[YAW] = om
    qdot[WHEEL_R] = (v + half_track * om) / r
    qdot[WHEEL_L] = (v - half_track * om) / r
    for j in range(u_turn(1), u.shape[0]):   # the arm
        qdot[q_joint(j)] = u[j]


@jit
def cholesky_solve(A, b, free, n_free, L, y):
    """Solve A[free, free] · y = b[free] in place (A symmetric positive definite).

    ``free[:n_free]`` lists the indices kept (locked degrees of freedom are left out);
    ``L`` is scratch of A's shape; its diagonal holds the reciprocal pivots (a multiply is
    several times cheaper than a divide). Raises nothing: a non-positive pivot yields NaN,
    which the engine reports.
    """
    for a in range(n_free):
        i = free[a]
        for c in range(a + 1):
            j = free[c]
            s = A[i, j]
            for k in range(c):
                s -= L[a, k] * L[c, k]
            if a == c:
                L[a, a] = 1.0 / math.sqrt(s) if s > 0.0 else math.nan
            else:
                L[a, c] = s * L[c, c]
    for a in range(n_free):
        s = b[free[a]]
        for k in range(a):
            s -= L[a, k] * y[k]
        y[a] = s * L[a, a]
    for a in range(n_free - 1, -1, -1):
        s = y[a]
        for k in range(a + 1, n_free):
            s -= L[k, a] * y[k]
        y[a] = s * L[a, a]
