"""The fixed-step core, compiled end to end: one call advances to a target time (or fills a whole
array of samples) with every step, crossing check, event location, impact, rest and release,
and the Zeno guard inside compiled code. Python is entered once per call — and, so that signals,
`~/pause` and `~/reset` act promptly, whenever a call has used its step budget.

The Zeno guard is `events.zeno_guard`, the adaptive core's too (called by `stops.impact`). A
step whose impacts would overflow the impact log (rods released and hitting again without end)
ends the call with CHATTER, the last resort.

The time line: t = t0 + k·dt with an integer step count k (so that long runs land exactly on
k·dt); a target off that grid ends in one shorter step, after which the grid restarts there.
"""
import math
from collections import namedtuple

import numpy as np

from ..dynamics import kernels
from ..dynamics.jit import jit, jit_inline
from ..scene.coordinates import arm_size
from . import layout
from .events import (
    N_SAMPLES,
    crossing_in_step,
    first_crossing,
    first_release,
    holding_margin,
    step_state,
)
from .fixed_step import inlined_step, step
from .sampling import next_update, update_at_instant
from .status import BUDGET, CHATTER, CONTACT_FAILED, DONE, LOG_FULL, NOT_FINITE  # why it returned
from .stops import any_resting, impact, release
from .system import HOLDING_LEAST_MARGIN, clear_holding

# clock[...] entries: CLOCK_LOST the energy the impact law removed (J), CLOCK_HELD the energy holds
# removed beyond it (J), CLOCK_HOLDS how many impacts were held (`stops.impact`), CLOCK_UPDATES
# how many updates the sampled controllers took (`sampling.py`; the next is due at
# CLOCK_UPDATES · period)
(CLOCK_T0, CLOCK_DT, CLOCK_K, CLOCK_STEPS, CLOCK_LOST, CLOCK_HELD, CLOCK_HOLDS,
 CLOCK_UPDATES) = range(8)
CLOCK_SIZE = 8

StepScratch = namedtuple("StepScratch", [
    "out",      # (size,) the step's end state
    "trial",    # (size,) trial steps of the event functions
    "stages",   # (4, size) Runge–Kutta stages
    "forces",   # (size,) holding forces (first n_u entries)
    "samples",  # (N_SAMPLES + 2n,) instants bracketing a crossing
    "crossed",  # (n,) int64: the stop (−1, +1) each rod is past at the bracket's end, or 0
    "impact",   # stops.ImpactScratch
])


def make_scratch(size: int, n_links: int, impact_scratch) -> StepScratch:
    return StepScratch(np.zeros(size), np.zeros(size), np.zeros((4, size)),
                       np.zeros(size), np.zeros(N_SAMPLES + arm_size(n_links)),
                       np.zeros(max(n_links, 1), dtype=np.int64), impact_scratch)


@jit_inline
def finite(s):
    for i in range(s.shape[0]):
        if not math.isfinite(s[i]):
            return False
    return True


@jit_inline
def copy_into(source, target):
    for i in range(source.shape[0]):
        target[i] = source[i]


@jit_inline
def any_watched(stops):
    for k in range(stops.watched.shape[0]):
        if stops.watched[k]:
            return True
    return False


@jit_inline
def book(clock, ledger):
    """Add an impact's (law, hold, held) energies and count (`stops.impact`) to the ledger."""
    lost, removed, held = ledger
    clock[CLOCK_LOST] += lost
    clock[CLOCK_HELD] += removed
    clock[CLOCK_HOLDS] += held


@jit
def step_with_events(method, system, stops, scr, s, h, t, clock):
    """One step of length h from time t in which end stops may be hit and resting rods leave
    them, again and again: the first event in what is left of the step — a crossing
    (`first_crossing`) or the instant a resting rod's stop would start to pull (`locate`
    RELEASE) — is located on the integrator's own step, applied there (`impact`, `release`),
    and the step goes on from it. CHATTER when the impact log has no room for the next impact."""
    dt = clock[CLOCK_DT]
    capacity = stops.log.shape[0]
    n = stops.resting.shape[0]
    for _ in range(2 * capacity):
        clear_holding(system)
        step(method, system, s, h, scr.out, scr.stages)
        if not finite(scr.out):
            return NOT_FINITE
        h_hit, k, side = -1.0, 0, 0
        if any_watched(stops) and crossing_in_step(s, scr.out, h, system, stops.watched,
                                                   stops.stroke):
            h_hit, k, side = first_crossing(method, system, s, h, stops.watched, stops.resting,
                                            stops.stroke, scr.samples, scr.crossed, scr.trial,
                                            scr.stages, scr.forces)
        h_leave = -1.0
        if any_resting(stops) and (holding_margin(system, scr.out, stops.resting, scr.stages[0],
                                                  scr.forces) < 0.0
                                   or system.holding[HOLDING_LEAST_MARGIN] < 0.0):
            # a stage (or the end) saw a stop pull: find the first pull on the step itself
            h_leave = first_release(method, system, s, h, stops.resting, scr.trial, scr.stages,
                                    scr.forces)
        if k == 0 and h_leave < 0.0:   # no event (or the Hermite path dipped, the step did not)
            copy_into(scr.out, s)
            return DONE
        if k == 0 or 0.0 <= h_leave < h_hit:
            # A resting rod is pulled off its stop: released at that instant, not a step later.
            step_state(method, system, s, h_leave, scr.trial, scr.stages)
            copy_into(scr.trial, s)
            h -= h_leave
            t += h_leave
            release(system, stops, s, scr.impact, scr.stages[3], scr.forces, True)
            if stops.failed[0] != 0:
                return CONTACT_FAILED
        else:
            if stops.count[0] + n > capacity:
                # The log is full within one step: rods released and hitting again without end
                # (or more rods chattering at once than it was sized for): reported, not run on.
                return CHATTER
            step_state(method, system, s, h_hit, scr.trial, scr.stages)
            copy_into(scr.trial, s)
            s[layout.q_slide(k)] = stops.stroke[k - 1, 0] if side < 0 else stops.stroke[k - 1, 1]
            h -= h_hit
            t += h_hit
            book(clock, impact(system, stops, s, k, side, t, scr.impact, scr.stages[3],
                               scr.forces))
            if stops.failed[0] != 0:
                return CONTACT_FAILED
        if h <= 1e-15 * dt:
            return DONE
    return CHATTER


@jit_inline
def grid_step(method, system, stops, scr, s, clock, k1_ready):
    """One whole step dt on the grid, events and releases included. Returns the status and
    whether scr.stages[0] now holds f(s) for the next step (the release check computed it).
    The right-hand side is inlined (`fixed_step.inlined_step`): nearly every step of a run is
    one of these."""
    dt, t = grid_step_start(system, clock)
    inlined_step(method, system, s, dt, scr.out, scr.stages, k1_ready)
    return grid_step_end(method, system, stops, scr, s, clock, dt, t)


@jit_inline
def grid_step_calling(method, system, stops, scr, s, clock, k1_ready):
    """`grid_step` with the right-hand side called (`fixed_step.step`), for the batch's groups
    (`batch.blocks.run_group`). Inlined there, beside the vector steps' copies of the same small
    kernels, every lane that took vector steps came out wrong although the scalar runs were
    right; the fault inside numba's inlining was not pinned down (two inlined copies of one
    overload sharing variable names, `system.arm_stage`, was one such fault)."""
    dt, t = grid_step_start(system, clock)
    step(method, system, s, dt, scr.out, scr.stages, k1_ready)
    return grid_step_end(method, system, stops, scr, s, clock, dt, t)


@jit_inline
def grid_step_start(system, clock):
    """dt and the step's start time; the holding watch cleared."""
    dt = clock[CLOCK_DT]
    clear_holding(system)
    return dt, clock[CLOCK_T0] + clock[CLOCK_K] * dt


@jit_inline
def grid_step_end(method, system, stops, scr, s, clock, dt, t):
    """After the grid step's trial step into scr.out: events and releases, or s = out."""
    if not finite(scr.out):
        return NOT_FINITE, False
    # The holding forces need f(out), which is the next step's first stage: computed once. The
    # stages sampled them inside the step (`system.watch_holding`).
    if (any_watched(stops) and crossing_in_step(s, scr.out, dt, system, stops.watched,
                                                stops.stroke)
            or any_resting(stops) and (holding_margin(system, scr.out, stops.resting,
                                                      scr.stages[0], scr.forces) < 0.0
                                       or system.holding[HOLDING_LEAST_MARGIN] < 0.0)):
        return step_with_events(method, system, stops, scr, s, dt, t, clock), False
    copy_into(scr.out, s)
    return DONE, any_resting(stops)


@jit
def advance(method, system, stops, scr, s, clock, t_end, max_steps):
    """Advance s to exactly t_end (s). Returns DONE, or BUDGET after max_steps steps, LOG_FULL
    when the impact log needs emptying, NOT_FINITE (s then holds the last finite state).
    Sampled controllers are updated on the way at each of their instants before t_end
    (`sampling.py`): a step ends there, as at a target off the grid. An update due at t_end
    itself is left to the next call, which applies it first, after the commands set between
    the calls: a command given at an update instant is taken at that update."""
    if system.rate <= 0.0:
        return advance_between_updates(method, system, stops, scr, s, clock, t_end, max_steps)
    steps = clock[CLOCK_STEPS]
    while True:
        t_stop, due = stretch_end(system, clock, t_end)
        status = advance_between_updates(method, system, stops, scr, s, clock, t_stop,
                                         max_steps - int(clock[CLOCK_STEPS] - steps))
        if status == DONE and due:
            status = apply_update(system, stops, scr, s, clock)
        if status != DONE or not due:
            return status


@jit_inline
def stretch_end(system, clock, t_end):
    """Where the next stretch of `advance` ends: (t_end, or the next update of sampled
    controllers when it comes first, and whether that update is due there). An update at t_end
    is not due in this call: the next call's first stretch, empty, ends at it."""
    t_update = next_update(system, clock[CLOCK_UPDATES])
    return min(t_end, t_update), t_update < t_end


@jit_inline
def apply_update(system, stops, scr, s, clock):
    """The update of sampled controllers due now (`sampling.update_at_instant`): DONE, or
    CONTACT_FAILED."""
    clock[CLOCK_UPDATES] += 1.0
    return CONTACT_FAILED if update_at_instant(system, stops, scr, s) else DONE


@jit
def advance_between_updates(method, system, stops, scr, s, clock, t_end, max_steps):
    """`advance` with no update of sampled controllers due before t_end."""
    dt = clock[CLOCK_DT]
    steps = (t_end - clock[CLOCK_T0]) / dt
    whole = math.floor(steps + 1e-9)
    room = stops.log.shape[0] // 2
    taken = 0
    k1_ready = False
    while clock[CLOCK_K] < whole:
        if taken >= max_steps:
            return BUDGET
        if stops.count[0] > room:
            return LOG_FULL
        status, k1_ready = grid_step(method, system, stops, scr, s, clock, k1_ready)
        if status != DONE:
            return status
        clock[CLOCK_K] += 1.0
        clock[CLOCK_STEPS] += 1.0
        taken += 1
    if steps - whole > 1e-9:  # t_end is off the grid: a last, shorter step
        if stops.count[0] > room:
            return LOG_FULL
        t = clock[CLOCK_T0] + clock[CLOCK_K] * dt
        status = step_with_events(method, system, stops, scr, s, t_end - t, t, clock)
        if status != DONE:
            return status
        clock[CLOCK_STEPS] += 1.0
        clock[CLOCK_T0], clock[CLOCK_K] = t_end, 0.0
    return DONE


@jit
def total_energy(system, s):
    """T + V (J) at s."""
    nq, nu = layout.sizes(system)
    kernels.frames(system.model, s[:nq], system.ws)
    T = kernels.kinetic_energy(system.model, s[:nq], s[nq:nq + nu], system.ws)
    return T + kernels.potential_energy(system.model, s[:nq], system.gravity, system.ws)


@jit
def advance_samples(method, system, stops, scr, s, clock, times, rows, first, max_steps):
    """`advance` to each of times[first:], writing (s, T + V) into rows[i]; returns (status,
    next sample index) — the caller calls again after BUDGET or LOG_FULL."""
    size = s.shape[0]
    i = first
    budget = max_steps
    while i < times.shape[0]:
        before = clock[CLOCK_STEPS]
        status = advance(method, system, stops, scr, s, clock, times[i], budget)
        budget -= int(clock[CLOCK_STEPS] - before)
        if status != DONE:
            return status, i
        for j in range(size):
            rows[i, j] = s[j]
        rows[i, size] = total_energy(system, s)
        i += 1
        if budget <= 0 and i < times.shape[0]:
            return BUDGET, i
    return DONE, i
