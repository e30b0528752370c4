// The recursive Gibbs–Appell dynamics of docs/model.md, generic in the scalar S (scalar.hpp).
//
//   frames             position pass: R_k, O_k, x_k, z_k
//   inverse_dynamics   Q = M(q) u̇ + h(q, u): one outward, one inward pass, O(n)
//   mass_matrix        M(q) by composite rigid bodies, O(n²)
//   kinetic_energy, potential_energy, configuration_rate
//
// Every function takes the constant `Model` and a `Workspace<S>`; vectors are raw arrays in the
// coordinates' order (model.hpp). The articulated-body forward dynamics is in articulated.hpp.
// Each formula keeps the operation order of the reference implementation it replaces, so that
// double results are bit for bit the same and a lane bit for bit its run.
#pragma once

#include <array>

#include "model.hpp"
#include "scalar.hpp"
#include "vec3.hpp"

namespace mms {

// A symmetric 3×3 stored as (xx, yy, zz, xy, xz, yz).
template <class S> using Sym3 = std::array<S, 6>;

// Rigid-body inertia about A: mass (kg), first moment h = ∫(p − A) dm, rotational inertia I.
template <class S>
struct RigidInertia {
  S m;
  Vec3<S> h;
  Sym3<S> I;
};

template <class S>
inline Vec3<S> sym_matvec(const Sym3<S>& I, const Vec3<S>& w) {
  return {I[0] * w[0] + I[3] * w[1] + I[4] * w[2], I[3] * w[0] + I[1] * w[1] + I[5] * w[2],
          I[4] * w[0] + I[5] * w[1] + I[2] * w[2]};
}

// Momentum of the twist (w, v): (I w + h × v, m v − h × w)
template <class S>
inline void inertia_times(const RigidInertia<S>& b, const Vec3<S>& w, const Vec3<S>& v,
                          Vec3<S>& n, Vec3<S>& f) {
  n = add(sym_matvec(b.I, w), cross(b.h, v));
  f = sub(Vec3<S>{b.m * v[0], b.m * v[1], b.m * v[2]}, cross(b.h, w));
}

template <class S>
inline Vec3<S> column(const Mat3<S>& R, int c) { return {R[0][c], R[1][c], R[2][c]}; }

// Position pass: R_k = R_{k−1} · R0_k · Rz(q_k), O_{k+1} = O_k + l_k x_k (docs/model.md frames).
template <class S, class P>
void frames(const ModelOf<P>& model, const S* q, Workspace<S>& ws) {
  const int n = model.n();
  auto& R = ws.R;
  S c, s;
  sincos_(q[YAW], s, c);
  R[0] = {{{c, -s, S(0.0)}, {s, c, S(0.0)}, {S(0.0), S(0.0), S(1.0)}}};
  ws.x[0] = {c, s, S(0.0)};
  ws.z[0] = {S(0.0), S(0.0), S(1.0)};
  ws.O[0] = {q[X], q[Y], S(0.0)};
  Vec3<S> mount = {S(model.mount[0]), S(model.mount[1]), S(model.mount[2])};
  ws.O[1] = add(ws.O[0], matvec(R[0], mount));
  for (int k = 1; k <= n; ++k) {
    S cq, sq;
    sincos_(q[q_turn(k)], sq, cq);
    const Mat3<P>& R0 = model.R0[k - 1];
    for (int i = 0; i < 3; ++i) {  // (R_{k−1} · R0_k) row i, then · Rz(q_k)
      const auto& row = R[k - 1][i];
      S a0 = row[0] * R0[0][0] + row[1] * R0[1][0] + row[2] * R0[2][0];
      S a1 = row[0] * R0[0][1] + row[1] * R0[1][1] + row[2] * R0[2][1];
      S a2 = row[0] * R0[0][2] + row[1] * R0[1][2] + row[2] * R0[2][2];
      R[k][i][0] = a0 * cq + a1 * sq;
      R[k][i][1] = -a0 * sq + a1 * cq;
      R[k][i][2] = a2;
    }
    ws.x[k] = column(R[k], 0);
    ws.z[k] = column(R[k], 2);
    ws.O[k + 1] = axpy(q[q_slide(k)], ws.x[k], ws.O[k]);
  }
}

// ∫η dη and ∫η² dη over the rod, η ∈ [l − L, l]
template <class S, class P>
inline void rod_moments(const S& l, const P& L, S& s1, S& s2) {
  s1 = L * (l - 0.5 * L);
  S t = l - L;
  s2 = (l * l * l - t * (t * t)) / 3.0;
}

// L·(J α + ω × J ω) in the world frame, J (kg·m, link frame) per unit length
template <class S, class P>
inline Vec3<S> cross_section_moment(const Mat3<S>& Rk, const Mat3<P>& Jk, const P& Lk,
                                    const Vec3<S>& alpha, const Vec3<S>& omega) {
  Vec3<S> ab = tmatvec(Rk, alpha), wb = tmatvec(Rk, omega);
  return scale(Lk, matvec(Rk, add(matvec(Jk, ab), cross(wb, matvec(Jk, wb)))));
}

// Inverse dynamics Q = ∂S/∂u̇ = M(q) u̇ + h(q, u), gravity g (m/s², along −z) included: one
// outward pass (ω_k, α_k, a_{O_k}; rod forces F_k, moments N_k) and one inward pass (accumulated
// f, n projected on z_k, x_k, then the base). Needs `frames`.
template <class S, class P>
void inverse_dynamics(const ModelOf<P>& model, const S* q, const S* u, const S* ud, double g,
                      Workspace<S>& ws, S* Q) {
  const int n = model.n();
  const auto& base = model.base;
  S v = u[V], om = u[OMEGA], vd = ud[V], omd = ud[OMEGA];
  Vec3<S> x0 = ws.x[0];
  Vec3<S> y0 = {-x0[1], x0[0], S(0.0)};
  Vec3<S> omega = {S(0.0), S(0.0), om}, alpha = {S(0.0), S(0.0), omd};
  // a_A = v̇ x + v ω y, plus g z: gravity as an acceleration of the root (docs/model.md)
  Vec3<S> a_A = axpy(vd, x0, scale(v * om, y0));
  a_A[2] = a_A[2] + g;
  Vec3<S> m_w = sub(ws.O[1], ws.O[0]);
  Vec3<S> a_O = add(a_A, add(cross(alpha, m_w), cross(omega, cross(omega, m_w))));
  for (int k = 1; k <= n; ++k) {
    const S& qd = u[u_turn(k)];
    const S& ld = u[u_slide(k)];
    const S& qdd = ud[u_turn(k)];
    const S& ldd = ud[u_slide(k)];
    const S& l = q[q_slide(k)];
    P Lk = model.L[k - 1], muk = model.mu[k - 1];
    const Vec3<S>& xk = ws.x[k];
    const Vec3<S>& zk = ws.z[k];
    alpha = add(alpha, axpy(qdd, zk, cross(omega, scale(qd, zk))));
    omega = axpy(qd, zk, omega);
    // a(η) = b + η c along the rod (docs/model.md, kinematics of a rod point)
    Vec3<S> b = add(a_O, axpy(2.0 * ld, cross(omega, xk), scale(ldd, xk)));
    Vec3<S> c = add(cross(alpha, xk), cross(omega, cross(omega, xk)));
    S s1, s2;
    rod_moments(l, Lk, s1, s2);
    ws.F[k] = scale(muk, axpy(Lk, b, scale(s1, c)));
    Vec3<S> N_rod = scale(muk, axpy(s1, cross(xk, b), scale(s2, cross(xk, c))));
    ws.N[k] = add(N_rod, cross_section_moment(ws.R[k], model.J[k - 1], Lk, alpha, omega));
    a_O = axpy(l, c, b);
  }
  ws.F[n + 1] = scale(model.tip_mass, a_O);
  ws.N[n + 1] = zero3<S>();
  Vec3<S> f = ws.F[n + 1], m = zero3<S>();  // m: moment about O_{k+1}
  for (int k = n; k >= 1; --k) {
    const Vec3<S>& xk = ws.x[k];
    m = add(add(ws.N[k], m), cross(scale(q[q_slide(k)], xk), f));
    f = add(ws.F[k], f);
    Q[u_turn(k)] = dot(ws.z[k], m);
    Q[u_slide(k)] = dot(xk, f);
  }
  Vec3<S> m_A = add(m, cross(m_w, f));
  P M_pw = base.mass, I_pw = base.yaw_inertia, d = base.com_offset;
  P r = base.wheel_radius, b = base.half_track;
  P wheels = 2.0 * base.wheel_inertia / (r * r);
  Q[V] = dot(x0, f) + M_pw * (vd - d * om * om) + wheels * vd;
  Q[OMEGA] = m_A[2] + M_pw * d * (v * om + d * omd) + I_pw * omd + wheels * (b * b) * omd;
}

// Rigid-body inertia about A of rod k (1 … n): ∫ over η ∈ [l_k − L_k, l_k] of μ_k at
// p = O_k + η x_k, plus L_k R J Rᵀ. Needs `frames`.
template <class S, class P>
RigidInertia<S> rod_inertia(const ModelOf<P>& model, const S* q, const Workspace<S>& ws, int k) {
  P Lk = model.L[k - 1], muk = model.mu[k - 1];
  S s1, s2;
  rod_moments(q[q_slide(k)], Lk, s1, s2);
  Vec3<S> r = sub(ws.O[k], ws.O[0]);
  const Vec3<S>& xk = ws.x[k];
  RigidInertia<S> body;
  body.m = S(muk * Lk);
  body.h = scale(muk, axpy(Lk, r, scale(s1, xk)));
  S rr = dot(r, r), rx = dot(r, xk);
  // μ [L (|r|² 1 − r rᵀ) + s1 (2 r·x 1 − r xᵀ − x rᵀ) + s2 (1 − x xᵀ)]
  P a = muk * Lk;
  S b = muk * s1, c = muk * s2;
  S diag = a * rr + 2.0 * b * rx + c;
  auto& I = body.I;
  I[0] = diag - a * r[0] * r[0] - 2.0 * b * r[0] * xk[0] - c * xk[0] * xk[0];
  I[1] = diag - a * r[1] * r[1] - 2.0 * b * r[1] * xk[1] - c * xk[1] * xk[1];
  I[2] = diag - a * r[2] * r[2] - 2.0 * b * r[2] * xk[2] - c * xk[2] * xk[2];
  I[3] = -a * r[0] * r[1] - b * (r[0] * xk[1] + xk[0] * r[1]) - c * xk[0] * xk[1];
  I[4] = -a * r[0] * r[2] - b * (r[0] * xk[2] + xk[0] * r[2]) - c * xk[0] * xk[2];
  I[5] = -a * r[1] * r[2] - b * (r[1] * xk[2] + xk[1] * r[2]) - c * xk[1] * xk[2];
  // the cross-section: L R J Rᵀ, the same about any point
  const Mat3<P>& J = model.J[k - 1];
  const Mat3<S>& Rk = ws.R[k];
  Mat3<S> RJ;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) RJ[i][j] = Rk[i][0] * J[0][j] + Rk[i][1] * J[1][j] + Rk[i][2] * J[2][j];
  auto rowdot = [&](int i, int j) {
    return RJ[i][0] * Rk[j][0] + RJ[i][1] * Rk[j][1] + RJ[i][2] * Rk[j][2];
  };
  I[0] += Lk * rowdot(0, 0);
  I[1] += Lk * rowdot(1, 1);
  I[2] += Lk * rowdot(2, 2);
  I[3] += Lk * rowdot(0, 1);
  I[4] += Lk * rowdot(0, 2);
  I[5] += Lk * rowdot(1, 2);
  return body;
}

// Rigid-body inertia about A of the payload, a point mass at the tip O_{n+1}. Needs `frames`.
template <class S, class P>
RigidInertia<S> payload_inertia(const ModelOf<P>& model, const Workspace<S>& ws) {
  P m = model.tip_mass;
  Vec3<S> t = sub(ws.O[model.n() + 1], ws.O[0]);
  S tt = dot(t, t);
  return {S(m), scale(m, t),
          {m * (tt - t[0] * t[0]), m * (tt - t[1] * t[1]), m * (tt - t[2] * t[2]),
           -m * t[0] * t[1], -m * t[0] * t[2], -m * t[1] * t[2]}};
}

// Sk[k] (6 × 2, about A): (z_k, (O_k − A) × z_k) for q̇_k and (0, x_k) for l̇_k; Sk[0]:
// (0, x_0) for v and (z, 0) for ω (constant in base_link). Needs `frames`.
template <class S, class P>
void motion_subspaces(const ModelOf<P>& model, Workspace<S>& ws) {
  auto& Sk = ws.Sk;
  for (int c = 0; c < 2; ++c) Sk[0][c].fill(S(0.0));
  Sk[0][0][3] = ws.x[0][0];
  Sk[0][0][4] = ws.x[0][1];
  Sk[0][1][2] = S(1.0);
  for (int k = 1; k <= model.n(); ++k) {
    const Vec3<S>& zk = ws.z[k];
    Vec3<S> lin = cross(sub(ws.O[k], ws.O[0]), zk);
    for (int i = 0; i < 3; ++i) {
      Sk[k][0][i] = zk[i];
      Sk[k][0][3 + i] = lin[i];
      Sk[k][1][i] = S(0.0);
      Sk[k][1][3 + i] = ws.x[k][i];
    }
  }
}

// M(q) by composite rigid bodies, O(n²), into M (n_u × n_u, row-major). Needs `frames`.
// M_ij = s_iᵀ I^c_{max(i,j)} s_j, I^c_k the composite inertia of rods k … n about A; the base
// and wheels add their own terms to the (v, ω) block, as in `inverse_dynamics`.
template <class S, class P>
void mass_matrix(const ModelOf<P>& model, Workspace<S>& ws, const S* q, S* M) {
  const int n = model.n(), nu = model.n_u();
  const auto& Sk = ws.Sk;
  motion_subspaces(model, ws);
  RigidInertia<S> comp = payload_inertia(model, ws);
  for (int k = n; k >= 1; --k) {
    RigidInertia<S> body = rod_inertia(model, q, ws, k);
    comp.m = comp.m + body.m;
    comp.h = add(comp.h, body.h);
    for (int i = 0; i < 6; ++i) comp.I[i] = comp.I[i] + body.I[i];
    for (int c = 0; c < 2; ++c) {
      Vec3<S> w = {Sk[k][c][0], Sk[k][c][1], Sk[k][c][2]};
      Vec3<S> v = {Sk[k][c][3], Sk[k][c][4], Sk[k][c][5]};
      Vec3<S> f_n, f_f;
      inertia_times(comp, w, v, f_n, f_f);
      int col = u_turn(k) + c;
      for (int j = 0; j <= k; ++j) {
        for (int d = 0; d < (j < k ? 2 : c + 1); ++d) {
          const auto& s = Sk[j][d];
          S value = s[0] * f_n[0] + s[1] * f_n[1] + s[2] * f_n[2] + s[3] * f_f[0] +
                    s[4] * f_f[1] + s[5] * f_f[2];
          M[(u_turn(j) + d) * nu + col] = value;
          M[col * nu + u_turn(j) + d] = value;
        }
      }
    }
  }
  const auto& base = model.base;
  P M_pw = base.mass, I_pw = base.yaw_inertia, d = base.com_offset;
  P r = base.wheel_radius, b = base.half_track;
  P wheels = 2.0 * base.wheel_inertia / (r * r);
  const Vec3<S>& x0 = ws.x[0];
  M[V * nu + V] = comp.m + M_pw + wheels;
  M[V * nu + OMEGA] = M[OMEGA * nu + V] =
      dot(x0, cross(Vec3<S>{S(0.0), S(0.0), S(1.0)}, comp.h));
  M[OMEGA * nu + OMEGA] = comp.I[2] + I_pw + M_pw * d * d + wheels * (b * b);
}

// T = Σ ½∫μ|v|² + ½ ω·(J L) ω over rods, plus the base and wheels. Needs `frames`.
template <class S, class P>
S kinetic_energy(const ModelOf<P>& model, const S* q, const S* u, const Workspace<S>& ws) {
  const auto& base = model.base;
  P M_pw = base.mass, I_pw = base.yaw_inertia, d = base.com_offset;
  P r = base.wheel_radius, b = base.half_track, I_w = base.wheel_inertia;
  S v = u[V], om = u[OMEGA];
  S T = 0.5 * M_pw * (v * v + d * d * om * om) + 0.5 * I_pw * om * om;
  S right = v + b * om, left = v - b * om;
  T += 0.5 * I_w * (right * right + left * left) / (r * r);
  Vec3<S> omega = {S(0.0), S(0.0), om};
  Vec3<S> v_O = add(scale(v, ws.x[0]), cross(omega, sub(ws.O[1], ws.O[0])));
  for (int k = 1; k <= model.n(); ++k) {
    const Vec3<S>& xk = ws.x[k];
    omega = axpy(u[u_turn(k)], column(ws.R[k], 2), omega);
    const S& l = q[q_slide(k)];
    P Lk = model.L[k - 1];
    S s1, s2;
    rod_moments(l, Lk, s1, s2);
    Vec3<S> bv = axpy(u[u_slide(k)], xk, v_O);  // v(η) = b + η c
    Vec3<S> c = cross(omega, xk);
    T += 0.5 * model.mu[k - 1] * (Lk * dot(bv, bv) + 2.0 * s1 * dot(bv, c) + s2 * dot(c, c));
    Vec3<S> wb = tmatvec(ws.R[k], omega);
    T += 0.5 * Lk * dot(wb, matvec(model.J[k - 1], wb));
    v_O = axpy(l, c, bv);
  }
  return T + 0.5 * model.tip_mass * dot(v_O, v_O);
}

// V = g Σ μ ∫ z(η) dη + g m_tip z_tip (the base moves in the plane). Needs `frames`.
template <class S, class P>
S potential_energy(const ModelOf<P>& model, const S* q, double g, const Workspace<S>& ws) {
  const int n = model.n();
  S V_sum = S(0.0);
  for (int k = 1; k <= n; ++k) {
    S s1, s2;
    rod_moments(q[q_slide(k)], model.L[k - 1], s1, s2);
    V_sum += model.mu[k - 1] * (model.L[k - 1] * ws.O[k][2] + s1 * ws.x[k][2]);
  }
  return g * (V_sum + model.tip_mass * ws.O[n + 1][2]);
}

// q̇ from u with the nonholonomic constraints built in: ẋ = v cos yaw, θ̇_R = (v + bω)/r, …
template <class S, class P>
void configuration_rate(const ModelOf<P>& model, const S* q, const S* u, S* qdot) {
  P r = model.base.wheel_radius, b = model.base.half_track;
  S v = u[V], om = u[OMEGA];
  S c, s;
  sincos_(q[YAW], s, c);
  qdot[X] = v * c;
  qdot[Y] = v * s;
  qdot[YAW] = om;
  qdot[WHEEL_R] = (v + b * om) / r;
  qdot[WHEEL_L] = (v - b * om) / r;
  for (int j = u_turn(1); j < model.n_u(); ++j) qdot[j + 3] = u[j];
}

}  // namespace mms
