// Embedded explicit Runge–Kutta pairs with error control and dense output, generic in the
// scalar S. Two methods, both with local extrapolation (the step is taken with the higher order):
//
//   Rk45     Dormand–Prince 5(4): 6 stages + the FSAL stage f(y₁) (Dormand & Prince 1980;
//            Hairer–Nørsett–Wanner I, §II.5, Table 5.2). Dense output: Shampine's 4th-order
//            interpolant, the one SciPy's RK45 uses; it costs no right-hand side.
//   Dop853   Dormand–Prince 8(5,3): 12 stages + f(y₁) (HNW I §II.5 and Hairer's DOP853 code).
//            The error estimate combines the 5th- and 3rd-order embedded formulas as dop853.f
//            does (`error_norm`). Dense output: the 7th-order interpolant, which costs 3 more
//            stages (`dense_prepare`), or, where its estimated error is within the tolerance,
//            a 6th-order continuous extension of the step's own stages, which costs none
//            (`dense_from_stages`). f(y₁) enters neither error estimate, so a rejected step
//            does not evaluate it (11 right-hand sides; an accepted one 12).
//
// The right-hand side is a functor F: f(x, dx) writes ds/dt at x, f.size() is the state size —
// `SystemRhs`, system.hpp's `rates` of the state s = (q, u, e, W) with its effects, or the
// engine's own evaluation (run.hpp), which also counts and watches; it is autonomous (the
// efforts are held through a step). Time in seconds, h the step (s); the tolerances are
// per component of s, in its own units. The tableaus are tableaus.hpp (generated data).
//
// Step-size control as Hairer and SciPy: ‖err‖ < 1 accepts; after an accepted step
// h_new = h·min(kMaxFactor, kSafety·‖err‖^(−1/(p̂+1))) (no growth right after a rejection), after
// a rejected one h·max(kMinFactor, kSafety·‖err‖^(−1/(p̂+1))), p̂ the error estimator's order.
//
// The stage, error and dense-output kernels take the
// step length as RealOf<S> (one per lane for Lanes); the step-size control decides on numbers
// (`value` of a Dual), so it is for scalars whose RealOf is double: a run, or its derivatives.
#pragma once

#include <cmath>
#include <limits>
#include <type_traits>
#include <vector>

#include "system.hpp"
#include "tableaus.hpp"

namespace mms {

enum class Adaptive { Rk45, Dop853 };

constexpr double kSafety = 0.9;     // of the asymptotically optimal step
constexpr double kMinFactor = 0.2;  // the most a step can shrink after a rejection
constexpr double kMaxFactor = 10.0; // the most a step can grow after an acceptance
constexpr int kMaxStages = 16;      // dop853's 12 stages, f(y₁) and its 3 dense-output stages
constexpr int kMaxDense = 7;        // dop853's degree-7 interpolant

inline const Tableau& tableau(Adaptive method) {
  return method == Adaptive::Rk45 ? kRk45 : kDop853;
}

// Python's min and max of two numbers (the first unless the second is strictly beyond it): the
// choice SciPy's controller makes where the two tie or one is NaN.
inline double first_min(double a, double b) { return b < a ? b : a; }
inline double first_max(double a, double b) { return b > a ? b : a; }

// `rates` of a robot with its effects and workspace, as the right-hand side a method steps.
template <class S>
struct SystemRhs {
  const Model& model;
  const Effects<S>& fx;
  SystemWorkspace<S>& ws;
  int size() const { return state_size(model); }
  void operator()(const S* x, S* dx) const { rates(model, fx, x, dx, ws); }
};

// One step's arrays (n = state size), allocated once per run.
template <class S>
struct StepWork {
  std::vector<std::vector<S>> k;      // (kMaxStages × n) stage derivatives k_i; row n_stages is
                                      // f(y₁); dop853's rows 13…15 its dense-output stages
  std::vector<std::vector<S>> dense;  // (kMaxDense × n) the step's interpolant (`dense_eval`)
  std::vector<S> f_start, f_end;      // f(y₀), f(y₁)
  std::vector<S> end;                 // y₁ (and the stages' state before that)
  std::vector<S> error_main;          // h Σ e_i k_i of the main embedded estimate
  std::vector<S> error_third;         // dop853: the 3rd-order one (rk45: zero)
  explicit StepWork(int n)
      : k(kMaxStages, std::vector<S>(n)), dense(kMaxDense, std::vector<S>(n)), f_start(n),
        f_end(n), end(n), error_main(n), error_third(n) {}
};

// y = s + h Σ_{j < n_terms} a_j k_j: the state at which a stage is evaluated.
template <class S>
void stage_state(int n, const S* s, const RealOf<S>& h, const double* a, int n_terms,
                 const std::vector<std::vector<S>>& k, S* y) {
  for (int i = 0; i < n; ++i) {
    S total = S(0.0);
    for (int j = 0; j < n_terms; ++j)
      if (a[j] != 0.0) total += a[j] * k[j][i];
    y[i] = s[i] + h * total;
  }
}

// The stages k₁…k_{n_stages−1} of a step of length h from s (k₀ = work.f_start) and its end
// state y₁ into work.end (the stages' state scratch too: it must not alias s).
template <class S, class F>
void stages(Adaptive method, F& f, const S* s, const RealOf<S>& h, StepWork<S>& work) {
  const Tableau& tab = tableau(method);
  const int n = f.size();
  work.k[0] = work.f_start;
  for (int stage = 1; stage < tab.n_stages; ++stage) {
    stage_state(n, s, h, tab.a[stage], stage, work.k, work.end.data());
    f(work.end.data(), work.k[stage].data());
  }
  stage_state(n, s, h, tab.b, tab.n_stages, work.k, work.end.data());
}

// f(y₁) into work.f_end and k[n_stages].
template <class S, class F>
void end_derivative(Adaptive method, F& f, StepWork<S>& work) {
  f(work.end.data(), work.f_end.data());
  work.k[tableau(method).n_stages] = work.f_end;
}

// error_main and error_third = h Σ_j e_j k_j over the stages and f(y₁).
template <class S>
void error_estimates(Adaptive method, int n, const RealOf<S>& h, StepWork<S>& work) {
  const Tableau& tab = tableau(method);
  std::vector<S>* rows[2] = {&work.error_main, &work.error_third};
  for (int row = 0; row < 2; ++row)
    for (int i = 0; i < n; ++i) {
      S total = S(0.0);
      for (int j = 0; j <= tab.n_stages; ++j)
        if (tab.e[row][j] != 0.0) total += tab.e[row][j] * work.k[j][i];
      (*rows[row])[i] = h * total;
    }
}

// Whether f(y₁) enters the error estimate (rk45: it is a stage; dop853: not).
inline bool error_needs_end_derivative(Adaptive method) {
  const Tableau& tab = tableau(method);
  return tab.e[0][tab.n_stages] != 0.0 || tab.e[1][tab.n_stages] != 0.0;
}

// One step of length h from s with f(s) in work.f_start: y₁ in work.end, f(y₁) in work.f_end,
// the stages in work.k and the error estimates. Returns the right-hand sides it evaluated.
template <class S, class F>
int rk_step(Adaptive method, F& f, const S* s, const RealOf<S>& h, StepWork<S>& work) {
  stages(method, f, s, h, work);
  end_derivative(method, f, work);
  error_estimates(method, f.size(), h, work);
  return tableau(method).n_stages;
}

// Hairer's scaled error norm of the step s → end, sc_i = atol + rtol·max(|s_i|, |end_i|).
// rk45: the RMS of error_main/sc. dop853 (as dop853.f): with e5 = Σ(error_main/sc)²,
// e3 = Σ(error_third/sc)², ‖err‖ = e5 / √(n (e5 + 0.01 e3)). A step is accepted below 1.
template <class S>
double error_norm(Adaptive method, int n, const S* s, const StepWork<S>& work, double rtol,
                  double atol) {
  static_assert(std::is_same<RealOf<S>, double>::value, "step-size control decides per run");
  double e5 = 0.0, e3 = 0.0;
  for (int i = 0; i < n; ++i) {
    double sc = atol + rtol * first_max(std::fabs(value(s[i])), std::fabs(value(work.end[i])));
    double main = value(work.error_main[i]) / sc, third = value(work.error_third[i]) / sc;
    e5 += main * main;
    e3 += third * third;
  }
  if (method == Adaptive::Rk45) return std::sqrt(e5 / n);
  if (e5 == 0.0 && e3 == 0.0) return 0.0;
  return e5 / std::sqrt(n * (e5 + 0.01 * e3));
}

// The next step size after a step of size h with error norm err_norm (same sign as h): after an
// acceptance (err_norm < 1) h·min(kMaxFactor, kSafety·err_norm^(−1/(p̂+1))), at most h when the
// step was itself a retry (`previous_rejected`); after a rejection (a NaN norm too) the step to
// retry with, h·max(kMinFactor, kSafety·err_norm^(−1/(p̂+1))).
inline double next_step(Adaptive method, double err_norm, double h, bool previous_rejected) {
  double exponent = -1.0 / (tableau(method).error_order + 1);
  double factor;
  if (err_norm < 1.0) {
    factor = err_norm == 0.0 ? kMaxFactor
                             : first_min(kMaxFactor, kSafety * std::pow(err_norm, exponent));
    if (previous_rejected) factor = first_min(1.0, factor);
  } else {
    factor = kSafety * std::pow(err_norm, exponent);
    if (!(factor > kMinFactor)) factor = kMinFactor;
  }
  return h * factor;
}

// ‖x/sc‖ (RMS) with sc_i = atol + rtol|s_i|.
template <class S>
double scaled_rms(int n, const S* x, const S* s, double rtol, double atol) {
  double total = 0.0;
  for (int i = 0; i < n; ++i) {
    double r = value(x[i]) / (atol + rtol * std::fabs(value(s[i])));
    total += r * r;
  }
  return std::sqrt(total / n);
}

// A starting step (s), Hairer's heuristic (HNW I §II.4; SciPy's select_initial_step): with
// sc = atol + rtol|s|, d0 = ‖s/sc‖, d1 = ‖f0/sc‖, h0 = 0.01 d0/d1 (1e-6 if either is below
// 1e-5); one explicit Euler step gives d2 = ‖(f(s + h0 f0) − f0)/sc‖/h0, and
// h1 = (0.01/max(d1, d2))^(1/(p̂+1)). Returns min(100 h0, h1, span, max_step) for a run over
// `span` seconds. Costs one right-hand side, evaluated at y_scratch into f_scratch.
template <class S, class F>
double initial_step(Adaptive method, F& f, const S* s, const S* f0, double span, double rtol,
                    double atol, double max_step, S* y_scratch, S* f_scratch) {
  static_assert(std::is_same<RealOf<S>, double>::value, "step-size control decides per run");
  const int n = f.size();
  if (span == 0.0) return 0.0;
  double d0 = scaled_rms(n, s, s, rtol, atol), d1 = scaled_rms(n, f0, s, rtol, atol);
  double h0 = d0 < 1e-5 || d1 < 1e-5 ? 1e-6 : 0.01 * d0 / d1;
  h0 = first_min(h0, span);
  for (int i = 0; i < n; ++i) y_scratch[i] = s[i] + h0 * f0[i];
  f(y_scratch, f_scratch);
  for (int i = 0; i < n; ++i) f_scratch[i] -= f0[i];
  double d2 = scaled_rms(n, f_scratch, s, rtol, atol) / h0;
  double h1 = d1 <= 1e-15 && d2 <= 1e-15
                  ? first_max(1e-6, h0 * 1e-3)
                  : std::pow(0.01 / first_max(d1, d2), 1.0 / (tableau(method).error_order + 1));
  return first_min(first_min(first_min(100.0 * h0, h1), span), max_step);
}

// The interpolant of the step s → work.end of length h, from its stages (after `rk_step`):
// rk45 writes dense[0…3] = Q with Q_j = Σ_i k_i P_ij (state/s); dop853 evaluates its 3
// dense-output stages into k[13…15] and writes dense[0…6] = the F₀…F₆ of dop853.f (in state
// units: F₀ = Δy, F₁ = h f₀ − Δy, F₂ = 2Δy − h(f₀ + f₁), F₃₊ᵣ = h Σ_i d_ri k_i); dense[0] is the
// stage-state scratch first. Returns the right-hand sides it evaluated (0 or 3).
template <class S, class F>
int dense_prepare(Adaptive method, F& f, const S* s, const RealOf<S>& h, StepWork<S>& work) {
  const Tableau& tab = tableau(method);
  const int n = f.size();
  auto& k = work.k;
  auto& dense = work.dense;
  if (method == Adaptive::Rk45) {
    for (int j = 0; j < 4; ++j)
      for (int i = 0; i < n; ++i) {
        S total = S(0.0);
        for (int stage = 0; stage <= tab.n_stages; ++stage)
          total += k[stage][i] * tab.shampine[stage][j];
        dense[j][i] = total;
      }
    return 0;
  }
  for (int stage = tab.n_stages + 1; stage < tab.n_extended; ++stage) {
    stage_state(n, s, h, tab.a[stage], stage, k, dense[0].data());
    f(dense[0].data(), k[stage].data());
  }
  for (int i = 0; i < n; ++i) {
    S dy = work.end[i] - s[i];
    dense[0][i] = dy;
    dense[1][i] = h * work.f_start[i] - dy;
    dense[2][i] = 2.0 * dy - h * (work.f_end[i] + work.f_start[i]);
  }
  for (int r = 0; r < 4; ++r)
    for (int i = 0; i < n; ++i) {
      S total = S(0.0);
      for (int stage = 0; stage < tab.n_extended; ++stage)
        if (tab.dense_d[r][stage] != 0.0) total += tab.dense_d[r][stage] * k[stage][i];
      dense[3 + r][i] = h * total;
    }
  return tab.n_extended - tab.n_stages - 1;
}

// dop853: the interpolant of the step s → work.end of length h from its 13 stages alone (no
// right-hand side), when its estimated error is within the tolerance: true when dense[0…6]
// holds it (the F₀…F₆ `dense_eval` reads), false (dense untouched) when the step needs
// `dense_prepare`'s 7th-order interpolant; always false for rk45, whose interpolant costs
// nothing anyway. The extension is of order 6; its error is estimated at θ = ½ by its
// difference to the 5th-order extension of the same stages (free_check) in `error_norm`'s scaled
// RMS norm, which must not exceed 1 (the step's own tolerance bounds the samples read from it).
template <class S>
bool dense_from_stages(Adaptive method, int n, const S* s, double h, StepWork<S>& work,
                       double rtol, double atol) {
  static_assert(std::is_same<RealOf<S>, double>::value, "the choice is made per run");
  if (method == Adaptive::Rk45) return false;
  const Tableau& tab = tableau(method);
  auto& k = work.k;
  double total = 0.0;
  for (int i = 0; i < n; ++i) {
    double estimate = 0.0;
    for (int stage = 0; stage <= tab.n_stages; ++stage)
      estimate += tab.free_check[stage] * value(k[stage][i]);
    double sc = atol + rtol * first_max(std::fabs(value(s[i])), std::fabs(value(work.end[i])));
    double r = h * estimate / sc;
    total += r * r;
  }
  if (!(std::sqrt(total / n) <= 1.0)) return false;  // also when NaN
  for (int r = 0; r < 7; ++r)
    for (int i = 0; i < n; ++i) {
      S sum = S(0.0);
      for (int stage = 0; stage <= tab.n_stages; ++stage) sum += tab.free_f[r][stage] * k[stage][i];
      work.dense[r][i] = h * sum;
    }
  return true;
}

// The state at t₀ + θh, θ ∈ [0, 1], of the step from s whose interpolant is in `dense`:
// rk45 y = s + h Σ_{j<4} θ^(j+1) Q_j; dop853 y = s + θ(F₀ + (1−θ)(F₁ + θ(F₂ + (1−θ)(F₃
// + θ(F₄ + (1−θ)(F₅ + θF₆)))))) (h is already inside the F's).
template <class S>
void dense_eval(Adaptive method, int n, const std::vector<std::vector<S>>& dense, const S* s,
                const RealOf<S>& h, const RealOf<S>& theta, S* y_out) {
  using Real = RealOf<S>;
  if (method == Adaptive::Rk45) {
    for (int i = 0; i < n; ++i) y_out[i] = S(0.0);
    Real power = Real(1.0);
    for (int j = 0; j < 4; ++j) {
      power *= theta;
      for (int i = 0; i < n; ++i) y_out[i] += dense[j][i] * power;
    }
    for (int i = 0; i < n; ++i) y_out[i] = h * y_out[i] + s[i];
    return;
  }
  const Real one_minus = 1.0 - theta;
  for (int i = 0; i < n; ++i) {
    S y = S(0.0);
    for (int r = 6; r >= 0; --r) {
      y += dense[r][i];
      y *= (6 - r) % 2 == 0 ? theta : one_minus;
    }
    y_out[i] = y + s[i];
  }
}

// h, moved by ulps, so that t + h rounds to t_end exactly (t_end − t rounded may miss it by one;
// a step that ended an ulp short of a bound would leave a step of 1e-18 s).
inline double step_to(double t, double t_end, double h) {
  for (int i = 0; i < 4; ++i) {
    if (t + h < t_end)
      h = std::nextafter(h, std::numeric_limits<double>::infinity());
    else if (t + h > t_end)
      h = std::nextafter(h, -std::numeric_limits<double>::infinity());
    else
      break;
  }
  return h;
}

// What `accepted_step` did: the step taken and the next to try (s), its right-hand sides and
// rejected tries. h = −1 when the step fell below 10 spacings of t (the state unchanged; h_next
// then holds the step that was tried, NaN after a stage overflowed).
struct AcceptedStep {
  double h = 0, h_next = 0;
  int evaluations = 0, rejections = 0;
};

// Steps from (t, s) with f(s) in work.f_start, shrinking the step from h_abs until one is
// accepted, never past t_bound: the new state in work.end, f(y₁) in work.f_end (evaluated
// last), the stages in work.k.
template <class S, class F>
AcceptedStep accepted_step(Adaptive method, F& f, const S* s, double t, double h_abs,
                           double t_bound, double rtol, double atol, StepWork<S>& work) {
  const int n = f.size();
  const double min_step =
      10.0 * std::fabs(std::nextafter(t, std::numeric_limits<double>::infinity()) - t);
  const bool end_first = error_needs_end_derivative(method);
  const int stage_calls = tableau(method).n_stages - 1;
  AcceptedStep result;
  bool retried = false;
  while (true) {
    if (!(h_abs >= min_step)) {  // a NaN step too (from a NaN error norm): fails, never loops
      result.h = -1.0;
      result.h_next = h_abs;
      return result;
    }
    double t_new = first_min(t + h_abs, t_bound);
    if (t + 1.01 * h_abs >= t_bound)  // (never with t_bound = inf)
      t_new = t_bound;  // not a remainder under 1 % of a step left for a step of its own
    double h = t_new - t;
    if (t_new == t_bound) h = step_to(t, t_bound, h);  // cut at the bound: t + h is it exactly
    stages(method, f, s, h, work);
    result.evaluations += stage_calls;
    if (end_first) {
      end_derivative(method, f, work);
      result.evaluations += 1;
    }
    error_estimates(method, n, h, work);
    double norm = error_norm(method, n, s, work, rtol, atol);
    double h_next = next_step(method, norm, std::fabs(h), retried);
    if (norm < 1.0) {  // a NaN norm (an overflow in a stage) rejects the step
      if (!end_first) {
        end_derivative(method, f, work);
        result.evaluations += 1;
      }
      result.h = h;
      result.h_next = h_next;
      return result;
    }
    h_abs = h_next;
    retried = true;
    result.rejections += 1;
  }
}

}  // namespace mms
