// The derivative of a fixed step that holds events — a rod reaching its end stop (the impact, with
// or without rebound, the rod coming to rest there), a resting rod released — by dual numbers.
//
// The double run takes the step (stepping.hpp's `step_with_events`) and records what it decided
// (EventScript: where each event was located, which rods were hit, the impact's contact set and
// which of its contacts were active, the locks after each event). The step is then replayed on
// dual numbers through the same pieces, the discrete decisions held:
//
//   stretch   x* = Φ(s, h*)             the integrator's own step (fixed_step.hpp) to the event;
//   event     g(Φ(s, h*)) = 0           g = σ (stop − l_k) for a crossing, the least holding force
//                                       of the resting rods for a release (events.hpp);
//             dh*/ds = −(∂g/∂x ∂Φ/∂s) / (dg/dh*)     the implicit function theorem: h* carries
//                                       the derivative of the event time (the saltation), the
//                                       located h* its value;
//   impact    u⁺ = u⁻ + M⁻¹E P, P_A = −W_AA⁻¹ (1 + e) c⁻_A  on the active set the double solve
//                                       found (stops.hpp's `active_impulses`, the same solve), the
//                                       rods hit set onto their stops (l fixed: ∂l = 0);
//   rest      what is left of the step, h − h*, from the state after the event, with its locks.
//
// The value part of every number is the double run's, operation for operation (a test checks the
// end state bit for bit), so the derivatives are those of the very map the engine computes — as
// long as a perturbation keeps the same events (a perturbation that moves an event out of the
// step, or changes the active set, is another branch of the map).
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include "events.hpp"

namespace mms {

// The replay's scratch, for one scalar S (Dual<double, D>).
template <class S>
struct EventWork {
  std::vector<S> segment, trial, x, rate, M, L, unit, MinvE, W, c_minus, qv, P, cholesky;
  std::vector<std::vector<S>> k;
  std::vector<int> free, index;
  EventWork(int size, int n_u, int n)
      : segment(size), trial(size), x(size), rate(size), M(n_u * n_u), L(n_u * n_u),
        unit(n_u), MinvE(n * n_u), W(n * n), c_minus(n), qv(n), P(n), cholesky(n * (n + 1)),
        k(4, std::vector<S>(size)), free(n_u), index(n) {}
};

// The event function of `event` at x (after `rates` at x for a release: its slide forces and
// applied forces in ws): σ (stop − l_k) for a crossing; for a release the holding force of the
// resting rod whose margin is least.
template <class S, class Rates>
S event_function(const RecordedEvent& event, const StopsArrays& stops, const Model& model, const S* x,
                 Rates& rates, SystemWorkspace<S>& ws, S* rate) {
  if (event.kind == CROSSING) {
    const double stop = stops.stroke[2 * (event.rod - 1) + (event.side < 0 ? 0 : 1)];
    return (stop - x[q_slide(event.rod)]) * double(event.side);
  }
  rates(x, rate);
  S least(0.0);
  bool found = false;
  for (int k = 1; k <= model.n(); ++k) {
    std::int64_t side = event.resting[k - 1];
    if (side == 0) continue;
    S margin = -double(side) * (ws.dynamics.slide_force[k] - ws.Q[u_slide(k)]);
    if (!found || value(margin) < value(least)) least = margin;
    found = true;
  }
  return least;
}

// The impact of `event` on x in place (stops.hpp's `contact_impulses`, or the `reflect` law), its
// contact set and active set as the double run found them.
template <class S>
void impact_map(const RecordedEvent& event, const StopsArrays& stops, const Model& model, S* x,
                SystemWorkspace<S>& ws, EventWork<S>& w) {
  const int nq = model.n_q(), nu = model.n_u(), n = std::max(model.n(), 1);
  const ContactSolution& c = event.solution;
  const int m = c.m;
  for (int r = 1; r <= model.n(); ++r)  // every rod hit sits on its stop: l fixed there
    if (event.hits[r - 1] != 0)
      x[q_slide(r)] = S(stops.stroke[2 * (r - 1) + (event.hits[r - 1] < 0 ? 0 : 1)]);
  if (stops.law == REFLECT) {
    for (int a = 0; a < m; ++a) {
      S& ld = x[nq + u_slide(c.rods[a])];
      ld = -c.e[a] * ld;
    }
  } else {
    int n_free = 0;
    for (int j = 0; j < nu; ++j) w.free[j] = -1;
    for (int j = 0; j < nu; ++j)
      if (!stops.permanent[j]) w.free[n_free++] = j;
    frames(model, x, ws.dynamics);
    mass_matrix(model, ws.dynamics, x, w.M.data());
    for (int a = 0; a < m; ++a) {
      for (int i = 0; i < nu; ++i) w.unit[i] = S(0.0);
      w.unit[u_slide(c.rods[a])] = S(c.sigma[a]);
      cholesky_solve(w.M.data(), nu, w.unit.data(), w.free.data(), n_free, w.L.data(),
                     w.MinvE.data() + a * nu);
    }
    for (int a = 0; a < m; ++a) {
      int j = u_slide(c.rods[a]), pos = 0;
      while (w.free[pos] != j) ++pos;
      for (int b = 0; b < m; ++b) w.W[a * n + b] = c.sigma[a] * w.MinvE[b * nu + pos];
    }
    for (int a = 0; a < m; ++a) {
      w.c_minus[a] = c.sigma[a] * x[nq + u_slide(c.rods[a])];
      w.qv[a] = (1.0 + c.e[a]) * w.c_minus[a];
    }
    int n_active = 0;
    for (int a = 0; a < m; ++a)
      if (c.active[a]) w.index[n_active++] = a;
    active_impulses(w.W.data(), n, w.qv.data(), m, w.index.data(), n_active, w.cholesky.data(),
                    n + 1, w.P.data());
    for (int b = 0; b < m; ++b)
      if (value(w.P[b]) != 0.0)
        for (int a = 0; a < n_free; ++a) x[nq + w.free[a]] += w.P[b] * w.MinvE[b * nu + a];
    for (int b = 0; b < m; ++b)
      if (c.active[b]) x[nq + u_slide(c.rods[b])] = -c.e[b] * w.c_minus[b] * c.sigma[b];
  }
  for (int r = 1; r <= model.n(); ++r)  // stopped dead: +0.0, as the run sets it
    if (event.hits[r - 1] != 0 && value(x[nq + u_slide(r)]) == 0.0) x[nq + u_slide(r)] = S(0.0);
}

// One step of `method` of length h from s, through the events of `script`, in dual numbers
// (module doc): out. `rates(x, rate)` the right-hand side in S with ws (whose locks `moving` this
// sets for each stretch). slopes[i] is dg/dh* of event i, found by a call with `find_slopes` in
// which nothing is seeded (s, the efforts and every other input plain: h* alone is, along the
// first direction), then read by the calls that carry the seeds.
template <class S, class Rates>
void step_through_events(Method method, const Model& model, const StopsArrays& stops,
                         const EventScript& script, Rates&& rates, SystemWorkspace<S>& ws,
                         const S* s, double h, S* out, EventWork<S>& w, int size,
                         std::vector<double>& slopes, bool find_slopes) {
  S* k[4] = {w.k[0].data(), w.k[1].data(), w.k[2].data(), w.k[3].data()};
  auto stretch = [&](const S* from, const S& length, S* to) {
    step_with(method, model, rates, from, length, to, k, w.x.data(), size);
  };
  std::copy(s, s + size, w.segment.begin());
  std::copy(script.moving.begin(), script.moving.end(), ws.dynamics.moving.begin());
  S left(h);
  if (find_slopes) slopes.assign(script.events.size(), 0.0);
  for (size_t e = 0; e < script.events.size(); ++e) {
    const RecordedEvent& event = script.events[e];
    if (find_slopes) {  // dg/dh*: h* seeded along the first direction, nothing else
      S seeded(event.h);
      seeded.d.set(0, 1.0);
      stretch(w.segment.data(), seeded, w.trial.data());
      slopes[e] = event_function(event, stops, model, w.trial.data(), rates, ws, w.rate.data()).d[0];
    }
    // g and its derivatives along the seeds at the located h*
    stretch(w.segment.data(), S(event.h), w.trial.data());
    S g = event_function(event, stops, model, w.trial.data(), rates, ws, w.rate.data());
    S h_event(event.h, -g.d / slopes[e]);
    stretch(w.segment.data(), h_event, w.trial.data());
    left = left - h_event;
    if (event.kind == CROSSING) impact_map(event, stops, model, w.trial.data(), ws, w);
    std::copy(w.trial.begin(), w.trial.end(), w.segment.begin());
    std::copy(event.moving.begin(), event.moving.end(), ws.dynamics.moving.begin());
  }
  if (script.last_stretch)
    stretch(w.segment.data(), left, out);
  else
    std::copy(w.segment.begin(), w.segment.end(), out);
}

}  // namespace mms
