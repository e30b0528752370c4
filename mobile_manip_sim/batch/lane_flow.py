"""One lane's control flow inside a group of lanes (`blocks.py`): `lanes.fixed_lane` and
`stepping.advance` around the grid step, resumable, so that the group can take the lanes' grid
steps together and everything else lane by lane, exactly as the run alone does it.

Compiled into `blocks.py`'s kernels: like every module whose code numba compiles into others,
it is read by the stale-cache sweep of `dynamics/jit.py` (which looks for '@jit' in a source).
"""
from __future__ import annotations

import math

from ..engine.stepping import (
    BUDGET,
    CLOCK_DT,
    CLOCK_K,
    CLOCK_STEPS,
    CLOCK_T0,
    DONE,
    LOG_FULL,
    step_with_events,
)
from .lanes import LANE_DONE, LANE_GOES_ON, after_advance
from .vector_steps import compiled_inline

NEED_STEP = -1       # `until_step`: the lane waits for its next whole grid step
# a slot's phase[...]: inside an `advance` call, steps taken in it, f(s) ready in stages[0], the
# status that ends the call (−1: none yet)
IN_CALL, TAKEN, K1_READY, ENDING = range(4)
# aim[...]: the call's whole grid steps to reach, and its steps as a real number
WHOLE, STEPS = range(2)


@compiled_inline
def until_step(method, system, stops, scr, s, clock, times, last, rows, rows_t, write, budget,
               log, log_q, log_u, log_free, count, phase, aim, at):
    """Lane control flow of `lanes.fixed_lane` and `stepping.advance`, resumed where it stopped
    (phase, aim; at[0] the next sample), run up to the lane's next whole grid step: returns
    (NEED_STEP, DONE) there, or the lane's outcome of this call (`fixed_lane`'s code and
    status). Everything but the grid step itself — the last shorter step to a sample off the
    grid, budgets, the log's room, the samples, the impacts moved to the lane's log — is done
    here, as they do it."""
    room = stops.log.shape[0] // 2
    while True:
        status = phase[ENDING]
        if status < 0:
            if phase[IN_CALL] == 0:   # `advance` to times[at[0]] begins
                if at[0] >= last:
                    return LANE_DONE, DONE
                steps = (times[at[0]] - clock[CLOCK_T0]) / clock[CLOCK_DT]
                aim[STEPS] = steps
                aim[WHOLE] = math.floor(steps + 1e-9)
                phase[IN_CALL] = 1
                phase[TAKEN] = 0
                phase[K1_READY] = 0
            if clock[CLOCK_K] < aim[WHOLE]:
                if phase[TAKEN] >= budget:
                    status = BUDGET
                elif stops.count[0] > room:
                    status = LOG_FULL
                else:
                    return NEED_STEP, DONE
            else:
                status = DONE
                if aim[STEPS] - aim[WHOLE] > 1e-9:   # the sample is off the grid
                    if stops.count[0] > room:
                        status = LOG_FULL
                    else:
                        dt = clock[CLOCK_DT]
                        t_end = times[at[0]]
                        t = clock[CLOCK_T0] + clock[CLOCK_K] * dt
                        status = step_with_events(method, system, stops, scr, s, t_end - t, t,
                                                  clock)
                        if status == DONE:
                            clock[CLOCK_STEPS] += 1.0
                            clock[CLOCK_T0], clock[CLOCK_K] = t_end, 0.0
        # `advance` returned `status`: what `fixed_lane` does with it
        phase[ENDING] = -1
        phase[IN_CALL] = 0
        code, at[0] = after_advance(status, at[0], system, stops, s, clock, rows, rows_t, write,
                                    log, log_q, log_u, log_free, count)
        if code != LANE_GOES_ON:
            return code, status


@compiled_inline
def stepped(clock, phase, status, k1_ready):
    """After the lane's grid step: as `advance` books it, or the status that ends the call."""
    if status != DONE:
        phase[ENDING] = status
    else:
        clock[CLOCK_K] += 1.0
        clock[CLOCK_STEPS] += 1.0
        phase[TAKEN] += 1
        phase[K1_READY] = 1 if k1_ready else 0


