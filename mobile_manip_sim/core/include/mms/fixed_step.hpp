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

template <class S>
void step(Method method, const Model& model, const Effects<S>& fx, const S* s, double h, S* out,
          SystemWorkspace<S>& ws) {
  const int n = state_size(model), nq = model.n_q(), nu = model.n_u();
  auto& k = ws.k;
  if (method == Method::Rk4) {
    for (int stage = 0; stage < 4; ++stage) {
      const S* x = s;
      if (stage > 0) {  // s + c h k_(stage−1), c = ½, ½, 1
        double c = stage == 3 ? h : 0.5 * h;
        for (int i = 0; i < n; ++i) ws.x[i] = s[i] + c * k[stage - 1][i];
        x = ws.x.data();
      }
      rates(model, fx, x, k[stage].data(), ws);
    }
    for (int i = 0; i < n; ++i)
      out[i] = s[i] + h / 6.0 * (k[0][i] + 2.0 * k[1][i] + 2.0 * k[2][i] + k[3][i]);
    return;
  }
  rates(model, fx, s, k[0].data(), ws);
  if (method == Method::Euler) {
    for (int i = 0; i < n; ++i) out[i] = s[i] + h * k[0][i];
    return;
  }
  for (int i = nq; i < n; ++i) out[i] = s[i] + h * k[0][i];
  configuration_rate(model, s, out + nq, k[1].data());
  for (int i = 0; i < nq; ++i) out[i] = s[i] + h * k[1][i];
  (void)nu;
}

}  // namespace mms
