// One simulation's run as the fixed-step engine sees it: the robot, what its scene turns on, its
// locks and resting rods, its end stops and their impact log, and the scratch of its steps.
//
// The arrays are the Python layer's (engine/system.py's SystemData, engine/stops.py's StopsData,
// engine/stepping.py's StepScratch): the engine reads and writes them in place, so everything a
// run is lives where Python reads it between calls (the impact log, the counters, which rods
// rest), and nothing is hidden here but scratch. Sizes: n rods, n_q = 2n + 5, n_u = 2n + 2, the
// state s = (q, u, e, W) of system.hpp.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "system.hpp"

namespace mms {

// counters[...]: the stages actually run (engine/system.py)
enum Counter { RHS_EVALS, DAMPING_STAGE, REDUCED_SOLVE, CROSSING_CHECKS, CONTROL_STAGE,
               ARM_CONTROL_STAGE };
// holding[...]: the resting rods' holding forces watched at every evaluation (`watch_holding`)
enum Holding { HOLDING_ON, HOLDING_LEAST_MARGIN };
// control[...]: the wheel-speed PI loop
enum Control { WHEEL_VELOCITY_MODE, WHEEL_KP, WHEEL_KI, WHEEL_LIMIT_R, WHEEL_LIMIT_L,
               WHEEL_TARGET_R, WHEEL_TARGET_L };
// clock[...]: the time line k·dt from t0, steps taken, the energy ledger of the impacts (the law's
// losses, what holds removed beyond them, how many impacts were held), and how many updates the
// sampled controllers took (the next is due at CLOCK_UPDATES / rate)
enum ClockEntry { CLOCK_T0, CLOCK_DT, CLOCK_K, CLOCK_STEPS, CLOCK_LOST, CLOCK_HELD, CLOCK_HOLDS,
                  CLOCK_UPDATES, CLOCK_ENTRIES };
// why a call returned (engine/status.py)
enum Status { DONE = 0, BUDGET = 1, LOG_FULL = 2, NOT_FINITE = 3, CHATTER = 4, STALLED = 5,
              CRAWLING = 6, CONTACT_FAILED = 7 };
// an impact-log row's columns (engine/impact_log.py)
enum LogColumn { LOG_TIME, LOG_LINK, LOG_SIDE, LOG_LD_BEFORE, LOG_LD_AFTER, LOG_LOST, LOG_RESTING,
                 LOG_HELD, LOG_HOLD_LOST, LOG_HOLD_BOUND, LOG_COLUMNS };
enum StopLawKind { IMPULSE = 0, REFLECT = 1 };

// What a scene turns on, and the state of its commands and locks.
struct SystemArrays {
  double gravity = 0;            // m/s² along −z
  const double* damping = nullptr;  // (n_u) viscous coefficients, or nullptr: no damping stage
  std::int64_t* free = nullptr;  // (n_u) the free pseudo-velocities, padded with −1
  const double* Q_cmd = nullptr; // (n_u) commanded generalized forces
  const double* control = nullptr;  // (7) the wheel-speed loop (Control)
  std::int64_t* counters = nullptr;  // (5, or 6 with an arm controller) Counter
  double* holding = nullptr;     // (2) Holding
  double rate = 0;               // Hz: the controllers' update rate; 0: continuous
  double* held = nullptr;        // (n_u) the efforts sampled controllers hold between updates
                                 // (the wheel-speed loop's τ_R, τ_L first)
};

// The end stops and their log.
struct StopsArrays {
  bool* watched = nullptr;           // (n) a rod's crossings are checked (not while it rests)
  std::int64_t* resting = nullptr;   // (n) −1 / +1 held at its lower / upper stop, 0 free
  const double* stroke = nullptr;    // (n × 2) [min, max] of each l_k, m
  const bool* permanent = nullptr;   // (n_u) locked by the scene
  int law = IMPULSE;
  double restitution = 0, rest_speed = 0;
  double* log = nullptr;             // (capacity × LOG_COLUMNS) one row per rod hit
  double* log_q = nullptr;           // (capacity × n_q) q at each impact
  double* log_u = nullptr;           // (capacity × 2 × n_u) u⁻, u⁺
  bool* log_free = nullptr;          // (capacity × n_u) the free pseudo-velocities at each
  int capacity = 0;
  std::int64_t* count = nullptr;     // (1) rows in use
  double* run = nullptr;             // (n × 2 × RUN_FIELDS) the Zeno guard's record per stop
  std::int64_t* failed = nullptr;    // (1) why the stops failed the run (1: a contact solve)
};

// The steps' scratch (engine/stepping.py's StepScratch).
struct StepArrays {
  double* out = nullptr;      // (size) the step's end
  double* trial = nullptr;    // (size) trial steps of the event functions
  double* stages = nullptr;   // (4 × size) Runge–Kutta stages
  double* forces = nullptr;   // (size) holding forces (first n_u)
  double* samples = nullptr;  // (N_SAMPLES + 2n) instants bracketing a crossing
  std::int64_t* crossed = nullptr;  // (n) the stop each rod is past at the bracket's end
};

// The contact solve an impact's outcome came from: its m contacts (rod, direction σ, restitution
// e) and which were active (for the `reflect` law, the rods reflected).
struct ContactSolution {
  int m = 0;
  std::vector<int> rods;
  std::vector<double> sigma, e;
  std::vector<char> active;
  explicit ContactSolution(int n = 0) : rods(n), sigma(n), e(n), active(n) {}
};

// One event of a step as a double run took it, for the step's derivative (event_jacobians.hpp).
struct RecordedEvent {
  int kind = 0;               // events.hpp's EventKind: CROSSING or RELEASE
  double h = 0;               // s: where it was located, into what was left of the step
  int rod = 0, side = 0;      // CROSSING: the rod whose crossing was located, and its stop
  std::vector<std::int64_t> resting;  // (n) the rods resting before it (their stop's side)
  std::vector<int> hits;      // (n) CROSSING: the stop each rod was hit at (0: none)
  ContactSolution solution;   // CROSSING: the impact's outcome
  std::vector<double> moving; // (n_u) the locks for what is left of the step
};

// The events of one step (`step_with_events` records them where Run::script is set).
struct EventScript {
  std::vector<double> moving;  // (n_u) the locks at the step's start
  std::vector<RecordedEvent> events;
  bool last_stretch = true;    // the step went on after its last event (else it ended there)
};

// An impact's and a release's scratch, owned here.
struct ImpactScratch {
  std::vector<double> M, L;          // (n_u × n_u) the mass matrix, its factor
  std::vector<double> unit;          // (n_u) a contact's direction
  std::vector<int> free;             // (n_u) the DOFs free in a contact solve
  std::vector<int> rods, hits, index;  // (n) rods in contact, the stop each meets, active set
  std::vector<char> bilateral, active;  // (n)
  std::vector<double> sigma, e, c_minus, qv, P, w;  // (n) per contact
  std::vector<double> MinvE;         // (n × n_u) M⁻¹E, one row per contact
  std::vector<double> W;             // (n × n) the Delassus matrix
  std::vector<double> cholesky;      // (n × (n + 1)) the solve's factor and right-hand side
  std::vector<double> saved_u;       // (2 × n_u) u before the impact, after the law
  std::vector<std::int64_t> saved_flags;  // (4 × n) resting and watched, before and after
  ContactSolution solution;          // the last impact's outcome (`solve_impact`)
  ContactSolution saved_solution[2];  // … before the impact, after the law
  ImpactScratch(int n_u, int n)
      : M(n_u * n_u), L(n_u * n_u), unit(n_u), free(n_u), rods(n), hits(n), index(n), bilateral(n),
        active(n), sigma(n), e(n), c_minus(n), qv(n), P(n), w(n), MinvE(n * n_u), W(n * n),
        cholesky(n * (n + 1)), saved_u(2 * n_u), saved_flags(4 * n), solution(n),
        saved_solution{ContactSolution(n), ContactSolution(n)} {}
};

struct Run {
  const Model& model;
  SystemArrays system;
  ArmControl arm;  // the arm controller's arrays (settings null: the arm takes Q_cmd)
  StopsArrays stops;
  StepArrays step;
  SystemWorkspace<double> ws;
  ImpactScratch impact;
  std::vector<double> x;  // (size) a stage's state
  int size;               // entries of s
  EventScript* script = nullptr;  // where set, the events of `step_with_events` are recorded
  Run(const Model& m, int state_entries)
      : model(m), ws(m), impact(m.n_u(), std::max(m.n(), 1)), x(state_entries),
        size(state_entries) {}

  int n() const { return model.n(); }
  int n_q() const { return model.n_q(); }
  int n_u() const { return model.n_u(); }
  double* stage(int i) const { return step.stages + i * size; }
  bool velocity_mode() const { return system.control[WHEEL_VELOCITY_MODE] != 0.0; }
  bool arm_on() const { return arm.settings != nullptr && arm.settings[ARM_ON] != 0.0; }
};

inline bool any_resting(const Run& run) {
  for (int k = 0; k < run.n(); ++k)
    if (run.stops.resting[k] != 0) return true;
  return false;
}

inline bool any_watched(const Run& run) {
  for (int k = 0; k < run.n(); ++k)
    if (run.stops.watched[k]) return true;
  return false;
}

// The dynamics' locks from `free` (which Python may have changed between calls).
inline void sync_locks(Run& run) {
  auto& moving = run.ws.dynamics.moving;
  for (int j = 0; j < run.n_u(); ++j) moving[j] = 0.0;
  for (int a = 0; a < run.n_u() && run.system.free[a] >= 0; ++a) moving[run.system.free[a]] = 1.0;
}

// free = the pseudo-velocities neither locked by the scene nor held at a stop; the holding
// forces are watched at every evaluation while a rod rests.
inline void relock(Run& run) {
  const int nu = run.n_u();
  run.system.holding[HOLDING_ON] = any_resting(run) ? 1.0 : 0.0;
  int m = 0;
  for (int j = 0; j < nu; ++j) {
    bool locked = run.stops.permanent[j];
    if (j >= 2 && j % 2 == 1 && run.stops.resting[(j - 1) / 2 - 1] != 0) locked = true;
    if (!locked) run.system.free[m++] = j;
  }
  for (int j = m; j < nu; ++j) run.system.free[j] = -1;
  sync_locks(run);
}

// min over resting rods of the force (N) its stop pushes with, `net(k)` the force rod k's slide
// transmits less its applied force (+inf when none rests). The stop pushes outward only: +l at
// the lower stop (side −1), −l at the upper (+1).
template <class Net>
inline double least_margin(const Run& run, Net&& net) {
  double margin = std::numeric_limits<double>::infinity();
  for (int k = 1; k <= run.n(); ++k) {
    std::int64_t side = run.stops.resting[k - 1];
    if (side != 0) margin = std::min(margin, -double(side) * net(k));
  }
  return margin;
}

// The net slide forces of the run's own last evaluation (`derivative`), for least_margin.
inline auto own_net(const Run& run) {
  return [&run](int k) { return run.ws.dynamics.slide_force[k] - run.ws.Q[u_slide(k)]; };
}

// … right after a `derivative` (> 0 while every stop pushes)
inline double holding_margin_now(const Run& run) { return least_margin(run, own_net(run)); }

// While a rod rests, every evaluation samples the holding forces: the least margin so far.
inline void watch_holding(Run& run, double margin) {
  if (margin < run.system.holding[HOLDING_LEAST_MARGIN])
    run.system.holding[HOLDING_LEAST_MARGIN] = margin;
}

// What the run books of one evaluation of ds/dt, whose net slide forces are net(k) (its own, or
// its lane's of a vector block, lanes.hpp): the stages it ran, counted (counters[...]); while a
// rod rests, the holding forces watched.
template <class Net>
inline void book_evaluation(Run& run, Net&& net) {
  auto& counters = run.system.counters;
  counters[RHS_EVALS] += 1;
  if (run.system.control[WHEEL_VELOCITY_MODE] != 0.0) counters[CONTROL_STAGE] += 1;
  if (run.arm_on()) counters[ARM_CONTROL_STAGE] += 1;
  if (run.system.damping != nullptr) counters[DAMPING_STAGE] += 1;
  if (run.system.free[run.n_u() - 1] < 0) counters[REDUCED_SOLVE] += 1;
  if (run.system.holding[HOLDING_ON] != 0.0) watch_holding(run, least_margin(run, net));
}

inline void clear_holding(Run& run) {
  run.system.holding[HOLDING_LEAST_MARGIN] = std::numeric_limits<double>::infinity();
}

inline WheelLoop wheel_loop(const double* control) {
  return WheelLoop{control[WHEEL_KP],      control[WHEEL_KI],      control[WHEEL_LIMIT_R],
                   control[WHEEL_LIMIT_L], control[WHEEL_TARGET_R], control[WHEEL_TARGET_L]};
}

// ds/dt at s (system.hpp's `rates`), counting its stages; while a rod rests, every evaluation —
// each stage of every step — samples the holding forces, so that a pull inside a step is noticed
// where a stage saw it.
inline void derivative(Run& run, const double* s, double* ds) {
  const double* control = run.system.control;
  WheelLoop wheels;
  const WheelLoop* loop = nullptr;
  const double* held = nullptr;
  if (control[WHEEL_VELOCITY_MODE] != 0.0) {
    if (run.system.rate > 0.0) {
      held = run.system.held;
    } else {
      wheels = wheel_loop(control);
      loop = &wheels;
    }
  }
  const ArmControl* arm = run.arm_on() ? &run.arm : nullptr;
  Effects<double> fx{run.system.gravity, run.system.Q_cmd, run.system.damping, loop, held, arm};
  rates(run.model, fx, s, ds, run.ws);
  book_evaluation(run, own_net(run));
}

// The force (N) the stop of each resting rod k must push with along the rod to hold it, into
// out[u_slide(k)], from an evaluation with the rod locked whose net slide forces are net(k)
// (by default the run's own last `derivative`).
template <class Net>
inline void slide_holding_forces(const Run& run, double* out, Net&& net) {
  for (int k = 1; k <= run.n(); ++k)
    if (run.stops.resting[k - 1] != 0) out[u_slide(k)] = net(k);
}
inline void slide_holding_forces(const Run& run, double* out) {
  slide_holding_forces(run, out, own_net(run));
}

// `holding_margin` for an evaluation ds/dt at s already made (net(k) its net slide forces):
// booked, the holding forces into the step's scratch, their least returned.
template <class Net>
inline double holding_margin_of(Run& run, Net&& net) {
  book_evaluation(run, net);
  slide_holding_forces(run, run.step.forces, net);
  return least_margin(run, net);
}

// min over resting rods of the force its stop pushes with at s: > 0 while all are held.
inline double holding_margin(Run& run, const double* s, double* ds) {
  derivative(run, s, ds);
  slide_holding_forces(run, run.step.forces);
  return holding_margin_now(run);
}

inline double kinetic_energy_at(Run& run, const double* s) {
  frames(run.model, s, run.ws.dynamics);
  return kinetic_energy(run.model, s, s + run.n_q(), run.ws.dynamics);
}

inline double total_energy(Run& run, const double* s) {
  frames(run.model, s, run.ws.dynamics);
  double T = kinetic_energy(run.model, s, s + run.n_q(), run.ws.dynamics);
  return T + potential_energy(run.model, s, run.system.gravity, run.ws.dynamics);
}

}  // namespace mms
