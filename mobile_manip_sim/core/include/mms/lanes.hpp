// The batch's lanes: many runs, each its own `Run` (run.hpp) with its own state and clock, advanced
// in one call over several threads. Each lane follows the very calls a simulation alone makes
// (batch/lanes.py is the contract, and the numba lanes the reference while both exist): for every
// sample time an `advance` with the simulation's step budget, again after BUDGET, and after every
// call the impact log emptied into the lane's own log (`keep_impacts`), which Python reads after
// the call. A lane pauses only when that log is full, and goes on in the next call once Python has
// read it; a lane that fails stops where its run would raise, and the others go on.
//
// A lane's flow (`until_step`) is `advance` (stepping.hpp) made resumable at each whole grid step,
// so that a group of lanes can take those steps together: the plain ones of up to kLaneWidth
// lanes in one vector block (`lane_blocks.hpp`: the same templated step on Lanes<W>), everything
// else — the shorter step to a sample off the grid, budgets, the log's room, events, impacts,
// rests, releases — lane by lane with the scalar code. Each lane is bit for bit its own run.
#pragma once

#include <atomic>
#include <cmath>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

#include "stepping.hpp"

namespace mms {

// a lane's outcome after a call (batch/lanes.py); LANE_GOES_ON: not yet; NEED_STEP: the lane
// waits for its next whole grid step
enum LaneCode { LANE_DONE = 0, LANE_PAUSED = 1, LANE_FAILED = 2, LANE_GOES_ON = -1,
                NEED_STEP = -2 };

// One lane: its run, method, state and clock (the simulation's own arrays).
struct Lane {
  Run* run = nullptr;
  Method method = Method::Rk4;
  double* s = nullptr;
  double* clock = nullptr;
};

// A lane's own impact log (batch/lanes.py's ImpactLogs): rows of the stops' log moved there.
struct LaneLog {
  double* log;           // (rows × LOG_COLUMNS)
  double* log_q;         // (rows × n_q)
  double* log_u;         // (rows × 2 × n_u)
  bool* log_free;        // (rows × n_u)
  std::int64_t* count;   // (1) rows in use
  int rows;
};

// What one call asks of a lane: samples times[at … last), written (with `write`) as rows[i] =
// (s, T + V) and rows_t[i] the lane's own clock there; `budget` steps per `advance`.
struct LaneCall {
  const double* times = nullptr;
  long last = 0;
  bool write = false;
  long budget = 0;
};

struct LaneOut {
  double* rows;      // (samples × (size + 1)), or one row never written
  double* rows_t;    // (samples)
  LaneLog log;
};

// Where a lane is in its calls: inside an `advance` to times[at], steps taken in it, f(s) ready
// in the first stage, the status that ends the call (−1: none yet).
struct LaneFlow {
  bool in_call = false;
  long taken = 0;
  bool k1_ready = false;
  int ending = -1;
  double whole = 0, steps = 0;  // the call's whole grid steps to reach, its steps as a real
  long at = 0;                  // the next sample
};

// Move the stops' impact log into the lane's own and empty it, as Python does after every call
// of a run alone; false, leaving the log as it is, when the rows do not fit.
inline bool keep_impacts(Run& run, LaneLog& lane) {
  const long rows = run.stops.count[0];
  if (lane.count[0] + rows > lane.rows) return false;
  const int nq = run.n_q(), nu = run.n_u();
  for (long r = 0; r < rows; ++r) {
    const long k = lane.count[0] + r;
    std::copy(run.stops.log + r * LOG_COLUMNS, run.stops.log + (r + 1) * LOG_COLUMNS,
              lane.log + k * LOG_COLUMNS);
    std::copy(run.stops.log_q + r * nq, run.stops.log_q + (r + 1) * nq, lane.log_q + k * nq);
    std::copy(run.stops.log_u + r * 2 * nu, run.stops.log_u + (r + 1) * 2 * nu,
              lane.log_u + k * 2 * nu);
    std::copy(run.stops.log_free + r * nu, run.stops.log_free + (r + 1) * nu,
              lane.log_free + k * nu);
  }
  lane.count[0] += rows;
  run.stops.count[0] = 0;
  return true;
}

// What a lane does after each `advance` towards sample f.at that returned `status`: the sample
// written once reached, the impacts moved into its own log. LANE_GOES_ON, or its outcome.
inline int after_advance(Lane& lane, LaneFlow& f, const LaneCall& call, LaneOut& out,
                         int status) {
  Run& run = *lane.run;
  if (status == DONE) {
    if (call.write) {
      double* row = out.rows + f.at * (run.size + 1);
      std::copy(lane.s, lane.s + run.size, row);
      row[run.size] = total_energy(run, lane.s);
      out.rows_t[f.at] = lane.clock[CLOCK_T0] + lane.clock[CLOCK_K] * lane.clock[CLOCK_DT];
    }
    ++f.at;
  } else if (status != BUDGET && status != LOG_FULL) {
    return LANE_FAILED;
  }
  if (run.stops.count[0] > 0 && !keep_impacts(run, out.log)) return LANE_PAUSED;
  return LANE_GOES_ON;
}

// The lane's calls (`advance` to each sample, as the run alone makes them) resumed where they
// stopped, up to its next whole grid step: NEED_STEP there, or the lane's outcome of this call
// (`status` the stepping status that ended it). Everything but the whole grid step is done here
// as `advance_between_updates` does it; a lane whose sampled controllers update on the way
// (none in a batch today) takes its whole `advance` here.
inline int until_step(Lane& lane, LaneFlow& f, const LaneCall& call, LaneOut& out, int& status) {
  Run& run = *lane.run;
  double* clock = lane.clock;
  const long room = run.stops.capacity / 2;
  while (true) {
    status = f.ending;
    if (status < 0) {
      if (!f.in_call) {  // `advance` to times[f.at] begins
        if (f.at >= call.last) {
          status = DONE;
          return LANE_DONE;
        }
        sync_locks(run);
        f.in_call = true;
        f.taken = 0;
        f.k1_ready = false;
        f.steps = (call.times[f.at] - clock[CLOCK_T0]) / clock[CLOCK_DT];
        f.whole = std::floor(f.steps + 1e-9);
        if (run.system.rate > 0.0 && run.velocity_mode())
          f.ending = advance(run, lane.method, lane.s, clock, call.times[f.at], call.budget);
        continue;
      }
      if (clock[CLOCK_K] < f.whole) {
        if (f.taken >= call.budget) {
          status = BUDGET;
        } else if (run.stops.count[0] > room) {
          status = LOG_FULL;
        } else {
          return NEED_STEP;
        }
      } else {
        status = DONE;
        if (f.steps - f.whole > 1e-9) {  // the sample is off the grid: a last, shorter step
          if (run.stops.count[0] > room) {
            status = LOG_FULL;
          } else {
            const double dt = clock[CLOCK_DT], t_end = call.times[f.at];
            const double t = clock[CLOCK_T0] + clock[CLOCK_K] * dt;
            status = step_with_events(run, lane.method, lane.s, t_end - t, t, clock);
            if (status == DONE) {
              clock[CLOCK_STEPS] += 1.0;
              clock[CLOCK_T0] = t_end;
              clock[CLOCK_K] = 0.0;
            }
          }
        }
      }
    }
    f.ending = -1;  // `advance` returned `status`
    f.in_call = false;
    int code = after_advance(lane, f, call, out, status);
    if (code != LANE_GOES_ON) return code;
  }
}

// After the lane's whole grid step: booked as `advance_between_updates` books it, or the status
// that ends the call.
inline void stepped(Lane& lane, LaneFlow& f, int status, bool k1_ready) {
  if (status != DONE) {
    f.ending = status;
    return;
  }
  lane.clock[CLOCK_K] += 1.0;
  lane.clock[CLOCK_STEPS] += 1.0;
  ++f.taken;
  f.k1_ready = k1_ready;
}

// One lane alone through the call: its flow, each whole grid step by the scalar `grid_step`.
// Returns its code; `status` the stepping status that ended it.
inline int run_lane(Lane& lane, LaneFlow& f, const LaneCall& call, LaneOut& out, int& status,
                    std::int64_t* scalar_steps) {
  while (true) {
    int code = until_step(lane, f, call, out, status);
    if (code != NEED_STEP) return code;
    bool k1_ready = f.k1_ready;
    int step_status = grid_step(*lane.run, lane.method, lane.s, lane.clock, k1_ready);
    stepped(lane, f, step_status, k1_ready);
    ++*scalar_steps;
  }
}

// work(i) for i in [0, items) on `threads` threads (this one among them), the items handed out
// one at a time (their costs differ: impacts, rests); the first exception is raised here.
template <class Work>
void on_threads(int threads, long items, Work&& work) {
  std::atomic<long> next{0};
  std::exception_ptr failure;
  std::mutex failure_lock;
  auto worker = [&] {
    try {
      for (long i = next++; i < items; i = next++) work(i);
    } catch (...) {
      std::lock_guard<std::mutex> hold(failure_lock);
      if (!failure) failure = std::current_exception();
      next = items;
    }
  };
  std::vector<std::thread> pool;
  for (int t = 1; t < threads && t < items; ++t) pool.emplace_back(worker);
  worker();
  for (auto& thread : pool) thread.join();
  if (failure) std::rethrow_exception(failure);
}

}  // namespace mms
