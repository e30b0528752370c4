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

#include <vector>

#include "articulated.hpp"

namespace mms {

// Positions in s beyond (q, u)
inline int controller_index(const Model& m) { return m.n_q() + m.n_u(); }
inline int work_index(const Model& m) { return m.n_q() + m.n_u() + 2; }
inline int state_size(const Model& m) { return m.n_q() + m.n_u() + 3; }

// What a scene and its commands turn on, for one evaluation: the effort-mode system.
template <class S>
struct Effects {
  double gravity = 0;            // g, m/s² along −z
  const S* Q_cmd = nullptr;      // (n_u) commanded generalized forces
  const double* damping = nullptr;  // (n_u) viscous coefficients on u, or nullptr: no damping
};

// One evaluation's scratch beside the dynamics' workspace.
template <class S>
struct SystemWorkspace {
  Workspace<S> dynamics;
  std::vector<S> Q;               // (n_u) the applied generalized forces
  std::vector<std::vector<S>> k;  // (4 × state) the stages of a step
  std::vector<S> x;               // (state) a stage's state
  explicit SystemWorkspace(const Model& m)
      : dynamics(m.n()), Q(m.n_u()), k(4, std::vector<S>(state_size(m))), x(state_size(m)) {}
};

// ds/dt at s: q̇ from the constraints, u̇ = M⁻¹(Q − h) by articulated bodies, ė = 0, Ẇ = Q·u.
template <class S>
void rates(const Model& model, const Effects<S>& fx, const S* s, S* ds, SystemWorkspace<S>& ws) {
  const int nq = model.n_q(), nu = model.n_u();
  const S* q = s;
  const S* u = s + nq;
  frames(model, q, ws.dynamics);
  configuration_rate(model, q, u, ds);
  for (int k = 0; k < nu; ++k) ws.Q[k] = fx.Q_cmd[k];
  const int e = controller_index(model);
  ds[e] = S(0.0);
  ds[e + 1] = S(0.0);
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
