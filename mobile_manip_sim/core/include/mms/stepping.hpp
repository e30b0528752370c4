// The fixed-step engine: advance a run to a target time (or through sample times) with every
// step, crossing check, event location, impact, rest and release inside (engine/stepping.py is
// the reference, operation for operation). The time line: t = t0 + k·dt with an integer step
// count k (long runs land exactly on k·dt); a target off that grid ends in one shorter step,
// after which the grid restarts there. A call returns after `max_steps` steps (BUDGET) so that
// the caller can act on signals, and when the impact log needs emptying (LOG_FULL).
#pragma once

#include <cmath>

#include "events.hpp"

namespace mms {

inline bool finite(const double* s, int n) {
  for (int i = 0; i < n; ++i)
    if (!std::isfinite(s[i])) return false;
  return true;
}

inline void book(double* clock, const ImpactEnergies& e) {
  clock[CLOCK_LOST] += e.lost;
  clock[CLOCK_HELD] += e.removed;
  clock[CLOCK_HOLDS] += e.held;
}

inline bool pull_seen(Run& run, const double* end) {
  return any_resting(run) && (holding_margin(run, end, run.stage(0)) < 0.0 ||
                              run.system.holding[HOLDING_LEAST_MARGIN] < 0.0);
}

// One step of length h from time t in which end stops may be hit and resting rods leave them,
// again and again: the first event in what is left of the step is located on the integrator's
// own step, applied there, and the step goes on from it. CHATTER when the impact log has no
// room for the next impact.
inline Status step_with_events(Run& run, Method method, double* s, double h, double t,
                               double* clock) {
  const double dt = clock[CLOCK_DT];
  const int capacity = run.stops.capacity, n = run.n();
  double* out = run.step.out;
  double* trial = run.step.trial;
  for (int i = 0; i < 2 * capacity; ++i) {
    clear_holding(run);
    run_step(run, method, s, h, out);
    if (!finite(out, run.size)) return NOT_FINITE;
    OwnStep path{run, method, s};
    Crossing hit;
    if (any_watched(run) && crossing_in_step(run, s, out, h))
      hit = first_crossing(run, path, s, h);
    double h_leave = -1.0;
    if (pull_seen(run, out))  // a stage (or the end) saw a stop pull: the first pull, located
      h_leave = first_release(run, path, s, h);
    if (hit.k == 0 && h_leave < 0.0) {  // no event (or the Hermite path dipped, the step did not)
      std::copy(out, out + run.size, s);
      return DONE;
    }
    if (hit.k == 0 || (0.0 <= h_leave && h_leave < hit.h)) {
      // a resting rod is pulled off its stop: released at that instant, not a step later
      step_state(run, path, s, h_leave, trial);
      std::copy(trial, trial + run.size, s);
      h -= h_leave;
      t += h_leave;
      release(run, s, true);
      if (run.stops.failed[0] != 0) return CONTACT_FAILED;
    } else {
      if (run.stops.count[0] + n > capacity) return CHATTER;  // the log is full within one step
      step_state(run, path, s, hit.h, trial);
      std::copy(trial, trial + run.size, s);
      s[q_slide(hit.k)] = run.stops.stroke[2 * (hit.k - 1) + (hit.side < 0 ? 0 : 1)];
      h -= hit.h;
      t += hit.h;
      book(clock, impact(run, s, hit.k, hit.side, t));
      if (run.stops.failed[0] != 0) return CONTACT_FAILED;
    }
    if (h <= 1e-15 * dt) return DONE;
  }
  return CHATTER;
}

// One whole step dt on the grid, events and releases included. Returns the status; k1_ready says
// on return whether the first stage now holds f(s) for the next step (the release check
// computed it).
inline Status grid_step(Run& run, Method method, double* s, double* clock, bool& k1_ready) {
  const double dt = clock[CLOCK_DT];
  clear_holding(run);
  const double t = clock[CLOCK_T0] + clock[CLOCK_K] * dt;
  double* out = run.step.out;
  run_step(run, method, s, dt, out, k1_ready);
  k1_ready = false;
  if (!finite(out, run.size)) return NOT_FINITE;
  // the holding forces need f(out), the next step's first stage: computed once
  if ((any_watched(run) && crossing_in_step(run, s, out, dt)) || pull_seen(run, out))
    return step_with_events(run, method, s, dt, t, clock);
  std::copy(out, out + run.size, s);
  k1_ready = any_resting(run);
  return DONE;
}

// Advance s to exactly t_end. DONE, or BUDGET after max_steps steps, LOG_FULL when the impact
// log needs emptying, NOT_FINITE (s then holds the last finite state), CHATTER, CONTACT_FAILED.
inline Status advance(Run& run, Method method, double* s, double* clock, double t_end,
                      long max_steps) {
  sync_locks(run);
  const double dt = clock[CLOCK_DT];
  const double steps = (t_end - clock[CLOCK_T0]) / dt;
  const double whole = std::floor(steps + 1e-9);
  const long room = run.stops.capacity / 2;
  long taken = 0;
  bool k1_ready = false;
  while (clock[CLOCK_K] < whole) {
    if (taken >= max_steps) return BUDGET;
    if (run.stops.count[0] > room) return LOG_FULL;
    Status status = grid_step(run, method, s, clock, k1_ready);
    if (status != DONE) return status;
    clock[CLOCK_K] += 1.0;
    clock[CLOCK_STEPS] += 1.0;
    ++taken;
  }
  if (steps - whole > 1e-9) {  // t_end is off the grid: a last, shorter step
    if (run.stops.count[0] > room) return LOG_FULL;
    double t = clock[CLOCK_T0] + clock[CLOCK_K] * dt;
    Status status = step_with_events(run, method, s, t_end - t, t, clock);
    if (status != DONE) return status;
    clock[CLOCK_STEPS] += 1.0;
    clock[CLOCK_T0] = t_end;
    clock[CLOCK_K] = 0.0;
  }
  return DONE;
}

struct Sampled {
  Status status;
  long next;  // the next sample to take
};

// `advance` to each of times[first:], writing (s, T + V) into rows[i] (row stride size + 1).
inline Sampled advance_samples(Run& run, Method method, double* s, double* clock,
                               const double* times, long n_times, double* rows, long first,
                               long max_steps) {
  long i = first, budget = max_steps;
  while (i < n_times) {
    double before = clock[CLOCK_STEPS];
    Status status = advance(run, method, s, clock, times[i], budget);
    budget -= long(clock[CLOCK_STEPS] - before);
    if (status != DONE) return {status, i};
    double* row = rows + i * (run.size + 1);
    std::copy(s, s + run.size, row);
    row[run.size] = total_energy(run, s);
    ++i;
    if (budget <= 0 && i < n_times) return {BUDGET, i};
  }
  return {DONE, i};
}

}  // namespace mms
