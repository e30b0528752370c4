// The adaptive engine: rk45 and dop853 (runge_kutta.hpp, adaptive_solve.hpp) with error control,
// advancing a run to a target time (or through sample times) with every step, crossing check,
// event location on the step's dense output, impact, rest and release, the Zeno guard and the
// crawl limits inside (their records: engine/adaptive_stepping.py, engine/step_watch.py).
//
// One solve runs from its start until a discontinuity (an impact, a release, a command change:
// `restart`); the step is never cut at a target or a sample. The last accepted step stays in hand:
// targets inside it are read from its dense output, built only when a target, a sample or an
// event lies in the step. An event found in the step ends the solve there: it is applied once a
// target passes it, and the solve restarts from the event, trying the length of the step that
// held it. The simulated time is clock[CLOCK_T0] (CLOCK_K stays 0).
//
// The crawl limits (engine/step_watch.py): an adaptive method that cannot follow the solution
// shrinks its step towards the spacing of numbers and crawls on; FLOOR_STEPS accepted steps in a
// row shorter than STEP_FLOOR × max(1 s, t), or BUDGET_STEPS steps that advance time by less
// than BUDGET_SPAN, end the call with CRAWLING.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include "adaptive_solve.hpp"
#include "stepping.hpp"

namespace mms {

constexpr double STEP_FLOOR = 1e-12;  // of max(1 s, t)
constexpr int FLOOR_STEPS = 50;
constexpr int BUDGET_STEPS = 5000;
constexpr double BUDGET_SPAN = 0.01;  // s of simulated time per BUDGET_STEPS steps
// watch[...]: steps in a row below the floor; start (s) and steps of the budget's window
enum WatchEntry { WATCH_SHORT, WATCH_MARK, WATCH_STEPS };

// After an accepted step h (s) from t_before (s): true when the solver is crawling.
inline bool watch_step(double* watch, double t_before, double h) {
  if (std::isnan(watch[WATCH_MARK])) watch[WATCH_MARK] = t_before;
  watch[WATCH_STEPS] += 1.0;
  bool short_step = h < STEP_FLOOR * std::max(1.0, std::fabs(t_before));
  watch[WATCH_SHORT] = short_step ? watch[WATCH_SHORT] + 1.0 : 0.0;
  if (watch[WATCH_SHORT] >= FLOOR_STEPS) return true;
  if (watch[WATCH_STEPS] >= BUDGET_STEPS) {
    if (t_before + h - watch[WATCH_MARK] < BUDGET_SPAN) return true;
    watch[WATCH_MARK] = t_before + h;
    watch[WATCH_STEPS] = 0.0;
  }
  return false;
}

// The run's right-hand side as the methods step it: counted, the holding forces watched.
struct RunRhs {
  Run& run;
  int size() const { return run.size; }
  void operator()(const double* x, double* dx) const { derivative(run, x, dx); }
};

// An adaptive step's path for the events: its dense output from its start.
struct DensePath {
  const Solve<double>& solve;
  int n;
  void operator()(double h, double* out) const { interpolate(solve, n, h, out); }
};

enum StepEvent { NO_EVENT, IMPACT, LEAVE };

// The solve of an adaptive run and the first event of its step in hand. An outside solver's run
// (SciPy's radau and bdf, stepped from Python) hands its steps in (`hand_in_step`): its solve
// only holds the step in hand, whose interpolant is a power series in solve.work.dense.
struct AdaptiveRun {
  Solve<double> solve;
  bool outside;  // the steps are handed in (`hand_in_step`), never taken here
  StepEvent event = NO_EVENT;
  double event_h = 0;  // s into the step
  int event_k = 0, event_side = 0;  // an impact's rod (1-based) and stop (−1 lower, +1 upper)
  std::vector<double> event_state;  // the state at the event (l_k exactly at the stop)
  double* watch;  // (3) the crawl limits' count (WatchEntry), Python's
  AdaptiveRun(Adaptive method, int n, double rtol, double atol, double* watch_,
              bool outside_ = false)
      : solve(method, n, rtol, atol), outside(outside_), event_state(n), watch(watch_) {}
};

// `body(path)` on the step in hand's path (events.hpp): its dense output, or the power series
// an outside solver handed in.
template <class Body>
inline void on_path(const Run& run, const AdaptiveRun& a, Body&& body) {
  if (a.outside) {
    PowerSeries path{a.solve.work.dense, a.solve.start.data(), a.solve.h, run.size};
    body(path);
  } else {
    DensePath path{a.solve, run.size};
    body(path);
  }
}

// The step in hand's dense output, built on first use (an outside solver's came with its step).
inline void interpolant(Run& run, AdaptiveRun& a, bool for_events) {
  RunRhs f{run};
  if (!a.outside) interpolant(a.solve, f, for_events);
}

// A discontinuity at the current (t, s): the next step starts a new solve there.
inline void restart(AdaptiveRun& a) {
  restart(a.solve);
  a.event = NO_EVENT;
}

// The first event in the step in hand: a watched rod reaching a stop, or the instant a resting
// rod's stop would start to pull, whichever comes first (the other is found again by the solve
// restarted there).
inline void locate_event(Run& run, AdaptiveRun& a) {
  Solve<double>& solve = a.solve;
  const double* start = solve.start.data();
  const double h = solve.h;
  // every evaluation of the step sampled the holding forces: read before the interpolant's
  // stages evaluate anything else
  const bool pulled = any_resting(run) && run.system.holding[HOLDING_LEAST_MARGIN] < 0.0;
  if (any_watched(run) && crossing_in_step(run, start, solve.work.end.data(), h)) {
    interpolant(run, a, true);
    on_path(run, a, [&](auto& path) {
      Crossing hit = first_crossing(run, path, start, h);
      if (hit.k != 0) {
        path(hit.h, a.event_state.data());
        a.event_state[q_slide(hit.k)] =
            run.stops.stroke[2 * (hit.k - 1) + (hit.side < 0 ? 0 : 1)];
        a.event = IMPACT;
        a.event_h = hit.h;
        a.event_k = hit.k;
        a.event_side = hit.side;
      }
    });
  }
  if (pulled) {
    interpolant(run, a, true);
    on_path(run, a, [&](auto& path) {
      double h_leave = first_release(run, path, start, h);
      if (h_leave >= 0.0 && (a.event == NO_EVENT || h_leave < a.event_h)) {
        path(h_leave, a.event_state.data());
        a.event = LEAVE;
        a.event_h = h_leave;
      }
    });
  }
}

// One accepted step after the step in hand (or starting a new solve at (t, s)), its first event
// located. DONE, NOT_FINITE (the bad state in run.step.out), STALLED or CRAWLING.
inline Status take_step(Run& run, AdaptiveRun& a, const double* s, double* clock) {
  Solve<double>& solve = a.solve;
  RunRhs f{run};
  begin_step(solve, f, clock[CLOCK_T0], s);
  clear_holding(run);
  // no step across an update of sampled controllers (their held efforts jump there)
  SolveStatus status = finish_step(solve, f, next_update(run, clock[CLOCK_UPDATES]));
  if (status == SolveStatus::Stalled) return STALLED;
  clock[CLOCK_STEPS] += 1.0;
  a.event = NO_EVENT;
  if (status == SolveStatus::NotFinite) {
    std::copy(solve.work.end.begin(), solve.work.end.end(), run.step.out);
    return NOT_FINITE;
  }
  if (watch_step(a.watch, solve.t0, solve.h)) return CRAWLING;
  locate_event(run, a);
  return DONE;
}

// Move (t, s) to the event of the step in hand, apply it, and restart the solve there.
inline void apply_event(Run& run, AdaptiveRun& a, double* s, double* clock) {
  const double t = a.solve.t0 + a.event_h;
  std::copy(a.event_state.begin(), a.event_state.end(), s);
  clock[CLOCK_T0] = t;
  if (a.event == IMPACT)
    book(clock, impact(run, s, a.event_k, a.event_side, t));
  else
    release(run, s, true);
  restart(a);
}

inline bool inside_step(Run& run, AdaptiveRun& a, double* s, double* clock, double t_end) {
  bool inside = false;
  on_path(run, a, [&](const auto& path) {
    inside = inside_step(a.solve, run.size, clock[CLOCK_T0], s, t_end,
                         a.event != NO_EVENT ? &a.event_h : nullptr, path);
  });
  return inside;
}

// Move (t, s) to t_end inside the step in hand, or to its event when t_end lies past it (which is
// then applied): true when (t, s) is at t_end, false when a new step is needed.
inline bool reach(Run& run, AdaptiveRun& a, double* s, double* clock, double t_end) {
  if (inside_step(run, a, s, clock, t_end)) return true;
  const Solve<double>& solve = a.solve;
  if (solve.h <= 0.0) return false;
  if (a.event != NO_EVENT) {
    if (t_end > solve.t0 + a.event_h) {
      apply_event(run, a, s, clock);
      return false;
    }
  } else if (t_end > solve.t0 + solve.h) {
    return false;
  }
  interpolant(run, a, false);  // t_end is inside: build what `inside_step` reads
  return inside_step(run, a, s, clock, t_end);
}

// --- an outside solver's steps (SciPy's radau and bdf, engine/scipy_steps.py): each one handed in
// as the step in hand; `locate_event`, `reach` and `apply_event` do the rest, as for rk45 and
// dop853 (engine/scipy_steps.py hands them in).

// The outside solver's next step starts at (t0, y0).
inline void begin_handed_step(Run& run, AdaptiveRun& a, double t0, const double* y0) {
  a.solve.t0 = t0;
  std::copy(y0, y0 + run.size, a.solve.start.begin());
}

// Its step of length h (s) as the step in hand: its end state y1 and its interpolant's power
// series (rows ≤ kMaxDense rows of run.size coefficients, `PowerSeries`), no event located yet.
inline void hand_in_step(Run& run, AdaptiveRun& a, double h, const double* y1,
                         const double* series, int rows) {
  Solve<double>& solve = a.solve;
  std::copy(y1, y1 + run.size, solve.work.end.begin());
  for (int j = 0; j < kMaxDense; ++j)
    for (int i = 0; i < run.size; ++i)
      solve.work.dense[j][i] = j < rows ? series[j * run.size + i] : 0.0;
  solve.h = h;
  solve.dense = DenseKind::Full;
  a.event = NO_EVENT;
}

// f(y₁) of the step in hand, counted and watched: the release check reads the holding forces
// at the step's end as at its other evaluations.
inline void step_end_derivative(Run& run, AdaptiveRun& a) {
  derivative(run, a.solve.work.end.data(), a.solve.work.f_end.data());
}

// Advance (t, s) to exactly t_end with no update due before it. DONE, or BUDGET after max_steps
// steps, LOG_FULL, NOT_FINITE, STALLED, CRAWLING, CONTACT_FAILED.
inline Status advance_between_updates(Run& run, AdaptiveRun& a, double* s, double* clock,
                                      double t_end, long max_steps) {
  const long room = run.stops.capacity / 2;
  long taken = 0;
  while (!reach(run, a, s, clock, t_end)) {
    if (run.stops.failed[0] != 0) return CONTACT_FAILED;
    if (taken >= max_steps) return BUDGET;
    if (run.stops.count[0] > room) return LOG_FULL;
    Status status = take_step(run, a, s, clock);
    if (status != DONE) return status;
    ++taken;
  }
  return DONE;
}

// Advance (t, s) to exactly t_end, the sampled controllers updated on the way (the steps end
// there and the solve restarts there).
inline Status advance(Run& run, AdaptiveRun& a, double* s, double* clock, double t_end,
                      long max_steps) {
  sync_locks(run);
  return advance_with_updates(
      run, s, clock, t_end, max_steps,
      [&](double t_stop, long budget) {
        return advance_between_updates(run, a, s, clock, t_stop, budget);
      },
      [&] { restart(a); });
}

// `advance` to each of times[first:], writing (s, T + V) into rows[i]; the budget counts steps
// only (a sample inside the step in hand costs none).
inline Sampled advance_samples(Run& run, AdaptiveRun& a, double* s, double* clock,
                               const double* times, long n_times, double* rows, long first,
                               long max_steps) {
  const double steps = clock[CLOCK_STEPS];
  for (long i = first; i < n_times; ++i) {
    Status status = advance(run, a, s, clock, times[i],
                            max_steps - long(clock[CLOCK_STEPS] - steps));
    if (status != DONE) return {status, i};
    double* row = rows + i * (run.size + 1);
    std::copy(s, s + run.size, row);
    row[run.size] = total_energy(run, s);
  }
  return {DONE, n_times};
}

}  // namespace mms
