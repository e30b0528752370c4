"""The adaptive core, compiled end to end: Dormand–Prince 5(4) (`rk45`) and 8(5,3) (`dop853`)
of `runge_kutta.py` with error control. One call advances to a target time (or fills a whole
array of samples) with every step, crossing check, event location on the step's dense output,
impact, rest and release, and the Zeno guard inside compiled code; Python is entered once per
call — and, as in `stepping.py`, whenever a call has used its step budget.

One solve runs from its start until a discontinuity (an impact, a release, a command change:
`restart`); the step is never cut at a target or a sample. The last accepted step stays *in hand*
(`Solve`: its start y₀, stages, y₁, f(y₀), f(y₁)): targets and samples inside it are read from
its dense output, which is built only when a target, a sample or an event lies in the step (3
right-hand sides for dop853 unless its stages alone give one within the tolerance for the
samples, none for rk45); the next step starts from y₁ with f(y₁) (FSAL). An
event found in the step ends the solve there: it is applied once a target passes it, and the
solve restarts from the event with the length of the step that held it as its first try.

SciPy's radau and bdf use the same bookkeeping from Python (`Simulation._advance_scipy`): each
SciPy step, its interpolant a `dense.POWER` series, becomes the step in hand (`reach`,
`locate_event`), so every adaptive method shares the event handling and the Zeno guard.

The Zeno guard is `events.zeno_guard`, the fixed-step core's too (called by `stops.impact`): it
reads the impact times alone, never the step.

The simulated time is clock[CLOCK_T0] of `stepping.py`'s clock (CLOCK_K stays 0); CLOCK_STEPS
and the energy ledger (CLOCK_LOST, CLOCK_HELD, CLOCK_HOLDS) as there.
"""
import math
from collections import namedtuple

import numpy as np

from ..dynamics.jit import jit
from . import layout
from . import runge_kutta as rk
from .dense import Interpolant, interpolate
from .events import crossing_in_step, first_crossing, first_release
from .sampling import next_update
from .status import BUDGET, CONTACT_FAILED, CRAWLING, DONE, LOG_FULL, NOT_FINITE, STALLED
from .step_watch import clear, make_watch, watch_step
from .stepping import (
    CLOCK_STEPS,
    CLOCK_T0,
    CLOCK_UPDATES,
    any_watched,
    apply_update,
    book,
    copy_into,
    finite,
    stretch_end,
    total_energy,
)
from .stops import any_resting, impact, release
from .system import HOLDING_LEAST_MARGIN, clear_holding, derivative

# Solve.status[...] entries
(STEP_T0,     # start of the step in hand (s)
 STEP_H,      # its length (s); 0: none in hand, the next step starts a new solve at (t, s)
 H_NEXT,      # the next step to try (s); 0: `rk.initial_step` picks one
 DENSE,       # 0 no interpolant of the step in hand yet; FULL or FROM_STAGES (`interpolant`)
 EVENT,       # NO_EVENT, IMPACT or LEAVE: the first event in the step in hand
 EVENT_H,     # its time into the step (s)
 EVENT_K,     # the rod (1-based) and the stop (−1 lower, +1 upper) of an impact
 EVENT_SIDE) = range(8)
N_STATUS = 8
NO_EVENT, IMPACT, LEAVE = 0, 1, 2
FULL, FROM_STAGES = 1.0, 2.0   # Solve.status[DENSE]: dense_prepare's, or dense_from_stages'

Solve = namedtuple("Solve", [
    "work",       # (rk.WORK_ROWS, size) the step in hand: stages, interpolant, f₀, f₁, y₁, errors
    "start",      # (size,) y₀, the state at the start of the step in hand
    "event",      # (size,) the state at its event (an impact: l_k exactly at the stop)
    "tolerance",  # (2,) rtol, atol (per component of s, in its own units)
    "status",     # (N_STATUS,) the solve's bookkeeping, entries above
    "watch",      # (3,) the run's progress count (`step_watch`)
])


def make_solve(size: int, rtol: float, atol: float) -> Solve:
    return Solve(rk.work_array(size), np.zeros(size), np.zeros(size), np.array([rtol, atol]),
                 np.zeros(N_STATUS), make_watch())


# --- the step in hand as Python sees it: SciPy's radau and bdf hand their steps in ------------

def new_solve(solve: Solve) -> None:
    """A fresh solve (after a reset): no step in hand, `rk.initial_step` picks the first."""
    solve.status[:] = 0.0
    clear(solve.watch)


def step_in_hand(solve: Solve) -> tuple[float, float]:
    """(start, length) of the step in hand; length 0: none (the next starts a new solve)."""
    return float(solve.status[STEP_T0]), float(solve.status[STEP_H])


def next_step(solve: Solve) -> float:
    """The next step to try (s); 0: none chosen yet; NaN: a stage overflowed."""
    return float(solve.status[H_NEXT])


def drop_step(solve: Solve) -> None:
    """No step in hand: the next one starts a new solve."""
    solve.status[STEP_H] = 0.0


def begin_step(solve: Solve, t0: float, y0) -> None:
    """An outside solver's step starts at (t0, y0)."""
    solve.status[STEP_T0] = t0
    solve.start[:] = y0


def hand_in_step(solve: Solve, h: float, y1, series) -> None:
    """An outside solver's step of length h as the step in hand: its end state y1 and its
    interpolant as a power series (at most `rk.MAX_DENSE` rows), no event located yet."""
    work, status = solve.work, solve.status
    work[rk.WORK_Y1] = y1
    coeffs = work[rk.WORK_COEFFS:rk.WORK_COEFFS + rk.MAX_DENSE]
    coeffs[:] = 0.0
    coeffs[:len(series)] = series
    status[STEP_H] = h
    status[DENSE] = FULL
    status[EVENT] = NO_EVENT


def step_end(solve: Solve):
    """The step in hand's end state y₁ (a view)."""
    return solve.work[rk.WORK_Y1]


def set_step_end_derivative(solve: Solve, f1) -> None:
    """f(y₁) of the step in hand (the release check reads it)."""
    solve.work[rk.WORK_F1] = f1


@jit
def restart(solve):
    """A discontinuity at the current (t, s): drop the step in hand; the next step starts a new
    solve there, trying the length of the last step taken."""
    status = solve.status
    if status[STEP_H] > 0.0:
        status[H_NEXT] = status[STEP_H]
    status[STEP_H] = 0.0
    status[EVENT] = NO_EVENT


@jit
def interpolant(method, system, solve, for_events):
    """The dense output of the step in hand, built on first use: for dop853 from the step's
    stages when that is accurate enough (`rk.dense_from_stages`), otherwise with 3 more
    right-hand sides. An event is located on the full one (`for_events`): its time and state
    start the next solve, so they get the better interpolant; samples only read it."""
    work, status = solve.work, solve.status
    coeffs = work[rk.WORK_COEFFS:rk.WORK_COEFFS + rk.MAX_DENSE]
    if status[DENSE] == 0.0 or (for_events and status[DENSE] == FROM_STAGES):
        K = work[rk.WORK_K:rk.WORK_K + rk.MAX_STAGES]
        if not for_events and rk.dense_from_stages(method, solve.start, work[rk.WORK_Y1],
                                                   status[STEP_H], K, coeffs, solve.tolerance[0],
                                                   solve.tolerance[1]):
            status[DENSE] = FROM_STAGES
        else:
            rk.dense_prepare(method, system, solve.start, work[rk.WORK_Y1], work[rk.WORK_F0],
                             work[rk.WORK_F1], status[STEP_H], K, coeffs)
            status[DENSE] = FULL
    return Interpolant(method, coeffs, status[STEP_H])


@jit
def locate_event(method, system, stops, scr, solve):
    """The first event in the step in hand, into solve.status[EVENT…] and solve.event: a watched
    rod reaching a stop, or the instant a resting rod's stop would start to pull."""
    work, status, start = solve.work, solve.status, solve.start
    y1, h = work[rk.WORK_Y1], status[STEP_H]
    # Every evaluation of the step (its stages, f(y₁)) sampled the holding forces
    # (`system.watch_holding`): read before the interpolant's stages evaluate anything else.
    pulled = any_resting(stops) and system.holding[HOLDING_LEAST_MARGIN] < 0.0
    if any_watched(stops) and crossing_in_step(start, y1, h, system, stops.watched, stops.stroke):
        dense = interpolant(method, system, solve, True)
        h_hit, k, side = first_crossing(method, system, start, h, stops.watched, stops.resting,
                                        stops.stroke, scr.samples, scr.crossed, scr.trial,
                                        scr.stages, scr.forces, dense)
        if k != 0:
            interpolate(dense, start, h_hit, solve.event)
            solve.event[layout.q_slide(k)] = (stops.stroke[k - 1, 0] if side < 0
                                              else stops.stroke[k - 1, 1])
            status[EVENT], status[EVENT_H] = IMPACT, h_hit
            status[EVENT_K], status[EVENT_SIDE] = k, side
    if pulled:
        dense = interpolant(method, system, solve, True)
        h_leave = first_release(method, system, start, h, stops.resting, scr.trial, scr.stages,
                                scr.forces, dense)
        # whichever comes first: the other one is found again by the solve restarted there
        if h_leave >= 0.0 and (status[EVENT] == NO_EVENT or h_leave < status[EVENT_H]):
            interpolate(dense, start, h_leave, solve.event)
            status[EVENT], status[EVENT_H] = LEAVE, h_leave


@jit
def take_step(method, system, stops, scr, solve, s, clock):
    """One accepted step after the step in hand (or starting a new solve at (t, s)), its first
    event located. Returns DONE, NOT_FINITE (the bad state in scr.out), STALLED or CRAWLING."""
    work, status, start = solve.work, solve.status, solve.start
    rtol, atol = solve.tolerance[0], solve.tolerance[1]
    f0, f1, y1 = work[rk.WORK_F0], work[rk.WORK_F1], work[rk.WORK_Y1]
    if status[STEP_H] > 0.0:
        status[STEP_T0] += status[STEP_H]
        copy_into(y1, start)
        copy_into(f1, f0)   # FSAL: f(y₁) is the next step's first stage
    else:
        status[STEP_T0] = clock[CLOCK_T0]
        copy_into(s, start)
        derivative(system, start, f0)
        if status[H_NEXT] <= 0.0:
            status[H_NEXT] = rk.initial_step(method, system, start, f0, math.inf, rtol, atol,
                                             math.inf, y1, f1)
    clear_holding(system)
    # no step across an update of sampled controllers (their held efforts jump there)
    h, h_next = rk.accepted_step(method, system, start, status[STEP_T0], status[H_NEXT],
                                 next_update(system, clock[CLOCK_UPDATES]), rtol, atol, work)
    if h < 0.0:
        status[STEP_H] = 0.0
        return STALLED
    clock[CLOCK_STEPS] += 1.0
    status[STEP_H], status[H_NEXT], status[DENSE], status[EVENT] = h, h_next, 0.0, NO_EVENT
    if not finite(y1):
        copy_into(y1, scr.out)
        return NOT_FINITE
    if watch_step(solve.watch, status[STEP_T0], h):
        return CRAWLING
    locate_event(method, system, stops, scr, solve)
    return DONE


@jit
def apply_event(system, stops, scr, solve, s, clock):
    """Move (t, s) to the event of the step in hand, apply it, and restart the solve there."""
    status = solve.status
    t = status[STEP_T0] + status[EVENT_H]
    copy_into(solve.event, s)
    clock[CLOCK_T0] = t
    if status[EVENT] == IMPACT:
        book(clock, impact(system, stops, s, int(status[EVENT_K]), int(status[EVENT_SIDE]), t,
                           scr.impact, scr.stages[3], scr.forces))
    else:
        release(system, stops, s, scr.impact, scr.stages[3], scr.forces, True)
    restart(solve)


@jit
def inside_step(method, solve, s, clock, t_end):
    """Move (t, s) to t_end (s) when it lies in the step in hand, not past its event, and its
    interpolant is built (or t_end is the step's end): True; otherwise False, nothing changed.
    It takes none of the system's records, so that Python can call it cheaply for a target
    inside the step (a call from Python unboxes every array it is given)."""
    status = solve.status
    if t_end <= clock[CLOCK_T0]:
        return True
    h, t0 = status[STEP_H], status[STEP_T0]
    event = status[EVENT] != NO_EVENT
    if h <= 0.0 or t_end > t0 + (status[EVENT_H] if event else h):
        return False
    if t_end == t0 + h and not event:
        copy_into(solve.work[rk.WORK_Y1], s)   # the step's end, exactly
    elif status[DENSE] == 0.0:
        return False
    else:
        dense = Interpolant(method, solve.work[rk.WORK_COEFFS:rk.WORK_COEFFS + rk.MAX_DENSE], h)
        interpolate(dense, solve.start, t_end - t0, s)
    clock[CLOCK_T0] = t_end
    return True


@jit
def reach(method, system, stops, scr, solve, s, clock, t_end):
    """Move (t, s) to t_end (s) inside the step in hand, or to its event when t_end lies past the
    event (which is then applied). True when (t, s) is at t_end, False when a new step is needed."""
    if inside_step(method, solve, s, clock, t_end):
        return True
    status = solve.status
    h = status[STEP_H]
    if h <= 0.0:
        return False
    if status[EVENT] != NO_EVENT:
        if t_end > status[STEP_T0] + status[EVENT_H]:
            apply_event(system, stops, scr, solve, s, clock)
            return False
    elif t_end > status[STEP_T0] + h:
        return False
    interpolant(method, system, solve, False)   # t_end is inside: build what `inside_step` reads
    return inside_step(method, solve, s, clock, t_end)


@jit
def advance(method, system, stops, scr, solve, s, clock, t_end, max_steps):
    """Advance (t, s) to exactly t_end (s). Returns DONE, or BUDGET after max_steps steps,
    LOG_FULL when the impact log needs emptying, NOT_FINITE (scr.out holds the bad state) or
    STALLED (the step fell below 10 ulps of t; solve.status[H_NEXT] the step tried). Sampled
    controllers are updated on the way at each of their instants before t_end (`sampling.py`);
    the steps end there (`take_step`) and the solve restarts there. One due at t_end is the next
    call's first act (`stepping.advance`)."""
    if system.rate <= 0.0:
        return advance_between_updates(method, system, stops, scr, solve, s, clock, t_end,
                                       max_steps)
    steps = clock[CLOCK_STEPS]
    while True:
        t_stop, due = stretch_end(system, clock, t_end)
        status = advance_between_updates(method, system, stops, scr, solve, s, clock, t_stop,
                                         max_steps - int(clock[CLOCK_STEPS] - steps))
        if status == DONE and due:
            status = apply_update(system, stops, scr, s, clock)
            restart(solve)
        if status != DONE or not due:
            return status


@jit
def advance_between_updates(method, system, stops, scr, solve, s, clock, t_end, max_steps):
    """`advance` with no update of sampled controllers due before t_end."""
    room = stops.log.shape[0] // 2
    taken = 0
    while not reach(method, system, stops, scr, solve, s, clock, t_end):
        if stops.failed[0] != 0:
            return CONTACT_FAILED
        if taken >= max_steps:
            return BUDGET
        if stops.count[0] > room:
            return LOG_FULL
        status = take_step(method, system, stops, scr, solve, s, clock)
        if status != DONE:
            return status
        taken += 1
    return DONE


@jit
def advance_samples(method, system, stops, scr, solve, s, clock, times, rows, first, max_steps):
    """`advance` to each of times[first:], writing (s, T + V) into rows[i]; returns (status,
    next sample index) — the caller calls again after BUDGET or LOG_FULL. The budget counts
    steps only: a sample inside the step in hand costs none."""
    steps = clock[CLOCK_STEPS]
    for i in range(first, times.shape[0]):
        status = advance(method, system, stops, scr, solve, s, clock, times[i],
                         max_steps - int(clock[CLOCK_STEPS] - steps))
        if status != DONE:
            return status, i
        copy_into(s, rows[i])
        rows[i, s.shape[0]] = total_energy(system, s)
    return DONE, times.shape[0]
