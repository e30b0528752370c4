// The fixed-step engine: advance a run to a target time (or through sample times) with every
// step, crossing check, event location, impact, rest and release inside, and the updates of
// sampled controllers (docs/controllers.md, "The control rate"). The time line: t = t0 + k·dt
// with an integer step
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

// --- sampled controllers: the wheel-speed loop and the arm controller updated at the control
// rate, as ros2_control's controller manager runs them at its update_rate and the hardware holds
// each command until the next update. An update is a discrete map at t_m = m / rate, outside the
// right-hand side, which only reads what it left (system.held): τ_m = sat(law(s(t_m))) held until
// t_{m+1}, each integral advanced by one forward-Euler step of its rate, or not at all while the
// output is saturated in the error's direction (control_toolbox's Pid::compute_command with its
// conditional integration: i_term += dt · i_gain · error after the command); then, as at a command
// change, a resting rod the new efforts pull is released. The steps end at every update (a step
// boundary, as a command change is; the adaptive solves restart there). The count of updates
// applied is the clock's (CLOCK_UPDATES). A call that ends at an update instant leaves that update
// to the next call, which applies it first: a command given between the calls, at the instant, is
// taken at that update, as ros2_control reads its commands in the update. A rate of 0 keeps the
// continuous controllers: no update, no hold.

// The instant (s) of the next update after `updates` of them; +inf when continuous, or when no
// controller drives (the arm in effort mode, the wheels under torque commands): such a run is not
// cut at updates.
inline double next_update(const Run& run, double updates) {
  if (run.system.rate > 0.0 && (run.arm_on() || run.velocity_mode()))
    return updates / run.system.rate;
  return std::numeric_limits<double>::infinity();
}

// The update at the current instant (the clock not counted): the controllers' outputs into
// system.held (the arm's evaluation into arm.last too), their integrals in s advanced by one
// period of their rates; a resting rod pulled off its stop released. CONTACT_FAILED when that
// release's contact solve failed, else DONE.
inline Status update_controllers(Run& run, double* s) {
  const double period = 1.0 / run.system.rate;
  const int nq = run.n_q(), nu = run.n_u(), e = nq + nu;
  double* held = run.system.held;
  for (int k = 0; k < nu; ++k) run.ws.Q[k] = run.system.Q_cmd[k];
  if (run.velocity_mode()) {
    const double r = run.model.base.wheel_radius, b = run.model.base.half_track;
    double rate_R, rate_L;
    wheels_drive(run.model, wheel_loop(run.system.control), s, false, held[0], held[1], rate_R,
                 rate_L);
    s[e] += period * rate_R;
    s[e + 1] += period * rate_L;
    run.ws.Q[V] = (held[0] + held[1]) / r;
    run.ws.Q[OMEGA] = b * (held[0] - held[1]) / r;
  }
  if (run.arm_on()) {  // the law itself (not its held efforts), its rates into `trial`
    double* rates = run.step.trial;
    frames(run.model, s, run.ws.dynamics);
    arm_efforts(run.model, run.arm, run.system.gravity, run.system.damping, s, rates,
                run.ws.Q.data(), run.ws.dynamics, run.ws.arm);
    const int i_z = arm_integrals_index(run.model);
    for (int j = 0; j < nu - 2; ++j) {
      held[2 + j] = run.ws.Q[2 + j];
      s[i_z + j] += period * rates[i_z + j];
    }
  }
  if (any_resting(run) && holding_margin(run, s, run.stage(3)) < 0.0) release(run, s, false);
  return run.stops.failed[0] != 0 ? CONTACT_FAILED : DONE;
}

// The update due now, counted on the clock.
inline Status apply_update(Run& run, double* s, double* clock) {
  clock[CLOCK_UPDATES] += 1.0;
  return update_controllers(run, s);
}

// `advance` (either engine's, `between` the updates) with the sampled controllers updated on the
// way at each of their instants before t_end; `after_update` is what the engine does once an
// update is applied (the adaptive solves restart). An update due at t_end is left to the next
// call, whose first stretch is empty and ends at it: it is applied after the commands set
// between the calls (a command given at an update instant is taken at that update).
template <class Between, class AfterUpdate>
inline Status advance_with_updates(Run& run, double* s, double* clock, double t_end,
                                   long max_steps, Between&& between, AfterUpdate&& after_update) {
  if (run.system.rate <= 0.0) return between(t_end, max_steps);
  const double steps = clock[CLOCK_STEPS];
  while (true) {
    double t_update = next_update(run, clock[CLOCK_UPDATES]);
    bool due = t_update < t_end;
    Status status = between(t_update < t_end ? t_update : t_end,
                            max_steps - long(clock[CLOCK_STEPS] - steps));
    if (status == DONE && due) {
      status = apply_update(run, s, clock);
      after_update();
    }
    if (status != DONE || !due) return status;
  }
}

inline void book(double* clock, const ImpactEnergies& e) {
  clock[CLOCK_LOST] += e.lost;
  clock[CLOCK_HELD] += e.removed;
  clock[CLOCK_HOLDS] += e.held;
}

// A stage (or the step's end, whose holding margin `margin_at_end()` gives, f(end) into the
// first stage) saw a resting rod's stop pull.
template <class Margin>
inline bool pull_seen_with(Run& run, Margin&& margin_at_end) {
  return any_resting(run) &&
         (margin_at_end() < 0.0 || run.system.holding[HOLDING_LEAST_MARGIN] < 0.0);
}
inline bool pull_seen(Run& run, const double* end) {
  return pull_seen_with(run, [&] { return holding_margin(run, end, run.stage(0)); });
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
  EventScript* script = run.script;
  if (script != nullptr) {
    script->moving = run.ws.dynamics.moving;
    script->events.clear();
  }
  // what a recorded event needs of the run as it was before it (the run's derivative replays it)
  auto record = [&](int kind, double h_event, int rod, int side) {
    if (script == nullptr) return;
    RecordedEvent event;
    event.kind = kind;
    event.h = h_event;
    event.rod = rod;
    event.side = side;
    event.resting.assign(run.stops.resting, run.stops.resting + n);
    script->events.push_back(event);
  };
  auto locks_after = [&] {
    if (script != nullptr) script->events.back().moving = run.ws.dynamics.moving;
  };
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
      if (script != nullptr) script->last_stretch = true;
      return DONE;
    }
    if (hit.k == 0 || (0.0 <= h_leave && h_leave < hit.h)) {
      // a resting rod is pulled off its stop: released at that instant, not a step later
      step_state(run, path, s, h_leave, trial);
      std::copy(trial, trial + run.size, s);
      record(RELEASE, h_leave, 0, 0);
      h -= h_leave;
      t += h_leave;
      release(run, s, true);
      if (run.stops.failed[0] != 0) return CONTACT_FAILED;
      locks_after();
    } else {
      if (run.stops.count[0] + n > capacity) return CHATTER;  // the log is full within one step
      step_state(run, path, s, hit.h, trial);
      std::copy(trial, trial + run.size, s);
      s[q_slide(hit.k)] = run.stops.stroke[2 * (hit.k - 1) + (hit.side < 0 ? 0 : 1)];
      record(CROSSING, hit.h, hit.k, hit.side);
      h -= hit.h;
      t += hit.h;
      book(clock, impact(run, s, hit.k, hit.side, t));
      if (run.stops.failed[0] != 0) return CONTACT_FAILED;
      locks_after();
    }
    if (h <= 1e-15 * dt) {
      if (script != nullptr) script->last_stretch = false;
      return DONE;
    }
  }
  return CHATTER;
}

// What a whole grid step does once its step s → run.step.out is taken (`run_step` here, or a
// vector block of lanes, lanes.hpp, which gives the holding margin at the end as
// `margin_at_end`): a non-finite end, a crossing or a pull turns it into the step with its
// events; else the end is taken. k1_ready says on return whether the first stage now holds
// f(s) for the next step (the release check computed it).
template <class Margin>
inline Status grid_step_end(Run& run, Method method, double* s, double* clock, bool& k1_ready,
                            Margin&& margin_at_end) {
  const double dt = clock[CLOCK_DT];
  const double t = clock[CLOCK_T0] + clock[CLOCK_K] * dt;
  double* out = run.step.out;
  k1_ready = false;
  if (!finite(out, run.size)) return NOT_FINITE;
  // the holding forces need f(out), the next step's first stage: computed once
  if ((any_watched(run) && crossing_in_step(run, s, out, dt)) ||
      pull_seen_with(run, margin_at_end))
    return step_with_events(run, method, s, dt, t, clock);
  std::copy(out, out + run.size, s);
  k1_ready = any_resting(run);
  return DONE;
}

// One whole step dt on the grid, events and releases included. Returns the status; k1_ready says
// on entry whether the first stage holds f(s), and on return whether it does for the next step.
inline Status grid_step(Run& run, Method method, double* s, double* clock, bool& k1_ready) {
  clear_holding(run);
  run_step(run, method, s, clock[CLOCK_DT], run.step.out, k1_ready);
  return grid_step_end(run, method, s, clock, k1_ready,
                       [&] { return holding_margin(run, run.step.out, run.stage(0)); });
}

// Advance s to exactly t_end with no update due before it. DONE, or BUDGET after max_steps
// steps, LOG_FULL when the impact log needs emptying, NOT_FINITE (s then holds the last finite
// state), CHATTER, CONTACT_FAILED.
inline Status advance_between_updates(Run& run, Method method, double* s, double* clock,
                                      double t_end, long max_steps) {
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

// Advance s to exactly t_end, the sampled controllers updated on the way (a step ends there).
inline Status advance(Run& run, Method method, double* s, double* clock, double t_end,
                      long max_steps) {
  sync_locks(run);
  return advance_with_updates(
      run, s, clock, t_end, max_steps,
      [&](double t_stop, long budget) {
        return advance_between_updates(run, method, s, clock, t_stop, budget);
      },
      [] {});
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
