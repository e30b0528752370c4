// The adaptive methods' solve (runge_kutta.hpp) as a loop can drive it: one accepted step at a
// time, the last one kept *in hand* (its start y₀, stages, y₁, f(y₀), f(y₁)), its dense output
// read at any instant inside it, and a restart that drops it at a discontinuity, without the
// events (stops, impacts, releases, holds: adaptive_stepping.hpp adds them):
//
//   take_step      the next accepted step after the one in hand (FSAL: it starts from y₁ with
//                  f(y₁)), or the first of a new solve at (t, s), with `initial_step`'s size
//                  unless a restart left one to try
//   interpolant    the step's dense output, built on first use (dop853: from the step's stages
//                  when that is accurate enough, else with 3 more right-hand sides; an event
//                  locator asks for the full one)
//   interpolate    the state h' (s) into the step in hand
//   restart        a discontinuity at the current (t, s): the next step starts a new solve
//                  there, trying the length of the last step taken
//   advance        (t, s) to exactly t_end: never cutting a step at a target, read from the dense
//                  output when it lies inside the step in hand
//
// Its time line is the caller's (t, s): t only moves to the targets `advance` reaches.
#pragma once

#include <cmath>
#include <limits>
#include <vector>

#include "runge_kutta.hpp"

namespace mms {

enum class DenseKind { None, Full, FromStages };
enum class SolveStatus { Done, Budget, Stalled, NotFinite };

template <class S>
struct Solve {
  Adaptive method;
  double rtol, atol;       // per component of s, in its own units
  double t0 = 0;           // s: start of the step in hand
  double h = 0;            // s: its length; 0: none in hand, the next step starts a new solve
  double h_next = 0;       // s: the next step to try; 0: `initial_step` picks one
  DenseKind dense = DenseKind::None;  // the step in hand's interpolant, once built
  std::vector<S> start;    // y₀ of the step in hand
  StepWork<S> work;        // its stages, y₁, f(y₀), f(y₁), interpolant
  long steps = 0, evaluations = 0, rejections = 0;  // accepted steps, right-hand sides, retries
  Solve(Adaptive m, int n, double rtol_, double atol_)
      : method(m), rtol(rtol_), atol(atol_), start(n), work(n) {}
};

template <class S>
void restart(Solve<S>& solve) {
  if (solve.h > 0.0) solve.h_next = solve.h;
  solve.h = 0.0;
}

// The start of the next step: after the step in hand (FSAL: from y₁ with f(y₁)), or a new solve
// at (t, s) with f(s) evaluated and, unless a restart left one to try, `initial_step`'s size.
template <class S, class F>
void begin_step(Solve<S>& solve, F& f, double t, const S* s) {
  const int n = f.size();
  StepWork<S>& work = solve.work;
  const double inf = std::numeric_limits<double>::infinity();
  if (solve.h > 0.0) {
    solve.t0 += solve.h;
    solve.start = work.end;
    work.f_start = work.f_end;  // FSAL: f(y₁) is the next step's first stage
  } else {
    solve.t0 = t;
    solve.start.assign(s, s + n);
    f(solve.start.data(), work.f_start.data());
    solve.evaluations += 1;
    if (solve.h_next <= 0.0) {
      solve.h_next = initial_step(solve.method, f, solve.start.data(), work.f_start.data(), inf,
                                  solve.rtol, solve.atol, inf, work.end.data(),
                                  work.f_end.data());
      solve.evaluations += 1;
    }
  }
}

// The accepted step from the start `begin_step` set, never past t_bound. NotFinite leaves the bad y₁ in
// solve.work.end; Stalled (the step fell below 10 spacings of t) leaves no step in hand and the
// step tried in solve.h_next.
template <class S, class F>
SolveStatus finish_step(Solve<S>& solve, F& f,
                        double t_bound = std::numeric_limits<double>::infinity()) {
  const int n = f.size();
  StepWork<S>& work = solve.work;
  AcceptedStep step = accepted_step(solve.method, f, solve.start.data(), solve.t0, solve.h_next,
                                    t_bound, solve.rtol, solve.atol, work);
  solve.evaluations += step.evaluations;
  solve.rejections += step.rejections;
  if (step.h < 0.0) {
    solve.h = 0.0;
    solve.h_next = step.h_next;
    return SolveStatus::Stalled;
  }
  solve.steps += 1;
  solve.h = step.h;
  solve.h_next = step.h_next;
  solve.dense = DenseKind::None;
  for (int i = 0; i < n; ++i)
    if (!std::isfinite(value(work.end[i]))) return SolveStatus::NotFinite;
  return SolveStatus::Done;
}

// The next accepted step (see the header).
template <class S, class F>
SolveStatus take_step(Solve<S>& solve, F& f, double t, const S* s) {
  begin_step(solve, f, t, s);
  return finish_step(solve, f);
}

// The step in hand's dense output, built on first use (see the header).
template <class S, class F>
void interpolant(Solve<S>& solve, F& f, bool for_events) {
  if (solve.dense == DenseKind::Full ||
      (solve.dense == DenseKind::FromStages && !for_events))
    return;
  const int n = f.size();
  if (!for_events && dense_from_stages(solve.method, n, solve.start.data(), solve.h, solve.work,
                                       solve.rtol, solve.atol)) {
    solve.dense = DenseKind::FromStages;
    return;
  }
  solve.evaluations +=
      dense_prepare(solve.method, f, solve.start.data(), solve.h, solve.work);
  solve.dense = DenseKind::Full;
}

// The state h_into (s) into the step in hand, whose interpolant is built, into out.
template <class S>
void interpolate(const Solve<S>& solve, int n, double h_into, S* out) {
  dense_eval(solve.method, n, solve.work.dense, solve.start.data(), solve.h, h_into / solve.h,
             out);
}

// Move (t, s) to t_end when it lies in the step in hand — up to its event, when `event_h` points
// at one's instant into the step — and its interpolant is built (or t_end is the step's end):
// true; otherwise false, nothing changed. `path(h', out)` reads the interpolant: the solve's own
// dense output, or the power series an outside solver handed in (adaptive_stepping.hpp).
template <class S, class Path>
bool inside_step(Solve<S>& solve, int n, double& t, S* s, double t_end, const double* event_h,
                 const Path& path) {
  if (t_end <= t) return true;
  if (solve.h <= 0.0 || t_end > solve.t0 + (event_h ? *event_h : solve.h)) return false;
  if (t_end == solve.t0 + solve.h && !event_h) {
    for (int i = 0; i < n; ++i) s[i] = solve.work.end[i];  // the step's end, exactly
  } else if (solve.dense == DenseKind::None) {
    return false;
  } else {
    path(t_end - solve.t0, s);
  }
  t = t_end;
  return true;
}

template <class S>
bool inside_step(Solve<S>& solve, int n, double& t, S* s, double t_end,
                 const double* event_h = nullptr) {
  return inside_step(solve, n, t, s, t_end, event_h,
                     [&](double h_into, S* out) { interpolate(solve, n, h_into, out); });
}

// Move (t, s) to t_end inside the step in hand: true; false when a new step is needed.
template <class S, class F>
bool reach(Solve<S>& solve, F& f, double& t, S* s, double t_end) {
  const int n = f.size();
  if (inside_step(solve, n, t, s, t_end)) return true;
  if (solve.h <= 0.0 || t_end > solve.t0 + solve.h) return false;
  interpolant(solve, f, false);  // t_end is inside: build what inside_step reads
  return inside_step(solve, n, t, s, t_end);
}

// Advance (t, s) to exactly t_end (s), taking at most max_steps steps (Budget: call again).
template <class S, class F>
SolveStatus advance(Solve<S>& solve, F& f, double& t, S* s, double t_end, long max_steps) {
  long taken = 0;
  while (!reach(solve, f, t, s, t_end)) {
    if (taken >= max_steps) return SolveStatus::Budget;
    SolveStatus status = take_step(solve, f, t, s);
    if (status != SolveStatus::Done) return status;
    ++taken;
  }
  return SolveStatus::Done;
}

}  // namespace mms
