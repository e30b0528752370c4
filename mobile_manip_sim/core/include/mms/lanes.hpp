// The batch's lanes: many runs, each its own `Run` (run.hpp) with its own state and clock, advanced
// in one call over several threads. Each lane follows the very calls a simulation alone makes
// (batch/runs.py drives them, batch/lane_logs.py holds their logs): for every
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
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "stepping.hpp"

namespace mms {

// a lane's outcome after a call (batch/lane_logs.py); LANE_GOES_ON: not yet; NEED_STEP: the lane
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

// A lane's own impact log (batch/lane_logs.py's ImpactLogs): rows of the stops' log moved there.
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

// ---------------------------------------------------------------------------------------------
// Vector blocks: the plain whole grid steps of up to W lanes in one step on Lanes<W>.

// A lane's grid step may share a vector block when nothing in its right-hand side is its own but
// numbers the block holds per lane (its robot, state, efforts, locks): no wheel-speed loop.
inline bool plain(const Lane& lane) { return lane.run->system.control[WHEEL_VELOCITY_MODE] == 0.0; }

// Two lanes may share a block: one method, step, gravity and damping (the block's step takes them
// once), one robot structure.
inline bool same_step(const Lane& a, const Lane& b) {
  const Run &ra = *a.run, &rb = *b.run;
  if (a.method != b.method || a.clock[CLOCK_DT] != b.clock[CLOCK_DT] ||
      ra.system.gravity != rb.system.gravity || ra.size != rb.size || ra.n() != rb.n())
    return false;
  if ((ra.system.damping == nullptr) != (rb.system.damping == nullptr)) return false;
  if (ra.system.damping != nullptr)
    for (int i = 0; i < ra.n_u(); ++i)
      if (ra.system.damping[i] != rb.system.damping[i]) return false;
  return true;
}

// Lane j of a block's robot set to a run's robot.
template <int W>
void set_lane(ModelOf<Lanes<W>>& to, int j, const Model& from) {
  BaseParametersOf<Lanes<W>>& b = to.base;
  b.mass.set(j, from.base.mass);
  b.yaw_inertia.set(j, from.base.yaw_inertia);
  b.com_offset.set(j, from.base.com_offset);
  b.wheel_radius.set(j, from.base.wheel_radius);
  b.half_track.set(j, from.base.half_track);
  b.wheel_inertia.set(j, from.base.wheel_inertia);
  for (int i = 0; i < 3; ++i) to.mount[i].set(j, from.mount[i]);
  for (int k = 0; k < from.n(); ++k) {
    to.L[k].set(j, from.L[k]);
    to.mu[k].set(j, from.mu[k]);
    for (int a = 0; a < 3; ++a)
      for (int c = 0; c < 3; ++c) {
        to.R0[k][a][c].set(j, from.R0[k][a][c]);
        to.J[k][a][c].set(j, from.J[k][a][c]);
      }
  }
  to.tip_mass.set(j, from.tip_mass);
}

// One vector block: its lanes' robots, the step's state, stages and efforts, and which run's
// robot each lane holds now.
template <int W>
struct LaneBlock {
  using B = Lanes<W>;
  ModelOf<B> model;
  SystemWorkspace<B> ws;
  std::vector<B> s, out, x, Q;
  std::vector<std::vector<B>> k;  // the step's stages, then f(end)
  const Run* owner[W] = {};
  LaneBlock(const Model& m, int size)
      : model(shaped(m)), ws(m), s(size), out(size), x(size), Q(m.n_u()),
        k(5, std::vector<B>(size)) {}
  static ModelOf<B> shaped(const Model& m) {
    ModelOf<B> b;
    b.R0.resize(m.n());
    b.L.resize(m.n());
    b.mu.resize(m.n());
    b.J.resize(m.n());
    return b;
  }
};

// The stages a step of `method` writes (fixed_step.hpp's step_with).
inline int stages_of(Method method) {
  return method == Method::Rk4 ? 4 : method == Method::SemiImplicitEuler ? 2 : 1;
}

// The whole grid step of `count` lanes (2 ≤ count ≤ W, one `same_step`, all `plain`) computed
// once in vector lanes (a short block repeats its first lane), each lane's run then left exactly
// as its own `run_step` leaves it — its step's end and stages in its scratch, its evaluations
// counted, its holding forces watched at every evaluation while a rod rests (not the first, when
// f(s) was ready) — and its grid step finished by the scalar `grid_step_end`: a lane that meets
// an event there leaves the block for its scalar run, which takes the step with its events.
template <int W>
void block_step(LaneBlock<W>& block, Lane* const* lanes, LaneFlow* const* flows, int count,
                std::int64_t* const* vector_steps) {
  using B = Lanes<W>;
  const Lane& first = *lanes[0];
  const Run& lead = *first.run;
  const int size = lead.size, nu = lead.n_u();
  for (int j = 0; j < W; ++j) {
    const Lane& lane = *lanes[j < count ? j : 0];
    const Run& run = *lane.run;
    if (block.owner[j] != &run) {
      set_lane(block.model, j, run.model);
      block.owner[j] = &run;
    }
    for (int i = 0; i < size; ++i) block.s[i].set(j, lane.s[i]);
    for (int i = 0; i < nu; ++i) {
      block.Q[i].set(j, run.system.Q_cmd[i]);
      block.ws.dynamics.moving[i].set(j, run.ws.dynamics.moving[i]);
    }
  }
  for (int j = 0; j < count; ++j) clear_holding(*lanes[j]->run);
  Effects<B> fx{lead.system.gravity, block.Q.data(), lead.system.damping};
  int stage = 0;
  auto net_of = [&](int j) {  // lane j's net slide forces of the block's last evaluation
    return [&block, j](int k) {
      return block.ws.dynamics.slide_force[k][j] - block.ws.Q[u_slide(k)][j];
    };
  };
  auto f = [&](const B* at, B* rate) {
    rates(block.model, fx, at, rate, block.ws);
    for (int j = 0; j < count; ++j) {
      Run& run = *lanes[j]->run;
      if (stage == 0 && flows[j]->k1_ready) {  // its step takes f(s) from its first stage
        for (int i = 0; i < size; ++i) rate[i].set(j, run.stage(0)[i]);
        continue;
      }
      book_evaluation(run, net_of(j));
    }
    ++stage;
  };
  B* k[4] = {block.k[0].data(), block.k[1].data(), block.k[2].data(), block.k[3].data()};
  step_with(first.method, block.model, f, block.s.data(), first.clock[CLOCK_DT], block.out.data(),
            k, block.x.data(), size);
  // f(end), which a lane with a resting rod needs for its holding forces there (and as its next
  // step's first stage): computed in the block too, booked only by the lanes that ask for it
  bool resting = false;
  for (int j = 0; j < count; ++j) resting = resting || any_resting(*lanes[j]->run);
  if (resting) rates(block.model, fx, block.out.data(), block.k[4].data(), block.ws);
  const int stages = stages_of(first.method);
  for (int j = 0; j < count; ++j) {
    Lane& lane = *lanes[j];
    Run& run = *lane.run;
    for (int i = 0; i < size; ++i) run.step.out[i] = block.out[i][j];
    for (int st = 0; st < stages; ++st)
      for (int i = 0; i < size; ++i) run.stage(st)[i] = block.k[st][i][j];
    bool k1_ready = false;
    int status = grid_step_end(run, lane.method, lane.s, lane.clock, k1_ready, [&] {
      for (int i = 0; i < size; ++i) run.stage(0)[i] = block.k[4][i][j];
      return holding_margin_of(run, net_of(j));
    });
    stepped(lane, *flows[j], status, k1_ready);
    ++*vector_steps[j];
  }
}

// One thread's group of lanes through the call, in rounds: each lane brought to its next whole
// grid step (`until_step`), then those ready together take it in vector blocks of up to W lanes
// that share a step (at least two: one lane alone steps in double), the rest with the scalar
// `grid_step`. flows[j] says where lane j is (its next sample); `outcome(j, code, status)` takes
// each lane's result; paths[j] its counts of grid steps in blocks and alone.
template <int W, class Outcome>
void run_group(Lane* const* lanes, LaneFlow* flows, LaneOut* outs, std::int64_t* const* paths,
               int g, const LaneCall& call, Outcome&& outcome) {
  std::vector<char> active(g, 1), ready(g, 0), taken(g, 0);
  std::vector<std::unique_ptr<LaneBlock<W>>> blocks;
  Lane* members[W];
  LaneFlow* member_flows[W];
  std::int64_t* member_paths[W];
  while (true) {
    int waiting = 0;
    for (int j = 0; j < g; ++j) {
      ready[j] = 0;
      if (!active[j]) continue;
      int status = DONE;
      int code = until_step(*lanes[j], flows[j], call, outs[j], status);
      if (code == NEED_STEP) {
        ready[j] = 1;
        ++waiting;
      } else {
        active[j] = 0;
        outcome(j, code, status);
      }
    }
    if (waiting == 0) return;
    std::fill(taken.begin(), taken.end(), 0);
    size_t b = 0;
    for (int j = 0; j < g; ++j) {
      if (!ready[j] || taken[j] || !plain(*lanes[j])) continue;
      int count = 0;
      for (int i = j; i < g && count < W; ++i)
        if (ready[i] && !taken[i] && plain(*lanes[i]) && same_step(*lanes[j], *lanes[i])) {
          members[count] = lanes[i];
          member_flows[count] = &flows[i];
          member_paths[count] = paths[i];
          taken[i] = 1;
          ++count;
        }
      if (count < 2) {
        taken[j] = 0;
        continue;
      }
      if (b == blocks.size())
        blocks.push_back(std::make_unique<LaneBlock<W>>(lanes[j]->run->model, lanes[j]->run->size));
      block_step(*blocks[b++], members, member_flows, count, member_paths);
    }
    for (int j = 0; j < g; ++j)
      if (ready[j] && !taken[j]) {
        bool k1_ready = flows[j].k1_ready;
        int status = grid_step(*lanes[j]->run, lanes[j]->method, lanes[j]->s, lanes[j]->clock,
                               k1_ready);
        stepped(*lanes[j], flows[j], status, k1_ready);
        ++paths[j][1];
      }
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
