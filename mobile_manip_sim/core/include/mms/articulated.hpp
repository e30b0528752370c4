// Forward dynamics in O(n): the articulated-body algorithm (Featherstone, Rigid Body Dynamics
// Algorithms §7.3) for docs/model.md's chain, generic in the scalar S.
//
// Bodies and joints, spatial vectors in the world frame about A, so that no transform is needed:
// body k (1 … n) is rod k (the payload rides on rod n); its joint is the R-P pair, a 2-DoF joint
// with S_k = [s_q, s_l]: s_q = (z_k, (O_k − A) × z_k), s_l = (0, x_k); their rates
// Ṡ_k u_k = v_{k−1} × s_q q̇_k + v_k × s_l l̇_k =: c_k. The root is the base, 2 DoF (v, ω),
// S_0 = [(0, x_0), (z, 0)]; its own mass, yaw inertia and wheels enter as a 2×2 block. Gravity is
// an upward acceleration (0, g z) of the root.
//
//   1. outward: v_k = v_{k−1} + S_k u_k and c_k;
//   2. inward: I^A_k = I_k + I^a_{k+1}, p^A_k = v_k ×* I_k v_k + p^a_{k+1}; U = I^A S,
//      D = Sᵀ U, u = Q_k − Sᵀ p^A; I^a = I^A − U D⁻¹ Uᵀ, p^a = p^A + I^a c_k + U D⁻¹ u;
//   3. root: (D_base + S_0ᵀ I^A_0 S_0) u̇_0 = Q_0 − h_base − S_0ᵀ (I^A_0 a_g + p^A_0); then
//      outward: u̇_k = D⁻¹ (u − Uᵀ (a_{k−1} + c_k)), a_k = a_{k−1} + c_k + S_k u̇_k.
//
// A locked pseudo-velocity (ws.moving = 0: a rod resting at its stop, a locked joint, a fixed
// base) has its column of S set to zero and its pivot to one: u̇ comes out exactly zero. The
// force a slide transmits, s_lᵀ (I^A_k a_k + p^A_k), is left in ws.slide_force[k] (for a locked
// slide: what its stop must push with, beside the applied force).
#pragma once

#include "dynamics.hpp"

namespace mms {

template <class S> using Mat6 = std::array<std::array<S, 6>, 6>;

// I^A += the rigid inertia of a body; p^A += v ×* (I v), v = the body's twist
template <class S>
inline void add_body(Mat6<S>& IA, Spatial<S>& pA, const RigidInertia<S>& body,
                     const Spatial<S>& twist) {
  const auto& I = body.I;
  const auto& h = body.h;
  IA[0][0] += I[0];
  IA[1][1] += I[1];
  IA[2][2] += I[2];
  IA[0][1] += I[3];
  IA[1][0] += I[3];
  IA[0][2] += I[4];
  IA[2][0] += I[4];
  IA[1][2] += I[5];
  IA[2][1] += I[5];
  // [h×] above the diagonal, its transpose below
  IA[0][4] -= h[2];
  IA[0][5] += h[1];
  IA[1][3] += h[2];
  IA[1][5] -= h[0];
  IA[2][3] -= h[1];
  IA[2][4] += h[0];
  IA[4][0] -= h[2];
  IA[5][0] += h[1];
  IA[3][1] += h[2];
  IA[5][1] -= h[0];
  IA[3][2] -= h[1];
  IA[4][2] += h[0];
  IA[3][3] += body.m;
  IA[4][4] += body.m;
  IA[5][5] += body.m;
  Vec3<S> w = {twist[0], twist[1], twist[2]}, v = {twist[3], twist[4], twist[5]};
  Vec3<S> n, f;
  inertia_times(body, w, v, n, f);
  Vec3<S> p_n = add(cross(w, n), cross(v, f)), p_f = cross(w, f);  // (w, v) ×* (n, f)
  for (int i = 0; i < 3; ++i) {
    pA[i] += p_n[i];
    pA[3 + i] += p_f[i];
  }
}

// u̇ = M(q)⁻¹ (Q − h(q, u)) in O(n), gravity g (m/s², along −z) included. Q (n_u): applied
// generalized forces; ws.moving (n_u): 1 free, 0 locked (locked ones get u̇ = 0). Needs `frames`.
template <class S, class P>
void forward_dynamics(const ModelOf<P>& model, const S* q, const S* u, const S* Q, double g,
                      Workspace<S>& ws, S* ud) {
  const int n = model.n();
  auto& Sk = ws.Sk;
  auto& Uk = ws.Uk;
  auto& IA = ws.I_art;
  auto& pA = ws.p_art;
  const auto& moving = ws.moving;
  const S zero = S(0.0), one = S(1.0);
  motion_subspaces(model, ws);

  // 1. outward: twists and velocity-product accelerations (all with the true velocities)
  const Vec3<S> x0 = ws.x[0];
  Vec3<S> w = {zero, zero, u[OMEGA]}, v = scale(u[V], x0);
  for (int i = 0; i < 3; ++i) {
    ws.Vk[0][i] = w[i];
    ws.Vk[0][3 + i] = v[i];
  }
  for (int k = 1; k <= n; ++k) {
    const S& qd = u[u_turn(k)];
    const S& ld = u[u_slide(k)];
    Vec3<S> sq_w = {Sk[k][0][0] * qd, Sk[k][0][1] * qd, Sk[k][0][2] * qd};
    Vec3<S> sq_v = {Sk[k][0][3] * qd, Sk[k][0][4] * qd, Sk[k][0][5] * qd};
    Vec3<S> c_w = cross(w, sq_w), c_v = add(cross(w, sq_v), cross(v, sq_w));
    w = add(w, sq_w);
    v = add(v, sq_v);
    Vec3<S> sl_v = {Sk[k][1][3] * ld, Sk[k][1][4] * ld, Sk[k][1][5] * ld};
    v = add(v, sl_v);
    c_v = add(c_v, add(cross(w, sl_v), cross(v, zero3<S>())));
    for (int i = 0; i < 3; ++i) {
      ws.Vk[k][i] = w[i];
      ws.Vk[k][3 + i] = v[i];
      ws.Ck[k][i] = c_w[i];
      ws.Ck[k][3 + i] = c_v[i];
    }
  }
  for (int k = 0; k <= n; ++k)  // locked columns out of the subspaces
    for (int c = 0; c < 2; ++c) {
      auto locked = is_zero(moving[u_turn(k) + c]);
      for (int i = 0; i < 6; ++i) Sk[k][c][i] = select(locked, zero, Sk[k][c][i]);
    }

  // 2. inward: articulated inertias and bias forces
  for (int i = 0; i < 6; ++i) {
    pA[i] = zero;
    IA[i].fill(zero);
  }
  add_body(IA, pA, payload_inertia(model, ws), ws.Vk[n]);
  for (int k = n; k >= 1; --k) {
    add_body(IA, pA, rod_inertia(model, q, ws, k), ws.Vk[k]);
    // U = I^A S. A locked slide's column is zero; it transmits s_lᵀ f_k, f_k = I^A_k a_k +
    // p^A_k, so I^A s_l (= s_lᵀ I^A, symmetric) and s_lᵀ p^A are kept for the outward pass.
    const Vec3<S>& xk = ws.x[k];
    auto slide_locked = is_zero(moving[u_slide(k)]);
    auto turn_locked = is_zero(moving[u_turn(k)]);
    auto& slide = ws.slide[k];
    for (int i = 0; i < 6; ++i) {
      S s = zero;
      for (int j = 0; j < 6; ++j) s += IA[i][j] * Sk[k][0][j];
      Uk[k][0][i] = s;
      slide[i] = IA[i][3] * xk[0] + IA[i][4] * xk[1] + IA[i][5] * xk[2];
      Uk[k][1][i] = select(slide_locked, zero, slide[i]);
    }
    slide[6] = pA[3] * xk[0] + pA[4] * xk[1] + pA[5] * xk[2];
    S D00 = zero, D11 = zero, D01 = zero, u0 = Q[u_turn(k)], u1 = Q[u_slide(k)];
    for (int i = 0; i < 6; ++i) {
      D00 += Sk[k][0][i] * Uk[k][0][i];
      D01 += Sk[k][0][i] * Uk[k][1][i];
      u0 -= Sk[k][0][i] * pA[i];
    }
    for (int i = 3; i < 6; ++i) {
      D11 += Sk[k][1][i] * Uk[k][1][i];
      u1 -= Sk[k][1][i] * pA[i];
    }
    D00 = select(turn_locked, one, D00);
    u0 = select(turn_locked, zero, u0);
    D11 = select(slide_locked, one, D11);
    u1 = select(slide_locked, zero, u1);
    S det = D00 * D11 - D01 * D01;
    S d00 = D11 / det, d11 = D00 / det, d01 = -D01 / det;
    ws.D_inv[k] = {d00, d11, d01};
    ws.u_art[k] = {u0, u1};
    for (int i = 0; i < 6; ++i) {  // I^a = I^A − U D⁻¹ Uᵀ, symmetric: the upper triangle, mirrored
      S W0 = Uk[k][0][i] * d00 + Uk[k][1][i] * d01;
      S W1 = Uk[k][0][i] * d01 + Uk[k][1][i] * d11;
      for (int j = i; j < 6; ++j) {
        IA[i][j] -= W0 * Uk[k][0][j] + W1 * Uk[k][1][j];
        IA[j][i] = IA[i][j];
      }
    }
    S Dinv_u0 = d00 * u0 + d01 * u1;
    S Dinv_u1 = d01 * u0 + d11 * u1;
    for (int i = 0; i < 6; ++i) {  // p^a = p^A + I^a c + U D⁻¹ u
      S s = Uk[k][0][i] * Dinv_u0 + Uk[k][1][i] * Dinv_u1;
      for (int j = 0; j < 6; ++j) s += IA[i][j] * ws.Ck[k][j];
      pA[i] += s;
    }
  }

  // 3. the root: base (v, ω) with its own mass, yaw inertia and wheels
  const auto& base = model.base;
  P M_pw = base.mass, I_pw = base.yaw_inertia, d = base.com_offset;
  P r = base.wheel_radius, b = base.half_track;
  P wheels = 2.0 * base.wheel_inertia / (r * r);
  const S& vv = u[V];
  const S& om = u[OMEGA];
  // S_0ᵀ I^A S_0 with s_v = (0, x_0), s_ω = (z, 0); a_g = (0, g z)
  S K00 = S(M_pw + wheels);
  S K11 = I_pw + M_pw * d * d + wheels * (b * b) + IA[2][2];
  S K01 = zero;
  S r0 = Q[V] + M_pw * d * om * om;
  S r1 = Q[OMEGA] - M_pw * d * vv * om - pA[2] - IA[2][5] * g;
  for (int i = 0; i < 3; ++i) {
    K01 += x0[i] * IA[3 + i][2];
    r0 -= x0[i] * (pA[3 + i] + IA[3 + i][5] * g);
    for (int j = 0; j < 3; ++j) K00 += x0[i] * IA[3 + i][3 + j] * x0[j];
  }
  auto v_locked = is_zero(moving[V]);
  auto w_locked = is_zero(moving[OMEGA]);
  K00 = select(v_locked, one, K00);
  K01 = select(v_locked, zero, K01);
  r0 = select(v_locked, zero, r0);
  K11 = select(w_locked, one, K11);
  K01 = select(w_locked, zero, K01);
  r1 = select(w_locked, zero, r1);
  S det = K00 * K11 - K01 * K01;
  ud[V] = (K11 * r0 - K01 * r1) / det;
  ud[OMEGA] = (K00 * r1 - K01 * r0) / det;

  // outward: joint accelerations
  Vec3<S> a_w = {zero, zero, ud[OMEGA]};
  Vec3<S> a_v = axpy(ud[V], x0, Vec3<S>{zero, zero, S(g)});
  for (int k = 1; k <= n; ++k) {
    a_w = add(a_w, Vec3<S>{ws.Ck[k][0], ws.Ck[k][1], ws.Ck[k][2]});
    a_v = add(a_v, Vec3<S>{ws.Ck[k][3], ws.Ck[k][4], ws.Ck[k][5]});
    S b0 = ws.u_art[k][0], b1 = ws.u_art[k][1];
    for (int i = 0; i < 3; ++i) {
      b0 -= Uk[k][0][i] * a_w[i] + Uk[k][0][3 + i] * a_v[i];
      b1 -= Uk[k][1][i] * a_w[i] + Uk[k][1][3 + i] * a_v[i];
    }
    const auto& Di = ws.D_inv[k];
    S qdd = Di[0] * b0 + Di[2] * b1;
    S ldd = Di[2] * b0 + Di[1] * b1;
    ud[u_turn(k)] = qdd;
    ud[u_slide(k)] = ldd;
    a_w = add(a_w, scale(qdd, Vec3<S>{Sk[k][0][0], Sk[k][0][1], Sk[k][0][2]}));
    a_v = add(a_v, add(scale(qdd, Vec3<S>{Sk[k][0][3], Sk[k][0][4], Sk[k][0][5]}),
                       scale(ldd, Vec3<S>{Sk[k][1][3], Sk[k][1][4], Sk[k][1][5]})));
    const auto& slide = ws.slide[k];
    S f = slide[6];
    for (int i = 0; i < 3; ++i) f += slide[i] * a_w[i] + slide[3 + i] * a_v[i];
    ws.slide_force[k] = select(is_zero(moving[u_slide(k)]), f, ws.slide_force[k]);
  }
}

// Solve A[free, free] · y = b[free] (A symmetric positive definite, n × n row-major), by
// Cholesky; free[:n_free] lists the indices kept. L (n × n) is scratch; its diagonal holds the
// reciprocal pivots. A non-positive pivot yields NaN, which the engine reports.
template <class S>
void cholesky_solve(const S* A, int n, const S* b, const int* free, int n_free, S* L, S* y) {
  for (int a = 0; a < n_free; ++a) {
    int i = free[a];
    for (int c = 0; c <= a; ++c) {
      int j = free[c];
      S s = A[i * n + j];
      for (int k = 0; k < c; ++k) s -= L[a * n + k] * L[c * n + k];
      if (a == c)
        L[a * n + a] = select(is_positive(value(s)), 1.0 / sqrt_(s), S(NAN));
      else
        L[a * n + c] = s * L[c * n + c];
    }
  }
  for (int a = 0; a < n_free; ++a) {
    S s = b[free[a]];
    for (int k = 0; k < a; ++k) s -= L[a * n + k] * y[k];
    y[a] = s * L[a * n + a];
  }
  for (int a = n_free - 1; a >= 0; --a) {
    S s = y[a];
    for (int k = a + 1; k < n_free; ++k) s -= L[k * n + a] * y[k];
    y[a] = s * L[a * n + a];
  }
}

}  // namespace mms
