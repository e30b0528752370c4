// The simulated ODE's right-hand side for a robot driven by efforts, generic in the scalar S.
//
// State s = (q, u, e, W) (the engine's layout: n_q + n_u + 3 numbers): configuration,
// pseudo-velocities, the wheel-speed loop's two error integrals e (constant while the wheels take
// efforts) and W, the work done on the robot by the efforts and by dissipation (J), so that
// T + V − W stays constant (impact losses aside).
//
// Generalized forces by source, summed once: Q = Q_cmd (the commanded efforts, already within
// their limits) − c ⊙ u (joint and wheel damping, when the scene turns it on; an empty `damping`
// adds no stage). Locked pseudo-velocities (moving = 0) get u̇ = 0.
#pragma once

#include <type_traits>
#include <vector>

#include "arm_control.hpp"
#include "articulated.hpp"

namespace mms {

// Positions in s beyond (q, u)
template <class P> inline int controller_index(const ModelOf<P>& m) { return m.n_q() + m.n_u(); }
template <class P> inline int work_index(const ModelOf<P>& m) { return m.n_q() + m.n_u() + 2; }
template <class P> inline int state_size(const ModelOf<P>& m) { return m.n_q() + m.n_u() + 3; }

// The wheel-speed loop of a base under velocity commands: each wheel's PI loop on its speed
// θ̇ = (v ± b ω)/r, τ = sat(kp (θ̇* − θ̇) + ki e) within ±limit, its integral e (in the state)
// stopped while τ is saturated in the direction of the error (conditional integration).
struct WheelLoop {
  double kp = 0, ki = 0;                  // N·m·s/rad, N·m/rad
  double limit_R = 0, limit_L = 0;        // N·m, each wheel's own
  double target_R = 0, target_L = 0;      // rad/s, θ̇*
};

// What a scene and its commands turn on, for one evaluation.
template <class S>
struct Effects {
  double gravity = 0;            // g, m/s² along −z
  const S* Q_cmd = nullptr;      // (n_u) commanded generalized forces (the wheels' unused when
                                 // `wheels` drives them)
  const double* damping = nullptr;  // (n_u) viscous coefficients on u, or nullptr: no damping
  const WheelLoop* wheels = nullptr;  // the wheel-speed loop, or nullptr: wheel efforts
  const double* held_wheels = nullptr;  // (τ_R, τ_L) N·m: a sampled wheel-speed loop's torques,
                                        // held since its last update (`wheels` then nullptr)
  const ArmControl* arm = nullptr;      // the arm controller (arm_control.hpp), or nullptr: the
                                        // arm takes Q_cmd (for runs in double only: one reference
                                        // segment per evaluation, not one per lane)
};

// One wheel's PI loop (WheelLoop): its torque and its integral's rate. Anti-windup: with
// `tracking` (the continuous loop) back-calculation with
// control_toolbox's default T_t = kp/ki, ė = error + (τ − raw)/kp, continuous in the state;
// otherwise (a sampled update) conditional integration.
template <class S>
inline void wheel_drive(double kp, double ki, double target, const S& speed, const S& integral,
                        double limit, bool tracking, S& tau, S& rate) {
  S error = target - speed;
  S raw = kp * error + ki * integral;
  S low = select(value(raw) < -limit, S(-limit), raw);   // max(raw, −limit)
  tau = select(limit < value(low), S(limit), low);       // min(…, limit)
  if (tracking && kp > 0.0) {
    rate = error + (tau - raw) / kp;
    return;
  }
  auto held = ((value(raw) > limit) & (value(error) > 0.0)) |
              ((value(raw) < -limit) & (value(error) < 0.0));
  rate = select(held, S(0.0), error);
}

// Both wheels' loops at the state s (u from index n_q, the integrals e_R, e_L at `e`): each wheel
// on its speed θ̇ = (v ± b ω)/r, its torque and its integral's rate (`wheel_drive`).
template <class S, class P>
inline void wheels_drive(const ModelOf<P>& model, const WheelLoop& w, const S* s, bool tracking,
                         S& tau_R, S& tau_L, S& rate_R, S& rate_L) {
  const S* u = s + model.n_q();
  const int e = controller_index(model);
  P r = model.base.wheel_radius, b = model.base.half_track;
  wheel_drive(w.kp, w.ki, w.target_R, (u[V] + b * u[OMEGA]) / r, s[e], w.limit_R, tracking, tau_R,
              rate_R);
  wheel_drive(w.kp, w.ki, w.target_L, (u[V] - b * u[OMEGA]) / r, s[e + 1], w.limit_L, tracking,
              tau_L, rate_L);
}

// One evaluation's scratch beside the dynamics' workspace.
template <class S>
struct SystemWorkspace {
  Workspace<S> dynamics;
  std::vector<S> Q;               // (n_u) the applied generalized forces
  std::vector<std::vector<S>> k;  // (4 × state) the stages of a step
  std::vector<S> x;               // (state) a stage's state
  ArmWorkspace<S> arm;            // the arm controller's passes
  template <class P>
  explicit SystemWorkspace(const ModelOf<P>& m)
      : dynamics(m.n()), Q(m.n_u()), k(4, std::vector<S>(state_size(m))), x(state_size(m)),
        arm(m.n_u()) {}
};

// ds/dt at s: q̇ from the constraints, u̇ = M⁻¹(Q − h) by articulated bodies, ė (the wheel
// loop's), Ẇ = Q·u, and ż, τ̇ when an arm controller drives (arm_control.hpp).
template <class S, class P>
void rates(const ModelOf<P>& model, const Effects<S>& fx, const S* s, S* ds, SystemWorkspace<S>& ws) {
  const int nq = model.n_q(), nu = model.n_u();
  const S* q = s;
  const S* u = s + nq;
  frames(model, q, ws.dynamics);
  configuration_rate(model, q, u, ds);
  for (int k = 0; k < nu; ++k) ws.Q[k] = fx.Q_cmd[k];
  const int e = controller_index(model);
  ds[e] = S(0.0);
  ds[e + 1] = S(0.0);
  if (fx.wheels != nullptr) {
    P r = model.base.wheel_radius, b = model.base.half_track;
    S tau_R, tau_L;
    wheels_drive(model, *fx.wheels, s, true, tau_R, tau_L, ds[e], ds[e + 1]);
    ws.Q[V] = (tau_R + tau_L) / r;
    ws.Q[OMEGA] = b * (tau_R - tau_L) / r;
  } else if (fx.held_wheels != nullptr) {  // sampled: the last update's torques (ė = 0)
    P r = model.base.wheel_radius, b = model.base.half_track;
    double tau_R = fx.held_wheels[0], tau_L = fx.held_wheels[1];
    ws.Q[V] = S((tau_R + tau_L) / r);
    ws.Q[OMEGA] = S(b * (tau_R - tau_L) / r);
  }
  if constexpr (std::is_same_v<RealOf<S>, double> && std::is_same_v<P, double>) {
    if (fx.arm != nullptr) {  // the arm's efforts, ż and τ̇ (after the base's forces: computed
                              // torque reads them)
      if (fx.arm->held != nullptr)
        held_arm_efforts(model, *fx.arm, ds, ws.Q.data());
      else
        arm_efforts(model, *fx.arm, fx.gravity, fx.damping, s, ds, ws.Q.data(), ws.dynamics,
                    ws.arm);
    }
  }
  S power = S(0.0);
  for (int k = 0; k < nu; ++k) power += ws.Q[k] * u[k];
  if (fx.damping != nullptr) {
    for (int k = 0; k < nu; ++k) {
      ws.Q[k] -= fx.damping[k] * u[k];
      power -= fx.damping[k] * u[k] * u[k];
    }
  }
  forward_dynamics(model, q, u, ws.Q.data(), fx.gravity, ws.dynamics, ds + nq);
  ds[work_index(model)] = power;
}

}  // namespace mms
