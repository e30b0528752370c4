// The fixed-step integrators, generic in the scalar S: one step of length h from s into out.
//
//   Euler                explicit Euler, order 1: s⁺ = s + h f(s)
//   SemiImplicitEuler    symplectic Euler, order 1: u⁺ = u + h u̇(q, u) (and e, W likewise),
//                        then q⁺ = q + h q̇(q, u⁺), the constraints taken at the new velocities
//   Rk4                  the classic Runge–Kutta method, order 4: c = 0, ½, ½, 1;
//                        b = 1/6, 1/3, 1/3, 1/6
//
// Instantiated for double it is the run's step; for Dual numbers seeded on (q, u) and the efforts
// it is the exact derivative of that very step map (A = ∂s⁺/∂s, B = ∂s⁺/∂τ).
#pragma once

#include <string>

#include "system.hpp"

namespace mms {

enum class Method { Euler, SemiImplicitEuler, Rk4 };

// One step with the right-hand side `f(x, dx)` given (the engine's counts its stages and watches
// the holding forces); k[0 … 3] are the stages (with `k1_ready`, k[0] already holds f(s)), x a
// stage's state; n entries of s. The length h is a double, or a scalar S where the step's length
// itself carries derivatives (a step that ends at a located event: event_jacobians.hpp).
template <class S, class H, class P, class F>
void step_with(Method method, const ModelOf<P>& model, F&& f, const S* s, H h, S* out,
               S* const* k, S* x, int n, bool k1_ready = false) {
  const int nq = model.n_q();
  if (method == Method::Rk4) {
    for (int stage = k1_ready ? 1 : 0; stage < 4; ++stage) {
      const S* at = s;
      if (stage > 0) {  // s + c h k_(stage−1), c = ½, ½, 1
        H c = stage == 3 ? h : 0.5 * h;
        for (int i = 0; i < n; ++i) x[i] = s[i] + c * k[stage - 1][i];
        at = x;
      }
      f(at, k[stage]);
    }
    for (int i = 0; i < n; ++i)
      out[i] = s[i] + h / 6.0 * (k[0][i] + 2.0 * k[1][i] + 2.0 * k[2][i] + k[3][i]);
    return;
  }
  if (!k1_ready) f(s, k[0]);
  if (method == Method::Euler) {
    for (int i = 0; i < n; ++i) out[i] = s[i] + h * k[0][i];
    return;
  }
  for (int i = nq; i < n; ++i) out[i] = s[i] + h * k[0][i];
  configuration_rate(model, s, out + nq, k[1]);
  for (int i = 0; i < nq; ++i) out[i] = s[i] + h * k[1][i];
}

template <class S, class P>
void step(Method method, const ModelOf<P>& model, const Effects<S>& fx, const S* s, double h, S* out,
          SystemWorkspace<S>& ws) {
  S* k[4] = {ws.k[0].data(), ws.k[1].data(), ws.k[2].data(), ws.k[3].data()};
  step_with(
      method, model, [&](const S* at, S* rate) { rates(model, fx, at, rate, ws); }, s, h, out,
      k, ws.x.data(), state_size(model));
}

}  // namespace mms
