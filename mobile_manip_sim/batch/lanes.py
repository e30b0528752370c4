"""The compiled lanes: many runs advanced in one compiled call, spread over the cores.

Each lane is one run with its own records (the system, its stops, its scratch, its state and
clock: exactly those its own `Simulation` steps with), and each lane follows the very calls a
`Simulation` makes from Python: for every sample time, `stepping.advance` with the simulation's
step budget, again after BUDGET, and after every call the impact log emptied as Python empties it
(`Simulation._collect_impacts`): its rows moved into the lane's own log (`keep_impacts`), which
Python reads after the compiled call. A lane pauses only when that log is full, and goes on in the
next call once Python has read it. The steps, the events (crossings, impacts, releases, holds:
`engine/stepping.py` and `engine/stops.py`, called, never copied), the calls' boundaries and
hence the rhs counters are those of the run alone: each lane is bit for bit its own run. A lane
that fails (NOT_FINITE, CHATTER) stops where its own run would raise, and the others go on.

`advance_fixed` runs the lanes of the fixed-step methods; the loop over lanes is numba's
`prange` (threads, the lanes of one call shared among them), one thread per lane at a time, the
project's scalar kernels inside each lane. Without numba it is the same loop in Python.
"""
from collections import namedtuple

import numpy as np

from ..dynamics import kernels
from ..dynamics.jit import ENABLED, jit, jit_inline
from ..engine.impact_log import LOG_COLUMNS
from ..engine.stepping import (
    BUDGET,
    CLOCK_DT,
    CLOCK_K,
    CLOCK_T0,
    DONE,
    LOG_FULL,
    advance,
    total_energy,
)

# a lane's outcome after a call (`code`); LANE_GOES_ON: not yet (`after_advance`)
LANE_DONE, LANE_PAUSED, LANE_FAILED, LANE_GOES_ON = 0, 1, 2, -1

if ENABLED:
    import numba
    from numba.typed import List as LaneList

    prange = numba.prange

    def jit_lanes(function):
        """A compiled loop over lanes, its iterations run by numba's threads (cached on disk;
        the stale-cache sweep of `dynamics/jit.py` reads this module for its '@jit')."""
        return numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy",
                          fastmath=False)(function)

    def set_threads(count: int) -> int:
        """Threads for the next calls from this thread (at most numba's pool); returns it."""
        count = max(1, min(int(count), numba.config.NUMBA_NUM_THREADS))
        numba.set_num_threads(count)
        return count
else:
    prange = range
    LaneList = list

    def jit_lanes(function):
        return function

    def set_threads(count: int) -> int:
        return 1


def lane_list(items) -> "LaneList":
    """The per-lane records as the compiled call takes them (a typed list under numba)."""
    return LaneList(items)


@jit
def keep_impacts(stops, log, log_q, log_u, log_free, count):
    """Move the impact log's rows into the lane's own (log, log_q, log_u, log_free, count[0]
    rows in use) and empty it, as Python does after every call of a run alone
    (`Simulation._collect_impacts`); False, leaving the log as it is, when they do not fit."""
    rows = stops.count[0]
    if count[0] + rows > log.shape[0]:
        return False
    for r in range(rows):
        k = count[0] + r
        for j in range(log.shape[1]):
            log[k, j] = stops.log[r, j]
        for j in range(log_q.shape[1]):
            log_q[k, j] = stops.log_q[r, j]
        for j in range(log_u.shape[2]):
            log_u[k, 0, j] = stops.log_u[r, 0, j]
            log_u[k, 1, j] = stops.log_u[r, 1, j]
            log_free[k, j] = stops.log_free[r, j]
    count[0] += rows
    stops.count[0] = 0
    return True


@jit
def fixed_lane(method, system, stops, scr, s, clock, times, first, last, rows, rows_t, write,
               budget, log, log_q, log_u, log_free, count):
    """One lane from sample `first` towards sample `last` (exclusive), as `Simulation.advance_to`
    does it sample by sample (rows[i] = (s, T + V) at times[i] and rows_t[i] the lane's own
    clock there, `Simulation.t`, when `write`), its impacts moved after every call into its own
    log (`keep_impacts`). Returns (code, next sample, the stepping status that ended a failed
    lane): PAUSED when its log is full (Python reads it and the lane goes on)."""
    i = first
    while i < last:
        status = advance(method, system, stops, scr, s, clock, times[i], budget)
        code, i = after_advance(status, i, system, stops, s, clock, rows, rows_t, write, log,
                                log_q, log_u, log_free, count)
        if code != LANE_GOES_ON:
            return code, i, status
    return LANE_DONE, i, DONE


@jit_inline
def after_advance(status, i, system, stops, s, clock, rows, rows_t, write, log, log_q, log_u,
                  log_free, count):
    """What a lane does after each `advance` towards sample i that returned `status`: the
    sample written (rows[i] = (s, T + V), rows_t[i] the lane's clock, when `write`) once
    reached, the impacts moved into the lane's own log (`keep_impacts`). Returns (LANE_GOES_ON,
    or LANE_FAILED / LANE_PAUSED; the next sample)."""
    if status == DONE:
        if write:
            size = s.shape[0]
            for j in range(size):
                rows[i, j] = s[j]
            rows[i, size] = total_energy(system, s)
            rows_t[i] = clock[CLOCK_T0] + clock[CLOCK_K] * clock[CLOCK_DT]
        i += 1
    elif status != BUDGET and status != LOG_FULL:
        return LANE_FAILED, i
    if stops.count[0] > 0 and not keep_impacts(stops, log, log_q, log_u, log_free, count):
        return LANE_PAUSED, i
    return LANE_GOES_ON, i


@jit_lanes
def advance_fixed(methods, systems, stops, scratches, states, clocks, lanes, records, times,
                  last, rows, rows_t, write, budget, code, next_sample, failure, logs):
    """Every lane in `lanes` (its records at index records[j] of the lists) from its
    next_sample[lane] towards sample `last`, in parallel; each lane's outcome in code[lane],
    next_sample[lane] and failure[lane] (`fixed_lane`). rows[lane] are its samples (with
    `write`; else rows is one dummy row per lane); logs (`ImpactLogs`) its impacts."""
    for j in prange(lanes.shape[0]):
        lane, r = lanes[j], records[j]
        c, i, status = fixed_lane(methods[r], systems[r], stops[r], scratches[r], states[r],
                                  clocks[r], times, next_sample[lane], last, rows[lane],
                                  rows_t[lane], write, budget, logs.log[lane], logs.log_q[lane],
                                  logs.log_u[lane], logs.log_free[lane],
                                  logs.count[lane:lane + 1])
        code[lane] = c
        next_sample[lane] = i
        failure[lane] = status


@jit
def configuration_rates(model, samples, nq, nu, out):
    """q̇ at each sample row (q, u, …) into out[i] (n_q each): `kernels.configuration_rate` row by
    row, as `Dynamics.configuration_rate` gives it."""
    for i in range(samples.shape[0]):
        kernels.configuration_rate(model, samples[i, :nq], samples[i, nq:nq + nu], out[i])


# Rows of each lane's own impact log: the impacts of one call (a block of samples) that Python
# reads after it; a lane with more pauses, and goes on once they are read.
LOG_ROWS = 16

ImpactLogs = namedtuple("ImpactLogs", "log log_q log_u log_free count")


def impact_logs(lanes: int, nq: int, nu: int) -> ImpactLogs:
    """Each lane's own impact log, indexed by lane (`keep_impacts`; rows as `stops.StopsData`'s)."""
    return ImpactLogs(np.zeros((lanes, LOG_ROWS, LOG_COLUMNS)), np.zeros((lanes, LOG_ROWS, nq)),
                      np.zeros((lanes, LOG_ROWS, 2, nu)),
                      np.zeros((lanes, LOG_ROWS, nu), dtype=np.bool_),
                      np.zeros(lanes, dtype=np.int64))


def lane_log(logs: ImpactLogs, lane: int) -> ImpactLogs:
    """Lane `lane`'s own log, read by `Simulation._collect_impacts` as the stops' log (the same
    field names) and emptied by it."""
    return ImpactLogs(logs.log[lane], logs.log_q[lane], logs.log_u[lane], logs.log_free[lane],
                      logs.count[lane:lane + 1])


def empty_rows(lanes: int, size: int) -> np.ndarray:
    """Rows for calls that write none (`advance_to`): one row per lane, never written."""
    return np.zeros((lanes, 1, size + 1))
