// Stroke end stops (docs/model.md, "Several stops at once" and "Resting, leaving, and no Zeno"):
// the contact problem of m rods at their stops, the impact law, resting at a stop and leaving it,
// and the Zeno guard's evidence (engine/stops.py holds the records, engine/events.py names the
// constants).
//
// - `solve_contacts`: the LCP P ≥ 0, w = W P + q ≥ 0, Pᵀw = 0 (W the Delassus matrix Eᵀ M⁻¹ E,
//   symmetric positive definite, so the solution is unique), by Murty's least-index principal
//   pivoting; a bilateral contact (held) is always active, with an impulse of either sign.
// - `impact`: one solve for every stop in contact at that instant — the rods reaching their
//   stops within SIMULTANEOUS of each other and those resting — each with its restitution (0 for
//   a rod that would rebound slower than rest_speed: it rests), or the paper's `reflect` law; one
//   log row per rod hit. Where the Zeno guard sees evidence of an accumulation point, the impact
//   is solved both ways and held only when the hold removes at most ZENO_SHARE of the run's
//   kinetic energy beyond the law; a rod found at its stop not moving into it is always held.
// - `release`: a resting rod leaves when its stop would have to pull; which rods leave together
//   is the same contact law at the level of accelerations.
#pragma once

#include <algorithm>
#include <cmath>

#include "run.hpp"

namespace mms {

constexpr double SIMULTANEOUS = 1e-9;  // s: stops reached this close together are one impact
constexpr double ZENO_TAIL = 1e-6;     // s: a run whose remaining tail is shorter is evidence
constexpr int ZENO_RUN = 3;            // shrinking intervals (and speeds) that make a run
constexpr double ZENO_SHARE = 1e-6;    // a hold removes at most this share of its run's T
// stops.run[k − 1][stop][...]: impacts there, the last one's time, the interval before it, its
// arrival speed, the shrinking intervals in a row, the largest kinetic energy at one there
enum RunField { RUN_COUNT, RUN_LAST, RUN_INTERVAL, RUN_SPEED, RUN_SHRINKS, RUN_ENERGY,
                RUN_FIELDS };
// which contacts an impact solve holds: none (the law), those found at their stop not moving
// into it, or every contact (an accumulation point)
enum Holds { HOLD_NONE, HOLD_PRESSED, HOLD_ALL };
constexpr int CONTACT_SOLVE_FAILED = 1;

inline int ld_index(const Run& run, int k) { return run.n_q() + u_slide(k); }

// P_A = −W_AA⁻¹ q_A by Cholesky on the active rows idx[:n_active], P zero elsewhere (m entries);
// L (n_active × (n_active + 1), row stride ldl) scratch. Generic in the scalar: the same solve,
// operation for operation, gives an impact's impulses in double and their derivatives in dual
// numbers (event_jacobians.hpp), the active set held.
template <class S>
inline void active_impulses(const S* W, int ldw, const S* q, int m, const int* idx, int n_active,
                            S* L, int ldl, S* P) {
  const int n = n_active;
  for (int a = 0; a < n; ++a)
    for (int c = 0; c <= a; ++c) {
      S s = W[idx[a] * ldw + idx[c]];
      for (int k = 0; k < c; ++k) s -= L[a * ldl + k] * L[c * ldl + k];
      if (a == c)
        L[a * ldl + a] = select(is_positive(value(s)), sqrt_(s), S(NAN));
      else
        L[a * ldl + c] = s / L[c * ldl + c];
    }
  auto y = [&](int a) -> S& { return L[a * ldl + m]; };
  for (int a = 0; a < n; ++a) {
    S s = -q[idx[a]];
    for (int k = 0; k < a; ++k) s -= L[a * ldl + k] * y(k);
    y(a) = s / L[a * ldl + a];
  }
  for (int a = n - 1; a >= 0; --a) {
    S s = y(a);
    for (int k = a + 1; k < n; ++k) s -= L[k * ldl + a] * y(k);
    y(a) = s / L[a * ldl + a];
  }
  for (int i = 0; i < m; ++i) P[i] = S(0.0);
  for (int a = 0; a < n; ++a) P[idx[a]] = y(a);
}

// The LCP above for m contacts: W (m × m, row stride ldw), q (m); P, w (m) out; L (m × (m + 1),
// row stride ldl) and idx (m) scratch. Returns the pivots taken, or −1 when none converged.
inline int solve_contacts(const double* W, int ldw, const double* q, int m, const char* bilateral,
                          char* active, double* P, double* w, double* L, int ldl, int* idx) {
  for (int i = 0; i < m; ++i) active[i] = bilateral[i];
  double scale = 0.0;
  for (int i = 0; i < m; ++i) scale = std::max(scale, std::fabs(q[i]));
  const double tol = 1e-13 * scale;
  const long tries = 1L << std::min(m + 4, 30);
  for (long pivots = 0; pivots < tries; ++pivots) {
    int n = 0;
    for (int i = 0; i < m; ++i)
      if (active[i]) idx[n++] = i;
    active_impulses(W, ldw, q, m, idx, n, L, ldl, P);
    for (int i = 0; i < m; ++i) {
      double s = q[i];
      for (int j = 0; j < m; ++j) s += W[i * ldw + j] * P[j];
      w[i] = s;
    }
    int wrong = -1;
    for (int i = 0; i < m; ++i) {
      if (bilateral[i]) continue;
      if ((active[i] && P[i] < -tol) || (!active[i] && w[i] < -tol)) {
        wrong = i;
        break;
      }
    }
    if (wrong < 0) {
      for (int i = 0; i < m; ++i)
        if (!active[i]) P[i] = 0.0;
      return int(pivots);
    }
    active[wrong] = !active[wrong];
  }
  return -1;
}

// W = Eᵀ M⁻¹ E (impact.W, m × m of stride n) and M⁻¹ E (impact.MinvE, one row per contact over
// the free DOFs in free order) for the m contacts impact.rods[:m], directions impact.sigma, every
// DOF free but the scene's locked ones (into impact.free). Returns how many DOFs are free.
inline int contact_matrix(Run& run, const double* s, int m) {
  const int nu = run.n_u(), n = std::max(run.n(), 1);
  ImpactScratch& c = run.impact;
  int n_free = 0;
  for (int j = 0; j < nu; ++j) c.free[j] = -1;
  for (int j = 0; j < nu; ++j)
    if (!run.stops.permanent[j]) c.free[n_free++] = j;
  frames(run.model, s, run.ws.dynamics);
  mass_matrix(run.model, run.ws.dynamics, s, c.M.data());
  std::vector<double>& unit = c.unit;
  for (int a = 0; a < m; ++a) {
    for (int i = 0; i < nu; ++i) unit[i] = 0.0;
    unit[u_slide(c.rods[a])] = c.sigma[a];
    cholesky_solve(c.M.data(), nu, unit.data(), c.free.data(), n_free, c.L.data(),
                   c.MinvE.data() + a * nu);
  }
  for (int a = 0; a < m; ++a) {
    // W_ab = E_aᵀ M⁻¹ E_b: row a of E picks DOF j_a, which sits at position pos in free
    int j = u_slide(c.rods[a]), pos = 0;
    while (c.free[pos] != j) ++pos;
    for (int b = 0; b < m; ++b) c.W[a * n + b] = c.sigma[a] * c.MinvE[b * nu + pos];
  }
  return n_free;
}

inline bool solve_set(Run& run, const double* q, int m) {
  ImpactScratch& c = run.impact;
  const int n = std::max(run.n(), 1);
  return solve_contacts(c.W.data(), n, q, m, c.bilateral.data(), c.active.data(), c.P.data(),
                        c.w.data(), c.cholesky.data(), n + 1, c.index.data()) >= 0;
}

// The Zeno guard's evidence (docs/model.md, "Resting, leaving, and no Zeno"): rod k meets its stop `side` at time t with
// arrival speed `speed`, the kinetic energy being T. Records the impact and returns the energy a
// hold may remove there beyond the law, or −1 without evidence of an accumulation point.
inline double zeno_guard(double* runs, int k, int side, double t, double speed, double T) {
  double* record = runs + ((k - 1) * 2 + (side < 0 ? 0 : 1)) * RUN_FIELDS;
  bool evidence = false;
  if (record[RUN_COUNT] > 0.0) {
    double interval = t - record[RUN_LAST];
    if (record[RUN_COUNT] > 1.0 && interval < record[RUN_INTERVAL] && speed < record[RUN_SPEED])
      record[RUN_SHRINKS] += 1.0;
    else
      record[RUN_SHRINKS] = 0.0;
    evidence = interval <= ZENO_TAIL;
    if (record[RUN_SHRINKS] >= ZENO_RUN) {
      double ratio = interval / record[RUN_INTERVAL];
      evidence = evidence || interval * ratio <= ZENO_TAIL * (1.0 - ratio);
    }
    record[RUN_INTERVAL] = interval;
  }
  record[RUN_COUNT] += 1.0;
  record[RUN_LAST] = t;
  record[RUN_SPEED] = speed;
  record[RUN_ENERGY] = std::max(record[RUN_ENERGY], T);
  return evidence ? ZENO_SHARE * record[RUN_ENERGY] : -1.0;
}

// The rods hit together with rod k at its stop `side` at the located state s (impact.hits): rod
// k, and every other watched rod moving into a stop closer to it than |l̇|·SIMULTANEOUS, or
// already past one, each moved exactly onto its stop in s.
inline void simultaneous_hits(Run& run, double* s, int k, int side) {
  auto& hits = run.impact.hits;
  for (int r = 1; r <= run.n(); ++r) {
    hits[r - 1] = 0;
    if (r == k) {
      hits[r - 1] = side;
    } else if (run.stops.watched[r - 1]) {
      double lo = run.stops.stroke[2 * (r - 1)], hi = run.stops.stroke[2 * (r - 1) + 1];
      double l_r = s[q_slide(r)], v = s[ld_index(run, r)];
      double reach = std::fabs(v) * SIMULTANEOUS;
      if (l_r < lo || (v < 0.0 && l_r - lo <= reach)) {
        hits[r - 1] = -1;
        s[q_slide(r)] = lo;
      } else if (l_r > hi || (v > 0.0 && hi - l_r <= reach)) {
        hits[r - 1] = 1;
        s[q_slide(r)] = hi;
      }
    }
  }
}

// One impact of the m contacts set up in run.impact (rods, σ, e, bilateral): u⁺ = u⁻ + M⁻¹ E P
// with P ≥ 0 ⊥ c⁺ + e c⁻ ≥ 0, in place on s. Afterwards a resting rod whose stop gave no impulse
// leaves it. A failed solve leaves s as it was and marks stops.failed.
inline void contact_impulses(Run& run, double* s, int m) {
  ImpactScratch& c = run.impact;
  const int nq = run.n_q(), nu = run.n_u();
  int n_free = contact_matrix(run, s, m);
  for (int a = 0; a < m; ++a) {
    c.c_minus[a] = c.sigma[a] * s[nq + u_slide(c.rods[a])];
    c.qv[a] = (1.0 + c.e[a]) * c.c_minus[a];
  }
  if (!solve_set(run, c.qv.data(), m)) {
    run.stops.failed[0] = CONTACT_SOLVE_FAILED;
    return;
  }
  for (int b = 0; b < m; ++b)
    if (c.P[b] != 0.0)
      for (int a = 0; a < n_free; ++a) s[nq + c.free[a]] += c.P[b] * c.MinvE[b * nu + a];
  for (int b = 0; b < m; ++b) {
    int j = nq + u_slide(c.rods[b]);
    if (c.active[b]) {
      s[j] = -c.e[b] * c.c_minus[b] * c.sigma[b];  // exact: c⁺ = −e c⁻ on an active contact
    } else if (run.stops.resting[c.rods[b] - 1] != 0) {
      run.stops.resting[c.rods[b] - 1] = 0;  // its stop would have had to pull: it leaves
      run.stops.watched[c.rods[b] - 1] = true;
    }
  }
  relock(run);
}

// The impact of log rows first … row − 1 (the rods hit) and every resting rod, on s, holding
// the contacts `holds` says.
inline void solve_impact(Run& run, double* s, int first, int row, Holds holds) {
  ImpactScratch& c = run.impact;
  const int nq = run.n_q();
  const StopsArrays& stops = run.stops;
  int m = 0;
  for (int i = first; i < row; ++i) {
    const double* log = stops.log + i * LOG_COLUMNS;
    int r = int(log[LOG_LINK]);
    double side = log[LOG_SIDE], u_before = log[LOG_LD_BEFORE];
    bool pressed = side * u_before <= 0.0;
    bool held = holds == HOLD_ALL || (holds == HOLD_PRESSED && pressed);
    double e_r = held || std::fabs(stops.restitution * u_before) < stops.rest_speed
                     ? 0.0 : stops.restitution;
    if (stops.law == REFLECT) s[nq + u_slide(r)] = -e_r * u_before;
    c.rods[m] = r;
    c.sigma[m] = -side;
    c.e[m] = e_r;
    c.bilateral[m] = held;
    ++m;
  }
  if (stops.law == IMPULSE) {
    for (int r = 1; r <= run.n(); ++r)
      if (stops.resting[r - 1] != 0) {
        c.rods[m] = r;
        c.sigma[m] = -double(stops.resting[r - 1]);
        c.e[m] = 0.0;
        c.bilateral[m] = holds == HOLD_ALL;
        ++m;
      }
    contact_impulses(run, s, m);
  }
  ContactSolution& solution = c.solution;
  solution.m = m;
  for (int a = 0; a < m; ++a) {
    solution.rods[a] = c.rods[a];
    solution.sigma[a] = c.sigma[a];
    solution.e[a] = c.e[a];
    solution.active[a] = stops.law == IMPULSE ? c.active[a] : 1;
  }
}

// Keep (which 0: before the impact, 1: after the law) or bring back u and the resting and
// watched flags.
inline void save_outcome(Run& run, const double* s, int which) {
  ImpactScratch& c = run.impact;
  for (int j = 0; j < run.n_u(); ++j) c.saved_u[which * run.n_u() + j] = s[run.n_q() + j];
  const int n = std::max(run.n(), 1);
  for (int r = 0; r < run.n(); ++r) {
    c.saved_flags[(2 * which) * n + r] = run.stops.resting[r];
    c.saved_flags[(2 * which + 1) * n + r] = run.stops.watched[r] ? 1 : 0;
  }
  c.saved_solution[which] = c.solution;
}

inline void restore_outcome(Run& run, double* s, int which) {
  ImpactScratch& c = run.impact;
  for (int j = 0; j < run.n_u(); ++j) s[run.n_q() + j] = c.saved_u[which * run.n_u() + j];
  const int n = std::max(run.n(), 1);
  for (int r = 0; r < run.n(); ++r) {
    run.stops.resting[r] = c.saved_flags[(2 * which) * n + r];
    run.stops.watched[r] = c.saved_flags[(2 * which + 1) * n + r] != 0;
  }
  c.solution = c.saved_solution[which];
  relock(run);
}

// Free the resting rods that their stops would have to pull at s (`at_root`, s a located
// release instant: also one whose stop no longer pushes). Returns how many left.
inline int release(Run& run, double* s, bool at_root) {
  ImpactScratch& c = run.impact;
  StopsArrays& stops = run.stops;
  double* ds = run.stage(3);
  double* forces = run.step.forces;
  derivative(run, s, ds);
  slide_holding_forces(run, forces);
  const int nq = run.n_q();
  bool pulled = false;
  int m = 0;
  for (int k = 1; k <= run.n(); ++k)
    if (stops.resting[k - 1] != 0) {
      double pull = double(stops.resting[k - 1]) * forces[u_slide(k)];
      pulled = pulled || pull > 0.0 || (at_root && pull >= 0.0);
      c.rods[m] = k;
      c.sigma[m] = -double(stops.resting[k - 1]);
      c.hits[m] = int(stops.resting[k - 1]);
      ++m;
    }
  if (!pulled) return 0;
  for (int b = 0; b < m; ++b) stops.resting[c.rods[b] - 1] = 0;
  if (m > 1) {
    relock(run);
    derivative(run, s, ds);
    for (int b = 0; b < m; ++b) c.c_minus[b] = c.sigma[b] * ds[nq + u_slide(c.rods[b])];
    contact_matrix(run, s, m);
    for (int b = 0; b < m; ++b) c.bilateral[b] = false;
    if (!solve_set(run, c.c_minus.data(), m)) {
      stops.failed[0] = CONTACT_SOLVE_FAILED;  // the run ends here
      return 0;
    }
    double largest = 0.0;
    for (int b = 0; b < m; ++b) largest = std::max(largest, std::fabs(c.P[b]));
    for (int b = 0; b < m; ++b)
      // at a located root, the force that crossed zero is zero up to round-off
      if (c.active[b] && c.P[b] > (at_root ? 1e-12 * largest : 0.0))
        stops.resting[c.rods[b] - 1] = c.hits[b];
  }
  int freed = 0;
  for (int b = 0; b < m; ++b)
    if (stops.resting[c.rods[b] - 1] == 0) {
      stops.watched[c.rods[b] - 1] = true;
      ++freed;
    }
  relock(run);
  return freed;
}

struct ImpactEnergies {
  double lost = 0;     // J: what the impact law removed
  double removed = 0;  // J: what a hold removed beyond it
  double held = 0;     // 1 for a held impact
};

// Rod k meets its lower (side −1) or upper (+1) stop at time t, s the located state (l_k at the
// stop): the impact of every rod hit together and every resting rod (module doc), logged, then a
// resting rod its stop would have to pull leaves.
inline ImpactEnergies impact(Run& run, double* s, int k, int side, double t) {
  StopsArrays& stops = run.stops;
  ImpactScratch& c = run.impact;
  const int nq = run.n_q(), nu = run.n_u(), n = run.n();
  simultaneous_hits(run, s, k, side);
  if (run.script != nullptr) run.script->events.back().hits = c.hits;
  double T_before = kinetic_energy_at(run, s);
  double allowance = -1.0;  // what a hold may remove beyond the law (J); −1: no evidence
  double bound = 0.0;       // ZENO_SHARE of the largest run energy among the stops hit (J)
  for (int r = 1; r <= n; ++r)
    if (c.hits[r - 1] != 0) {
      double allowed = zeno_guard(stops.run, r, c.hits[r - 1], t,
                                  std::fabs(s[nq + u_slide(r)]), T_before);
      if (allowed >= 0.0) allowance = allowance < 0.0 ? allowed : std::min(allowance, allowed);
      const double* record = stops.run + ((r - 1) * 2 + (c.hits[r - 1] < 0 ? 0 : 1)) * RUN_FIELDS;
      bound = std::max(bound, ZENO_SHARE * record[RUN_ENERGY]);
    }
  int row = int(stops.count[0]);
  const int first = row;
  bool pressed = false;
  for (int r = 1; r <= n; ++r)
    if (c.hits[r - 1] != 0) {
      for (int i = 0; i < nq; ++i) stops.log_q[row * nq + i] = s[i];
      for (int i = 0; i < nu; ++i) {
        stops.log_u[(row * 2) * nu + i] = s[nq + i];
        stops.log_free[row * nu + i] = false;
      }
      for (int a = 0; a < nu; ++a)
        if (run.system.free[a] >= 0) stops.log_free[row * nu + run.system.free[a]] = true;
      double* log = stops.log + row * LOG_COLUMNS;
      log[LOG_TIME] = t;
      log[LOG_LINK] = r;
      log[LOG_SIDE] = c.hits[r - 1];
      log[LOG_LD_BEFORE] = s[nq + u_slide(r)];
      // A rod at the stop but not moving into it is pressed against it: held there.
      log[LOG_HELD] = c.hits[r - 1] * log[LOG_LD_BEFORE] <= 0.0 ? 1.0 : 0.0;
      pressed = pressed || log[LOG_HELD] != 0.0;
      ++row;
    }
  Holds holds = HOLD_NONE;
  double T_law;
  if (allowance < 0.0 && !pressed) {
    solve_impact(run, s, first, row, HOLD_NONE);
    T_law = kinetic_energy_at(run, s);
  } else {
    // solved both ways: the law (booked as the impact's loss), then with the holds
    save_outcome(run, s, 0);
    solve_impact(run, s, first, row, HOLD_NONE);
    T_law = kinetic_energy_at(run, s);
    if (allowance >= 0.0 && stops.failed[0] == 0) {
      save_outcome(run, s, 1);
      restore_outcome(run, s, 0);
      solve_impact(run, s, first, row, HOLD_ALL);
      holds = HOLD_ALL;
      if (T_law - kinetic_energy_at(run, s) > allowance) {  // no accumulation: the law
        holds = HOLD_NONE;
        restore_outcome(run, s, 1);
      }
    }
    if (holds == HOLD_NONE && pressed && stops.failed[0] == 0) {
      restore_outcome(run, s, 0);
      solve_impact(run, s, first, row, HOLD_PRESSED);
      holds = HOLD_PRESSED;
    }
  }
  if (stops.failed[0] != 0) return {};
  for (int i = first; i < row; ++i) {
    double* log = stops.log + i * LOG_COLUMNS;
    int r = int(log[LOG_LINK]);
    if (holds == HOLD_ALL)
      log[LOG_HELD] = 1.0;
    else if (holds == HOLD_NONE)
      log[LOG_HELD] = 0.0;
    if (s[nq + u_slide(r)] == 0.0) {  // stopped dead (e = 0, active): held at its stop
      s[nq + u_slide(r)] = 0.0;       // (not −0.0)
      stops.resting[r - 1] = c.hits[r - 1];
      stops.watched[r - 1] = false;
    }
  }
  for (int i = first; i < row; ++i) {
    double* log = stops.log + i * LOG_COLUMNS;
    int r = int(log[LOG_LINK]);
    log[LOG_LD_AFTER] = s[nq + u_slide(r)];
    log[LOG_LOST] = 0.0;
    log[LOG_HOLD_LOST] = 0.0;
    log[LOG_HOLD_BOUND] = 0.0;
    log[LOG_RESTING] = stops.resting[r - 1] != 0 ? 1.0 : 0.0;
    for (int j = 0; j < nu; ++j) stops.log_u[(i * 2 + 1) * nu + j] = s[nq + j];
  }
  stops.count[0] = row;
  relock(run);
  ImpactEnergies energies;
  energies.lost = T_before - T_law;
  energies.removed = holds != HOLD_NONE ? T_law - kinetic_energy_at(run, s) : 0.0;
  energies.held = holds != HOLD_NONE ? 1.0 : 0.0;
  double* log = stops.log + first * LOG_COLUMNS;
  log[LOG_LOST] = energies.lost;
  log[LOG_HOLD_LOST] = energies.removed;
  log[LOG_HOLD_BOUND] = bound;
  if (run.script != nullptr) run.script->events.back().solution = c.solution;
  if (any_resting(run)) release(run, s, false);
  return energies;
}

}  // namespace mms
