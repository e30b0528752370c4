// The arm controller inside the right-hand side, generic in the scalar S: a PID per arm joint on
// a reference trajectory, with a model-based feed-forward (engine/arm_control.py and
// engine/arm_reference.py are the reference, operation for operation).
//
// Per arm joint j (revolute τ_j in N·m, prismatic F_j in N), the reference evaluated at the
// reference clock τ (a state component, τ̇ = 1):
//
//     e = q_ref − q   (the shortest angle on the revolute joints, which are continuous)
//     ė = q̇_ref − q̇,   ż = e
//     τ_j = sat(ff_j + kp e + kd ė + ki z)   within the effort limit of the joint
//
// z stops integrating while the output is saturated in the direction of the error
// (conditional integration). Feed-forward ff: none; gravity G(q) (the inverse dynamics at
// u = u̇ = 0, in closed form); computed torque M u̇* + h(q, u) − Q_damp with u̇* = (v̇*, ω̇*,
// q̈_ref), the base's (v̇*, ω̇*) solved from the base rows of the same equations. Both model-based
// feed-forwards compute with `ArmControl::model`: the plant's, or one whose masses, inertias and
// payload carry a model error.
//
// Sampled (`held` set): the efforts of the last update are held (ż = 0) and the update applies
// the law outside the right-hand side (stepping.hpp's `update_controllers`).
//
// State beyond (q, u, e, W): z_1 … z_{n_arm}, then τ; n_arm = n_u − 2.
#pragma once

#include <cmath>
#include <vector>

#include "dynamics.hpp"

namespace mms {

// arm[...] (engine/arm_control.py): on, the feed-forward's kind, segments in use, and the segment
// of the last evaluation (a search hint: the result does not depend on it)
enum ArmSetting { ARM_ON, ARM_FEEDFORWARD, ARM_SEGMENTS, ARM_SEGMENT };
enum Feedforward { FEEDFORWARD_NONE = 0, FEEDFORWARD_GRAVITY = 1, FEEDFORWARD_COMPUTED_TORQUE = 2 };
// rows of the evaluated reference and of the last evaluation's outputs (ArmControl::last)
enum ArmRow { Q_REF, QD_REF, QDD_REF, LAST_FF, LAST_TAU, ARM_ROWS };
// gains rows
enum Gain { GAIN_KP, GAIN_KI, GAIN_KD };
// a reference segment's coefficients: the polynomial's (degree ≤ 5), then the constants added to
// q̇_ref and q̈_ref (a trajectory's last point held)
constexpr int REF_COEFFS = 6, HELD_QD = 6, HELD_QDD = 7, REF_WIDTH = 8;

inline int arm_integrals_index(const Model& m) { return m.n_q() + m.n_u() + 3; }
inline int reference_clock_index(const Model& m) { return arm_integrals_index(m) + m.n_u() - 2; }
// entries of s with the controller's states: (q, u, e, W), then z (n_arm) and τ
inline int arm_state_size(const Model& m) { return m.n_q() + m.n_u() + 3 + m.n_u() - 1; }

// The controller's settings and reference, the Python layer's arrays (engine/system.py's
// SystemData: arm, arm_gains, arm_limits, ref_starts, ref_coeffs, arm_ref).
struct ArmControl {
  double* settings = nullptr;       // (4) ArmSetting
  const double* gains = nullptr;    // (3 × n_arm) kp, ki, kd
  const double* limits = nullptr;   // (n_arm) N·m or N; inf where none
  const double* starts = nullptr;   // (segments) s: each segment's start on the clock τ
  const double* coeffs = nullptr;   // (segments × n_arm × REF_WIDTH)
  double* last = nullptr;           // (ARM_ROWS × n_arm) the last evaluation's reference, ff, τ
  const Model* model = nullptr;     // the feed-forward's model (the plant's, or a model error's)
  const double* held = nullptr;     // (n_u) sampled: the efforts of the last update (arm's from
                                    // index 2); nullptr: the law at every evaluation
  int feedforward() const { return int(settings[ARM_FEEDFORWARD]); }
};

// What a held reference's target is, for derivatives with respect to it: none, the position
// target of position mode (q_ref = r), the velocity target of velocity mode (q_ref = q₀ + r τ,
// q̇_ref = r).
enum TargetKind { TARGET_NONE = 0, TARGET_POSITION = 1, TARGET_VELOCITY = 2 };

// One evaluation's scratch of the law (n_u each, n_arm for the rows).
template <class S>
struct ArmWorkspace {
  std::vector<S> ud, Q_id, col_v, col_w, zero;  // (n_u) the inverse-dynamics passes
  std::vector<S> ref;                            // (3 × n_arm) q_ref, q̇_ref, q̈_ref
  std::vector<S> ff;                             // (n_arm) the feed-forward
  // (n_arm) zeros carrying the derivatives of the target (`target_kind`), added to the reference
  // where it depends on the target (dual numbers only: TARGET_NONE leaves the law untouched)
  std::vector<S> target;
  int target_kind = TARGET_NONE;
  explicit ArmWorkspace(int n_u)
      : ud(n_u), Q_id(n_u), col_v(n_u), col_w(n_u), zero(n_u, S(0.0)), ref(3 * (n_u - 2)),
        ff(n_u - 2), target(n_u - 2, S(0.0)) {}
};

// The target's derivatives into the reference of the segment in use at clock tau (values kept).
template <class S>
void seed_target(const ArmControl& arm, int n_arm, const S& tau, ArmWorkspace<S>& w) {
  const S t = tau - arm.starts[int(arm.settings[ARM_SEGMENT])];
  for (int j = 0; j < n_arm; ++j) {
    if (w.target_kind == TARGET_POSITION) {
      w.ref[Q_REF * n_arm + j] += w.target[j];
    } else {
      w.ref[Q_REF * n_arm + j] += w.target[j] * t;
      w.ref[QD_REF * n_arm + j] += w.target[j];
    }
  }
}

// angles::shortest_angular_distance(start, end): end − start moved by whole turns into (−π, π].
inline double shortest_angle(double start, double end) {
  double d = end - start;
  if (-M_PI < d && d <= M_PI) return d;
  double r = std::fmod(d + M_PI, 2.0 * M_PI);
  return r <= 0.0 ? r + M_PI : r - M_PI;
}
// A continuous joint's error q_ref − q, the shortest angle (its whole turns are constants).
inline double angle_error(double q, double q_ref) { return shortest_angle(q, q_ref); }
template <class D>
inline Dual<double, D> angle_error(const Dual<double, D>& q, const Dual<double, D>& q_ref) {
  return {shortest_angle(q.val, q_ref.val), q_ref.d - q.d};
}

// q_ref, q̇_ref, q̈_ref at clock τ into ref (3 × n_arm): the last of the first `count` segments
// that has started, found by walking from `hint`; Horner's rule in the segment's local time.
// Returns that segment (the next hint).
template <class S>
int reference(const double* starts, const double* coeffs, int count, int n_arm, const S& tau,
              S* ref, int hint) {
  int lo = 0 <= hint && hint < count ? hint : 0;
  while (lo + 1 < count && starts[lo + 1] <= value(tau)) ++lo;
  while (lo > 0 && starts[lo] > value(tau)) --lo;
  S t = tau - starts[lo];
  for (int j = 0; j < n_arm; ++j) {
    const double* c = coeffs + (lo * n_arm + j) * REF_WIDTH;
    S p = S(c[5]), v = S(5.0 * c[5]), a = S(20.0 * c[5]);
    for (int k = 4; k >= 0; --k) {
      p = p * t + c[k];
      if (k >= 1) v = v * t + double(k) * c[k];
      if (k >= 2) a = a * t + double(k * (k - 1)) * c[k];
    }
    ref[Q_REF * n_arm + j] = p;
    ref[QD_REF * n_arm + j] = v + c[HELD_QD];
    ref[QDD_REF * n_arm + j] = a + c[HELD_QDD];
  }
  return lo;
}

// G(q) on the arm joints into out (n_arm): the inverse dynamics at u = u̇ = 0, where every point
// accelerates by g ẑ: rod k's force μ_k L_k g ẑ, its moment about O_k μ_k s1 g x_k × ẑ, the
// payload's force m g ẑ; the inward pass keeps f vertical and m horizontal. Needs `frames`.
template <class S>
void gravity_efforts(const Model& model, const S* q, double g, const Workspace<S>& ws, S* out) {
  S f_z = S(model.tip_mass * g), m_x = S(0.0), m_y = S(0.0);
  for (int k = model.n(); k >= 1; --k) {
    const S& l = q[q_slide(k)];
    double Lk = model.L[k - 1], muk = model.mu[k - 1];
    S s1, s2;
    rod_moments(l, Lk, s1, s2);
    S lever = muk * s1 * g + l * f_z;  // N_k + l x_k × f, per unit of x_k × ẑ
    m_x += lever * ws.x[k][1];
    m_y -= lever * ws.x[k][0];
    f_z += muk * Lk * g;
    out[2 * k - 2] = ws.z[k][0] * m_x + ws.z[k][1] * m_y;
    out[2 * k - 1] = ws.x[k][2] * f_z;
  }
}

// (v̇*, ω̇*): the base rows M_bb u̇_b = Q_b − (M_ba q̈* + h_b), with Q_id the inverse dynamics at
// u̇ = (0, 0, q̈*); the unit-base-acceleration columns M e_v, M e_ω into w.col_v, w.col_w; a locked
// base pseudo-velocity has u̇ = 0. Needs `frames`.
template <class S>
void base_acceleration(const Model& model, Workspace<S>& ws, const S* q, const S& Qb0,
                       const S& Qb1, ArmWorkspace<S>& w, S& vd, S& omd) {
  const auto& moving = ws.moving;
  if (moving[0] == 0.0 && moving[1] == 0.0) {
    vd = S(0.0);
    omd = S(0.0);
    return;
  }
  auto& unit = w.ud;
  for (auto& x : unit) x = S(0.0);
  unit[0] = S(1.0);
  inverse_dynamics(model, q, w.zero.data(), unit.data(), 0.0, ws, w.col_v.data());
  unit[0] = S(0.0);
  unit[1] = S(1.0);
  inverse_dynamics(model, q, w.zero.data(), unit.data(), 0.0, ws, w.col_w.data());
  S K00 = w.col_v[0], K01 = w.col_w[0], K11 = w.col_w[1];
  S r0 = Qb0 - w.Q_id[0], r1 = Qb1 - w.Q_id[1];
  if (moving[0] == 0.0) {
    K00 = S(1.0);
    K01 = S(0.0);
    r0 = S(0.0);
  }
  if (moving[1] == 0.0) {
    K11 = S(1.0);
    K01 = S(0.0);
    r1 = S(0.0);
  }
  S det = K00 * K11 - K01 * K01;
  vd = (K11 * r0 - K01 * r1) / det;
  omd = (K00 * r1 - K01 * r0) / det;
}

// The feed-forward efforts into w.ff (n_arm), Q holding the base's applied forces acting now
// (before damping). Needs `frames`.
template <class S>
void feedforward(const Model& plant, const ArmControl& arm, double g, const double* damping,
                 const S* s, const S* Q, Workspace<S>& ws, ArmWorkspace<S>& w) {
  const int kind = arm.feedforward(), n_arm = plant.n_u() - 2, nq = plant.n_q();
  if (kind == FEEDFORWARD_NONE || (kind == FEEDFORWARD_GRAVITY && g == 0.0)) {
    for (int j = 0; j < n_arm; ++j) w.ff[j] = S(0.0);
    return;
  }
  const Model& model = *arm.model;
  const S* q = s;
  const S* u = s + nq;
  if (kind == FEEDFORWARD_GRAVITY) {
    gravity_efforts(model, q, g, ws, w.ff.data());
    return;
  }
  w.ud[0] = S(0.0);
  w.ud[1] = S(0.0);
  for (int j = 0; j < n_arm; ++j) w.ud[2 + j] = w.ref[QDD_REF * n_arm + j] * ws.moving[2 + j];
  inverse_dynamics(model, q, u, w.ud.data(), g, ws, w.Q_id.data());
  S Qb0 = Q[V], Qb1 = Q[OMEGA];
  if (damping != nullptr) {
    Qb0 -= damping[0] * u[0];
    Qb1 -= damping[1] * u[1];
  }
  S vd, omd;
  base_acceleration(model, ws, q, Qb0, Qb1, w, vd, omd);
  const bool base_moves = !(value(vd) == 0.0 && value(omd) == 0.0);
  for (int j = 0; j < n_arm; ++j) {
    w.ff[j] = w.Q_id[2 + j];
    if (base_moves) w.ff[j] += w.col_v[2 + j] * vd + w.col_w[2 + j] * omd;
    if (damping != nullptr) w.ff[j] += damping[2 + j] * u[2 + j];
  }
}

// The arm's efforts into Q[2:], ż and τ̇ into ds, the evaluation's reference, feed-forward and
// efforts into arm.last (module comment). Needs `frames` of s and the base's applied forces in
// Q[0:2].
template <class S>
void arm_efforts(const Model& plant, const ArmControl& arm, double g, const double* damping,
                 const S* s, S* ds, S* Q, Workspace<S>& ws, ArmWorkspace<S>& w) {
  const int nq = plant.n_q(), n_arm = plant.n_u() - 2;
  const int i_z = arm_integrals_index(plant), i_clock = reference_clock_index(plant);
  double* settings = arm.settings;
  settings[ARM_SEGMENT] = reference(arm.starts, arm.coeffs, int(settings[ARM_SEGMENTS]), n_arm,
                                    s[i_clock], w.ref.data(), int(settings[ARM_SEGMENT]));
  if (w.target_kind != TARGET_NONE) seed_target(arm, n_arm, s[i_clock], w);
  feedforward(plant, arm, g, damping, s, Q, ws, w);
  for (int j = 0; j < n_arm; ++j) {
    const S& q_j = s[q_turn(1) + j];
    const S& q_ref = w.ref[Q_REF * n_arm + j];
    S e = j % 2 == 0 ? angle_error(q_j, q_ref) : q_ref - q_j;
    S ed = w.ref[QD_REF * n_arm + j] - s[nq + 2 + j];
    S raw = w.ff[j] + arm.gains[GAIN_KP * n_arm + j] * e + arm.gains[GAIN_KD * n_arm + j] * ed +
            arm.gains[GAIN_KI * n_arm + j] * s[i_z + j];
    double limit = arm.limits[j];
    S low = select(value(raw) < -limit, S(-limit), raw);  // max(raw, −limit)
    S tau = select(limit < value(low), S(limit), low);    // min(…, limit)
    Q[2 + j] = tau;
    auto saturated = ((value(raw) > limit) & (value(e) > 0.0)) |
                     ((value(raw) < -limit) & (value(e) < 0.0));
    ds[i_z + j] = select(saturated, S(0.0), e);
    for (int row = Q_REF; row <= QDD_REF; ++row)
      arm.last[row * n_arm + j] = value(w.ref[row * n_arm + j]);
    arm.last[LAST_FF * n_arm + j] = value(w.ff[j]);
    arm.last[LAST_TAU * n_arm + j] = value(tau);
  }
  ds[i_clock] = S(1.0);
}

// Sampled: the efforts of the last update, held, into Q[2:]; ż = 0, τ̇ = 1.
template <class S>
void held_arm_efforts(const Model& plant, const ArmControl& arm, S* ds, S* Q) {
  const int n_arm = plant.n_u() - 2, i_z = arm_integrals_index(plant);
  for (int j = 0; j < n_arm; ++j) {
    Q[2 + j] = S(arm.held[2 + j]);
    ds[i_z + j] = S(0.0);
  }
  ds[reference_clock_index(plant)] = S(1.0);
}

}  // namespace mms
