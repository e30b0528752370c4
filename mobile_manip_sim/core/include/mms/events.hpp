// Events inside a step (docs/model.md, "Resting, leaving, and no Zeno"): a rod reaching an end
// stop, a resting rod pulled off its stop. Both are roots in h' ∈ (0, h] of an event function of
// the state h' into the step along the step's path — for the fixed-step methods the integrator's
// own step s0 → h' (so the located state is what the integrator itself reaches), for the
// adaptive ones the step's dense output: g = side·(stop − l_k) for a crossing, the least holding
// margin for a release.
//
// A crossing is flagged after a step when a rod's end value or the extremum of its cubic Hermite
// path over the step leaves the stroke (a fast rod that crosses and comes back within one step is
// not missed); the first crossing is bracketed between 16 samples of the step plus the path's
// turning points, then located by the Illinois method. A release is watched at every evaluation
// of the right-hand side (run.hpp's `derivative`); where one saw a stop pull, the margin is
// sampled at 16 instants of the step and the first pull located by the same root finder.
// (Their constants: events.hpp, stops.hpp, read by engine/events.py through `core.vocabulary`.)
#pragma once

#include <cmath>
#include <vector>

#include "fixed_step.hpp"
#include "stops.hpp"

namespace mms {

constexpr int N_SAMPLES = 16;
enum EventKind { CROSSING, RELEASE };

// A step's path: `path(h', out)` writes the state h' into the step (h' > 0) into out — the
// integrator's own step from its start (`OwnStep`), an adaptive step's dense output
// (adaptive_stepping.hpp's `DensePath`), or the power series of a step handed in (`PowerSeries`).

// One step of `method` from s of length h into out, the run's right-hand side counted and
// watched (`derivative`); with k1_ready the first stage already holds f(s).
inline void run_step(Run& run, Method method, const double* s, double h, double* out,
                     bool k1_ready = false) {
  double* k[4] = {run.stage(0), run.stage(1), run.stage(2), run.stage(3)};
  step_with(
      method, run.model, [&](const double* at, double* rate) { derivative(run, at, rate); }, s,
      h, out, k, run.x.data(), run.size, k1_ready);
}

struct HermiteTurns {
  double tau[2];  // where the path has zero slope (−1 for a missing root)
  double c2, c3;  // p(τ) = l0 + d0 τ + c2 τ² + c3 τ³
};

// The turning points of the cubic Hermite with values l0, l1 and slopes d0, d1 over [0, h].
inline HermiteTurns hermite_turns(double l0, double d0, double l1, double d1, double h) {
  HermiteTurns t;
  t.c2 = (3.0 * (l1 - l0) / h - 2.0 * d0 - d1) / h;
  t.c3 = (d0 + d1 - 2.0 * (l1 - l0) / h) / (h * h);
  double a = 3.0 * t.c3, b = 2.0 * t.c2, c = d0;
  t.tau[0] = t.tau[1] = -1.0;
  if (a == 0.0) {
    if (b != 0.0) t.tau[0] = -c / b;
  } else {
    double disc = b * b - 4.0 * a * c;
    if (disc >= 0.0) {
      // cancellation-free: a path that is nearly a parabola has a ≈ 0 from round-off
      double w = -0.5 * (b + std::copysign(std::sqrt(disc), b));
      t.tau[0] = w / a;
      t.tau[1] = w != 0.0 ? c / w : -1.0;
    }
  }
  return t;
}

// True when a watched rod leaves its stroke during the step s0 → s1.
inline bool crossing_in_step(Run& run, const double* s0, const double* s1, double h) {
  run.system.counters[CROSSING_CHECKS] += 1;
  for (int k = 1; k <= run.n(); ++k) {
    if (!run.stops.watched[k - 1]) continue;
    double lo = run.stops.stroke[2 * (k - 1)], hi = run.stops.stroke[2 * (k - 1) + 1];
    int i_l = q_slide(k), i_ld = ld_index(run, k);
    if (s1[i_l] < lo || s1[i_l] > hi) return true;
    double l0 = s0[i_l], d0 = s0[i_ld], l1 = s1[i_l], d1 = s1[i_ld];
    double low = std::min(l0, l1), high = std::max(l0, l1);
    HermiteTurns turns = hermite_turns(l0, d0, l1, d1, h);
    for (double tau : turns.tau)
      if (0.0 < tau && tau < h) {
        double p = l0 + tau * (d0 + tau * (turns.c2 + tau * turns.c3));
        low = std::min(low, p);
        high = std::max(high, p);
      }
    if (low < lo || high > hi) return true;
  }
  return false;
}

// The state h into the step from s0 (s0 itself for h ≤ 0), into out, along `path`.
template <class Path>
inline void step_state(Run& run, Path& path, const double* s0, double h, double* out) {
  if (h <= 0.0) {
    for (int i = 0; i < run.size; ++i) out[i] = s0[i];
  } else {
    path(h, out);
  }
}

// The fixed-step methods' path: the integrator's own step from s0.
struct OwnStep {
  Run& run;
  Method method;
  const double* s0;
  void operator()(double h, double* out) const { run_step(run, method, s0, h, out); }
};

// An outside solver's step (SciPy's radau and bdf, stepped from Python one step at a time): its
// interpolant handed in as a power series in θ = h'/h, y(θ) = y₀ + Σ_j c_j θ^(j+1)
// (engine/scipy_steps.py's `power_series`), summed by Horner's rule over every row (the unused
// ones are zero).
struct PowerSeries {
  const std::vector<std::vector<double>>& c;  // (rows × n) c_j
  const double* s0;                           // y₀, the state at the step's start
  double h;                                   // the step's length (s)
  int n;
  void operator()(double h_into, double* out) const {
    const double theta = h_into / h;
    for (int i = 0; i < n; ++i) {
      double y = 0.0;
      for (int j = int(c.size()) - 1; j >= 0; --j) y = (y + c[j][i]) * theta;
      out[i] = s0[i] + y;
    }
  }
};

struct EventTarget {
  EventKind kind;
  int i_l = 0;       // CROSSING: the rod's l in s, the stop met, its value
  int side = 0;
  double stop = 0;
};

template <class Path>
inline double event_value(Run& run, Path& path, const EventTarget& e, const double* s0,
                          double h) {
  double* trial = run.step.trial;
  step_state(run, path, s0, h, trial);
  if (e.kind == CROSSING) return (e.stop - trial[e.i_l]) * e.side;
  return holding_margin(run, trial, run.stage(3));
}

// The root of g in (a, b] with g(a) ≥ 0 > g(b), by the Illinois method: the h' with g(h') ≤ 0
// closest to the root (the state has just reached the event).
template <class Path>
inline double locate(Run& run, Path& path, const EventTarget& e, const double* s0, double a,
                     double b) {
  const double h = b - a;
  double ga = event_value(run, path, e, s0, a);
  double gb = event_value(run, path, e, s0, b);
  double g_root = gb;  // g at b itself: the Illinois steps halve gb
  int last = 0;
  for (int i = 0; i < 200; ++i) {
    // with g(a) = 0 (a rod starting exactly at its stop) the secant would land on a itself
    double c = gb != ga && ga != 0.0 ? b - gb * (b - a) / (gb - ga) : 0.5 * (a + b);
    if (!(a < c && c < b)) c = 0.5 * (a + b);
    double gc = event_value(run, path, e, s0, c);
    if (gc <= 0.0) {
      b = c;
      gb = gc;
      g_root = gc;
      if (last == -1) ga *= 0.5;
      last = -1;
    } else {
      a = c;
      ga = gc;
      if (last == 1) gb *= 0.5;
      last = 1;
    }
    if ((-1e-13 <= g_root && g_root <= 0.0) || b - a <= 1e-15 * h) break;
  }
  return b;
}

// Insert x into the sorted a[:m] (a has room for it); returns m + 1.
inline int insert_sorted(double* a, int m, double x) {
  int j = m;
  while (j > 0 && a[j - 1] > x) {
    a[j] = a[j - 1];
    --j;
  }
  a[j] = x;
  return m + 1;
}

struct Crossing {
  double h = -1.0;  // h' into the step, −1 for none
  int k = 0;        // the rod (1-based), 0 for none
  int side = 0;
};

// The earliest (h', rod k, side) at which a watched rod meets a stop within the step s0 → h.
template <class Path>
inline Crossing first_crossing(Run& run, Path& path, const double* s0, double h) {
  double* samples = run.step.samples;
  std::int64_t* crossed = run.step.crossed;
  double* trial = run.step.trial;
  const int n = run.n();
  int m = 0;
  for (int j = 1; j <= N_SAMPLES; ++j) samples[m++] = h * j / N_SAMPLES;
  // the instants where each rod's Hermite path over the step turns
  step_state(run, path, s0, h, trial);
  for (int k = 1; k <= n; ++k)
    if (run.stops.watched[k - 1]) {
      int i_l = q_slide(k), i_ld = ld_index(run, k);
      HermiteTurns turns = hermite_turns(s0[i_l], s0[i_ld], trial[i_l], trial[i_ld], h);
      for (double tau : turns.tau)
        if (0.0 < tau && tau < h) m = insert_sorted(samples, m, tau);
    }
  // bracket the first crossing: every stop inside at samples[end − 1], some past at samples[end]
  int end = -1;
  for (int j = 0; j < m; ++j) {
    step_state(run, path, s0, samples[j], trial);
    for (int k = 1; k <= n; ++k) {
      crossed[k - 1] = 0;
      if (run.stops.watched[k - 1]) {
        double l_k = trial[q_slide(k)];
        if (l_k < run.stops.stroke[2 * (k - 1)])
          crossed[k - 1] = -1;
        else if (l_k > run.stops.stroke[2 * (k - 1) + 1])
          crossed[k - 1] = 1;
        if (crossed[k - 1] != 0) end = j;
      }
    }
    if (end >= 0) break;
  }
  Crossing best;
  if (end < 0) return best;
  double a = end > 0 ? samples[end - 1] : 0.0;
  for (int k = 1; k <= n; ++k) {
    int side = int(crossed[k - 1]);
    if (side == 0) continue;
    EventTarget e{CROSSING, q_slide(k), side,
                  run.stops.stroke[2 * (k - 1) + (side < 0 ? 0 : 1)]};
    double h_hit = locate(run, path, e, s0, a, samples[end]);
    if (best.k == 0 || h_hit < best.h) best = Crossing{h_hit, k, side};
  }
  return best;
}

// The earliest h' in (0, h] at which a resting rod's stop would start to pull, or −1.
template <class Path>
inline double first_release(Run& run, Path& path, const double* s0, double h) {
  const EventTarget e{RELEASE};
  double before = 0.0;
  for (int j = 1; j <= N_SAMPLES; ++j) {
    double h_j = h * j / N_SAMPLES;
    if (event_value(run, path, e, s0, h_j) < 0.0)
      return locate(run, path, e, s0, before, h_j);
    before = h_j;
  }
  return -1.0;
}

}  // namespace mms
