"""Lanes stepped four at a time: the plain grid steps of lanes that share a right-hand side
computed together in vector lanes.

A group is up to GROUP lanes of one method and one state layout (`block_keys`), run by one
thread. Each lane keeps its own records and follows exactly the calls of a run alone
(`lanes.fixed_lane`: one `stepping.advance` per sample, its step budget, the impact log emptied
after every call): the group runs that control flow for each lane separately (`until_step`, a
resumable copy of `advance` and `fixed_lane` around the grid step) up to the point where the lane
needs its next whole grid step. The lanes that are there together and may share a right-hand
side (`plain`: no wheel-speed loop, no arm controller; `same_right_hand_side`: one method, the
same locks) form blocks of four (`form_blocks`); a block of at least MIN_VECTOR lanes takes that
step together: every stage's dynamics in `dynamics.lanes.rates` (`Vec4`, four lanes per
instruction, each lane performing the scalar kernels' operations in their order), the efforts,
damping, work rate, holding watch and stage sums lane by lane in scalar code as
`system.derivative`, `system.watch_holding` and `fixed_step.step` do them. Then each lane's end
state is checked by the very tests the scalar grid step runs after a step (non-finite, the
crossing check, the resting rods' holding margins); a lane whose step has nothing else to do
takes it (its counters, holding watch, f(end) and holding forces left as the scalar step leaves
them), any other lane throws the vector result away and takes the step with the scalar
`stepping.grid_step` from its untouched state — events, impacts, releases and failures then run
exactly as in its run alone. So every lane is bit for bit its own run; the blocks only decide
who computes a plain step.

Nothing compiled elsewhere calls into this module, so an edit of it needs no sweep of the other
modules' caches (numba recompiles this module's functions from their own source).
"""
from __future__ import annotations

import math

import numpy as np

from ..dynamics.jit import ENABLED
from ..dynamics.kernels import configuration_rate
from ..dynamics.lane_arrays import wrap
from ..dynamics.lanes import ModelStack, block_model, rates
from ..dynamics.records import Workspace
from ..engine import layout
from ..engine.arm_control import ARM_ON
from ..engine.events import crossing_in_step
from ..engine.fixed_step import EULER, SEMI_IMPLICIT_EULER
from ..engine.stepping import (
    BUDGET,
    CLOCK_DT,
    CLOCK_K,
    CLOCK_STEPS,
    CLOCK_T0,
    DONE,
    LOG_FULL,
    any_watched,
    copy_into,
    finite,
    grid_step,
    step_with_events,
    total_energy,
)
from ..engine.stops import any_resting
from ..engine.system import (
    CROSSING_CHECKS,
    DAMPING_STAGE,
    HOLDING_LEAST_MARGIN,
    HOLDING_ON,
    REDUCED_SOLVE,
    RHS_EVALS,
    WHEEL_VELOCITY_MODE,
)
from .lanes import LANE_DONE, LANE_FAILED, LANE_PAUSED, keep_impacts

WIDTH = 4
NEED_STEP = -1       # `until_step`: the lane waits for its next whole grid step
MIN_VECTOR = 2       # lanes ready together for the vector step to pay (one lane: scalar)
# a slot's phase[...]: inside an `advance` call, steps taken in it, f(s) ready in stages[0], the
# status that ends the call (−1: none yet)
IN_CALL, TAKEN, K1_READY, ENDING = range(4)
# aim[...]: the call's whole grid steps to reach, and its steps as a real number
WHOLE, STEPS = range(2)
# paths[lane, ...]: grid steps taken by the vector right-hand side, by the scalar one
VECTOR_STEPS, SCALAR_STEPS = range(2)

if ENABLED:
    import numba

    def _compiled(function):
        return numba.njit(cache=True, nogil=True, error_model="numpy",
                          fastmath=False)(function)

    def _compiled_inline(function):
        return numba.njit(cache=True, nogil=True, error_model="numpy", fastmath=False,
                          inline="always", _nrt=False)(function)

    def _compiled_lanes(function):
        return numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy",
                          fastmath=False)(function)

    def _vector(function):
        return numba.njit(cache=True, nogil=True, error_model="numpy", fastmath=False,
                          _nrt=False)(function)

    prange = numba.prange
else:
    def _compiled(function):
        return function

    _compiled_inline = _compiled_lanes = _vector = _compiled
    prange = range


# ------------------------------------------------------------------- one block's vector step

@_compiled_inline
def _block_workspace(w):
    return Workspace(wrap(w.R), wrap(w.O), wrap(w.x), wrap(w.z), wrap(w.F), wrap(w.N),
                     wrap(w.S), wrap(w.V), wrap(w.C), wrap(w.U), wrap(w.D_inv), wrap(w.u_art),
                     wrap(w.I_art), wrap(w.p_art), w.moving, wrap(w.slide),
                     wrap(w.slide_force))


@_compiled_inline
def _block_derivative(model, ws, wraw, g, free, nq, nu, y, d, qcmd, damp, qb, has_damping, watch,
                      rest, least):
    """d = f(y) for the four lanes (states as (size, 4) columns): what `system.derivative`
    computes in effort mode without controllers — q̇, u̇ in vector lanes (`rates`); Q = Q_cmd −
    c ⊙ u, ė = 0, Ẇ = Q·u and, for the lanes in `watch`, the holding watch
    (`system.watch_holding`: least[j] the smallest margin of lane j's resting rods, ``rest``)
    lane by lane, in its order."""
    i_e, i_w = layout.controller(nq, nu), layout.work(nq, nu)
    for j in range(WIDTH):
        power = 0.0
        for k in range(nu):
            qb[k, j] = qcmd[k, j]
        for k in range(nu):
            power += qb[k, j] * y[nq + k, j]
        if has_damping:
            for k in range(nu):
                u_k = y[nq + k, j]
                qb[k, j] -= damp[k, j] * u_k
                power -= damp[k, j] * u_k * u_k
        d[i_e, j] = 0.0
        d[i_e + 1, j] = 0.0
        d[i_w, j] = power
    rates(model, wrap(y[:nq]), wrap(y[nq:nq + nu]), wrap(qb), g, free, ws, wrap(d[:nq]),
          wrap(d[nq:nq + nu]))
    for j in range(WIDTH):
        if watch[j]:
            margin = _margin(wraw, qb, rest, j)
            if margin < least[j]:
                least[j] = margin


@_compiled_inline
def _margin(wraw, qb, rest, j):
    """`system.holding_margin_now` of lane j right after a `_block_derivative`."""
    margin = math.inf
    for k in range(1, rest.shape[0] + 1):
        if rest[k - 1, j] != 0:
            i = layout.u_slide(k)
            margin = min(margin, -rest[k - 1, j] * (wraw.slide_force[k, j] - qb[i, j]))
    return margin


@_vector
def vector_step(method, stack, b, gravity, free, wraw, nq, nu, x, out, k, qcmd, damp, qb, h,
                has_damping, watch, have_k1, rest, least, end):
    """One step of each lane j from x[:, j] by h[j] into out[:, j], the stages in k: the
    operations of `fixed_step.step`, in its order, lane by lane (block b of the stack's models).
    A lane in have_k1 takes its first stage as k[0][:, j] holds it (f(x) of its last step; the
    watch skips it, as the scalar step does). With ``end``, also f(out) into k[4] (watched): what
    the scalar grid step computes after a step while a rod rests. least: the lanes' smallest
    holding margins over the step."""
    model = block_model(stack, b)
    ws = _block_workspace(wraw)
    g = wrap(gravity[b])[0]
    size = x.shape[0]
    k1, k2, k3, k4 = k[0], k[1], k[2], k[3]
    for i in range(size):
        for j in range(WIDTH):
            k4[i, j] = k1[i, j]   # the lanes' own first stages, kept aside
    for j in range(WIDTH):
        least[j] = math.inf
    _block_derivative(model, ws, wraw, g, free, nq, nu, x, k1, qcmd, damp, qb, has_damping,
                      watch, rest, least)
    for j in range(WIDTH):
        if have_k1[j]:
            least[j] = math.inf
            for i in range(size):
                k1[i, j] = k4[i, j]
    if method == EULER:
        for i in range(size):
            for j in range(WIDTH):
                out[i, j] = x[i, j] + h[j] * k1[i, j]
    elif method == SEMI_IMPLICIT_EULER:
        for i in range(nq, size):
            for j in range(WIDTH):
                out[i, j] = x[i, j] + h[j] * k1[i, j]
        configuration_rate(model, wrap(x[:nq]), wrap(out[nq:nq + nu]), wrap(k2[:nq]))
        for i in range(nq):
            for j in range(WIDTH):
                out[i, j] = x[i, j] + h[j] * k2[i, j]
    else:
        for i in range(size):
            for j in range(WIDTH):
                out[i, j] = x[i, j] + 0.5 * h[j] * k1[i, j]
        _block_derivative(model, ws, wraw, g, free, nq, nu, out, k2, qcmd, damp, qb,
                          has_damping, watch, rest, least)
        for i in range(size):
            for j in range(WIDTH):
                out[i, j] = x[i, j] + 0.5 * h[j] * k2[i, j]
        _block_derivative(model, ws, wraw, g, free, nq, nu, out, k3, qcmd, damp, qb,
                          has_damping, watch, rest, least)
        for i in range(size):
            for j in range(WIDTH):
                out[i, j] = x[i, j] + h[j] * k3[i, j]
        _block_derivative(model, ws, wraw, g, free, nq, nu, out, k4, qcmd, damp, qb,
                          has_damping, watch, rest, least)
        for i in range(size):
            for j in range(WIDTH):
                out[i, j] = x[i, j] + h[j] / 6.0 * (k1[i, j] + 2.0 * k2[i, j] + 2.0 * k3[i, j]
                                                    + k4[i, j])
    if end:
        _block_derivative(model, ws, wraw, g, free, nq, nu, out, k[4], qcmd, damp, qb,
                          has_damping, watch, rest, least)


# ------------------------------------------------------------------- one lane's control flow

@_compiled_inline
def until_step(method, system, stops, scr, s, clock, times, last, rows, rows_t, write, budget,
               log, log_q, log_u, log_free, count, phase, aim, at):
    """Lane control flow of `lanes.fixed_lane` and `stepping.advance`, resumed where it stopped
    (phase, aim; at[0] the next sample), run up to the lane's next whole grid step: returns
    (NEED_STEP, DONE) there, or the lane's outcome of this call (`fixed_lane`'s code and
    status). Everything but the grid step itself — the last shorter step to a sample off the
    grid, budgets, the log's room, the samples, the impacts moved to the lane's log — is done
    here, as they do it."""
    size = s.shape[0]
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
        i = at[0]
        if status == DONE:
            if write:
                for j in range(size):
                    rows[i, j] = s[j]
                rows[i, size] = total_energy(system, s)
                rows_t[i] = clock[CLOCK_T0] + clock[CLOCK_K] * clock[CLOCK_DT]
            at[0] = i + 1
        elif status != BUDGET and status != LOG_FULL:
            return LANE_FAILED, status
        if stops.count[0] > 0 and not keep_impacts(stops, log, log_q, log_u, log_free, count):
            return LANE_PAUSED, status


@_compiled_inline
def stepped(clock, phase, status, k1_ready):
    """After the lane's grid step: as `advance` books it, or the status that ends the call."""
    if status != DONE:
        phase[ENDING] = status
    else:
        clock[CLOCK_K] += 1.0
        clock[CLOCK_STEPS] += 1.0
        phase[TAKEN] += 1
        phase[K1_READY] = 1 if k1_ready else 0


@_compiled_inline
def plain(system):
    """The lane's next grid step can be computed by the vector right-hand side: no wheel-speed
    loop, no arm controller (resting rods and their holding watch are in it)."""
    return system.control[WHEEL_VELOCITY_MODE] == 0.0 and system.arm[ARM_ON] == 0.0


@_compiled_inline
def same_right_hand_side(a, b, method_a, method_b, size_a, size_b):
    """Two lanes' steps may share one vector call: one method and state size, the same locks,
    damping on in both or neither."""
    if (method_a != method_b or size_a != size_b
            or a.damping.shape[0] != b.damping.shape[0]):
        return False
    for k in range(a.free.shape[0]):
        if a.free[k] != b.free[k]:
            return False
    return True


@_compiled_inline
def take_vector_step(system, stops, scr, s, clock, out, k, wraw, qb, least, j, stages, have_k1):
    """Lane j's step out[:, j], taken when the scalar grid step would do nothing else with it
    (finite, no crossing, every resting rod still held): s becomes it, the counters, the holding
    watch, f(out) (k[4], while a rod rests) and the holding forces as the scalar step leaves
    them. False, with nothing changed, otherwise: the scalar step then takes it from s. Returns
    (taken, f(out) ready in stages[0])."""
    size = s.shape[0]
    for i in range(size):
        scr.out[i] = out[i, j]
    if not finite(scr.out):
        return False, False
    checked = any_watched(stops)
    if checked and crossing_in_step(s, scr.out, clock[CLOCK_DT], system, stops.watched,
                                    stops.stroke):
        system.counters[CROSSING_CHECKS] -= 1   # the scalar step checks it again
        return False, False
    resting = any_resting(stops)
    evaluations = stages - (1 if have_k1 else 0)
    if resting:
        # `holding_margin` at out: f(out) and the resting rods' forces (`slide_holding_forces`)
        margin = math.inf
        for r in range(1, stops.resting.shape[0] + 1):
            if stops.resting[r - 1] != 0:
                i = layout.u_slide(r)
                margin = min(margin, -stops.resting[r - 1] * (wraw.slide_force[r, j] - qb[i, j]))
        if margin < 0.0 or least[j] < 0.0:
            if checked:
                system.counters[CROSSING_CHECKS] -= 1
            return False, False
        for r in range(1, stops.resting.shape[0] + 1):
            if stops.resting[r - 1] != 0:
                i = layout.u_slide(r)
                scr.forces[i] = wraw.slide_force[r, j] - qb[i, j]
        for i in range(size):
            scr.stages[0, i] = k[4, i, j]
        evaluations += 1
    system.holding[HOLDING_LEAST_MARGIN] = least[j] if system.holding[HOLDING_ON] != 0.0 \
        else math.inf
    counters = system.counters
    counters[RHS_EVALS] += evaluations
    if system.damping.shape[0] > 0:
        counters[DAMPING_STAGE] += evaluations
    if system.free[system.free.shape[0] - 1] < 0:
        counters[REDUCED_SOLVE] += evaluations
    copy_into(scr.out, s)
    return True, resting


# ------------------------------------------------------------------- a group, and all of them

@_compiled
def _fill_slot(stack, gravity, b, j, system):
    """Lane slot j of block b's model and gravity: the lane's own constants."""
    m = system.model
    base = stack.base
    base[b, 0, j] = m.base.mass
    base[b, 1, j] = m.base.yaw_inertia
    base[b, 2, j] = m.base.com_offset
    base[b, 3, j] = m.base.wheel_radius
    base[b, 4, j] = m.base.half_track
    base[b, 5, j] = m.base.wheel_inertia
    for a in range(3):
        stack.mount[b, a, j] = m.mount[a]
    for r in range(m.L.shape[0]):
        stack.L[b, r, j] = m.L[r]
        stack.mu[b, r, j] = m.mu[r]
        for a in range(3):
            for c in range(3):
                stack.R0[b, r, a, c, j] = m.R0[r, a, c]
                stack.J[b, r, a, c, j] = m.J[r, a, c]
    stack.tip_mass[b, 0, j] = m.tip_mass
    gravity[b, 0, j] = system.gravity


@_compiled
def _new_stack(blocks, n):
    return ModelStack(np.zeros((blocks, 6, WIDTH)), np.zeros((blocks, 3, WIDTH)),
                      np.zeros((blocks, n, 3, 3, WIDTH)), np.zeros((blocks, n, WIDTH)),
                      np.zeros((blocks, n, WIDTH)), np.zeros((blocks, n, 3, 3, WIDTH)),
                      np.zeros((blocks, 1, WIDTH)))


@_compiled
def _new_workspace(n):
    """`records.make_workspace(n)` with four lanes in every field (locks aside)."""
    return Workspace(np.zeros((n + 1, 3, 3, WIDTH)), np.zeros((n + 2, 3, WIDTH)),
                     np.zeros((n + 1, 3, WIDTH)), np.zeros((n + 1, 3, WIDTH)),
                     np.zeros((n + 2, 3, WIDTH)), np.zeros((n + 2, 3, WIDTH)),
                     np.zeros((n + 1, 6, 2, WIDTH)), np.zeros((n + 1, 6, WIDTH)),
                     np.zeros((n + 1, 6, WIDTH)), np.zeros((n + 1, 6, 2, WIDTH)),
                     np.zeros((n + 1, 3, WIDTH)), np.zeros((n + 1, 2, WIDTH)),
                     np.zeros((6, 6, WIDTH)), np.zeros((6, WIDTH)), np.zeros(2 * n + 2),
                     np.zeros((n + 1, 7, WIDTH)), np.zeros((n + 1, WIDTH)))


@_compiled
def form_blocks(ready, eligible, systems, methods, states, records, block_of, members, count):
    """The ready lanes that may share a vector step, four at a time: each eligible lane joins the
    first block (in slot order) whose first lane shares its right-hand side and has room, else
    starts one; members[b, :count[b]] are block b's slots. Returns how many blocks."""
    blocks = 0
    for j in range(ready.shape[0]):
        block_of[j] = -1
        if not (ready[j] and eligible[j]):
            continue
        r = records[j]
        for b in range(blocks):
            first = records[members[b, 0]]
            if count[b] < WIDTH and same_right_hand_side(
                    systems[first], systems[r], methods[first], methods[r],
                    states[first].shape[0], states[r].shape[0]):
                block_of[j] = b
                break
        if block_of[j] < 0:
            block_of[j] = blocks
            count[blocks] = 0
            blocks += 1
        b = block_of[j]
        members[b, count[b]] = j
        count[b] += 1
    return blocks


@_compiled
def run_group(methods, systems, stops, scratches, states, clocks, slots, records, times, last,
              rows, rows_t, write, budget, code, next_sample, failure, logs, paths, vector):
    """The lanes slots[j] (−1: none; their records records[j]) of one group from their
    next_sample towards sample `last`, each as `lanes.fixed_lane` runs it alone, in rounds:
    each lane is brought to its next whole grid step (`until_step`), then those ready together
    with one right-hand side (`form_blocks`) take it in vector lanes, at least MIN_VECTOR at a
    time (`vector_step`, `take_vector_step`), the rest with the scalar grid step. paths[lane]
    counts both."""
    width = slots.shape[0]
    first = records[0]
    n = systems[first].model.L.shape[0]
    nq, nu = layout.sizes(systems[first])
    size = states[first].shape[0]
    stack, gravity, wraw = _new_stack(width, n), np.zeros((width, 1, WIDTH)), _new_workspace(n)
    owner = np.full((width, WIDTH), -1, dtype=np.int64)   # whose constants each block slot holds
    x, out, k = np.zeros((size, WIDTH)), np.zeros((size, WIDTH)), np.zeros((5, size, WIDTH))
    qcmd, damp, qb = np.zeros((nu, WIDTH)), np.zeros((nu, WIDTH)), np.zeros((nu, WIDTH))
    h, least = np.zeros(WIDTH), np.zeros(WIDTH)
    watch = np.zeros(WIDTH, dtype=np.bool_)
    have_k1 = np.zeros(WIDTH, dtype=np.bool_)
    rest = np.zeros((max(n, 1), WIDTH), dtype=np.int64)
    phase = np.zeros((width, 4), dtype=np.int64)
    aim = np.zeros((width, 2))
    active = np.zeros(width, dtype=np.bool_)
    ready = np.zeros(width, dtype=np.bool_)
    eligible = np.zeros(width, dtype=np.bool_)
    block_of = np.zeros(width, dtype=np.int64)
    members = np.zeros((width, WIDTH), dtype=np.int64)
    count = np.zeros(width, dtype=np.int64)
    for j in range(width):
        phase[j, ENDING] = -1
        active[j] = slots[j] >= 0
    while True:
        waiting = 0
        for j in range(width):
            ready[j] = False
            if not active[j]:
                continue
            lane, r = slots[j], records[j]
            c, status = until_step(methods[r], systems[r], stops[r], scratches[r], states[r],
                                   clocks[r], times, last, rows[lane], rows_t[lane], write,
                                   budget, logs.log[lane], logs.log_q[lane], logs.log_u[lane],
                                   logs.log_free[lane], logs.count[lane:lane + 1], phase[j],
                                   aim[j], next_sample[lane:lane + 1])
            if c == NEED_STEP:
                ready[j] = True
                eligible[j] = vector and plain(systems[r])
                waiting += 1
            else:
                active[j] = False
                code[lane] = c
                failure[lane] = status
        if waiting == 0:
            return
        blocks = form_blocks(ready, eligible, systems, methods, states, records, block_of,
                             members, count)
        for b in range(blocks):
            if count[b] < MIN_VECTOR:
                continue
            lead = records[members[b, 0]]
            for j in range(WIDTH):
                slot = members[b, j] if j < count[b] else members[b, 0]
                r = records[slot]
                if owner[b, j] != r:
                    _fill_slot(stack, gravity, b, j, systems[r])
                    owner[b, j] = r
                s, own, lane_stops = states[r], systems[r], stops[r]
                h[j] = clocks[r][CLOCK_DT]
                for i in range(size):
                    x[i, j] = s[i]
                for i in range(nu):
                    qcmd[i, j] = own.Q_cmd[i]
                    damp[i, j] = own.damping[i] if own.damping.shape[0] > 0 else 0.0
                watch[j] = own.holding[HOLDING_ON] != 0.0
                have_k1[j] = phase[slot, K1_READY] != 0
                if have_k1[j]:
                    for i in range(size):
                        k[0, i, j] = scratches[r].stages[0, i]
                for i in range(n):
                    rest[i, j] = lane_stops.resting[i]
            end = False
            for j in range(count[b]):
                end = end or any_resting(stops[records[members[b, j]]])
            system, method = systems[lead], methods[lead]
            vector_step(method, stack, b, gravity, system.free, wraw, nq, nu, x, out, k, qcmd,
                        damp, qb, h, system.damping.shape[0] > 0, watch, have_k1, rest, least,
                        end)
            stages = 1 if method == EULER or method == SEMI_IMPLICIT_EULER else 4
            for j in range(count[b]):
                slot = members[b, j]
                r = records[slot]
                taken, k1_ready = take_vector_step(systems[r], stops[r], scratches[r], states[r],
                                                   clocks[r], out, k, wraw, qb, least, j, stages,
                                                   have_k1[j])
                if taken:
                    stepped(clocks[r], phase[slot], DONE, k1_ready)
                    paths[slots[slot], VECTOR_STEPS] += 1
                    ready[slot] = False
        for j in range(width):
            if ready[j]:
                r = records[j]
                status, k1_ready = grid_step(methods[r], systems[r], stops[r], scratches[r],
                                             states[r], clocks[r], phase[j, K1_READY] != 0)
                stepped(clocks[r], phase[j], status, k1_ready)
                paths[slots[j], SCALAR_STEPS] += 1


@_compiled_lanes
def advance_blocks(methods, systems, stops, scratches, states, clocks, slots, records, times,
                   last, rows, rows_t, write, budget, code, next_sample, failure, logs, paths,
                   vector):
    """Every group of lanes (slots[g], their records records[g]: `group_slots`) from each lane's
    next_sample towards sample `last`, the groups in parallel (`run_group`); each lane's outcome
    in code, next_sample and failure, as `lanes.advance_fixed` gives it."""
    for g in prange(slots.shape[0]):
        run_group(methods, systems, stops, scratches, states, clocks, slots[g], records[g],
                  times, last, rows, rows_t, write, budget, code, next_sample, failure, logs,
                  paths, vector)


GROUP = 16   # lanes per group: one thread's lanes, among which the vector blocks are formed


def block_keys(sims) -> np.ndarray:
    """A number per lane: lanes of one number may share a group (one method, one state size,
    damping on in all or none, no arm controller)."""
    keys = [(sim._core_args[0], sim.s.size, sim.system.data.damping.size, sim.system.arm_on)
            for sim in sims]
    _, numbers = np.unique(np.array(keys, dtype=np.int64).reshape(len(keys), 4), axis=0,
                           return_inverse=True)
    return numbers.reshape(-1).astype(np.int64)


def group_slots(lanes: np.ndarray, records: np.ndarray, keys: np.ndarray, group: int = GROUP):
    """(slots, records) of the groups of these lanes, (groups, group) each, −1 past a group's
    lanes: lanes of one key (`block_keys`, indexed by record) in order, `group` at a time."""
    slots, rows = [], []
    lanes, records = np.asarray(lanes, dtype=np.int64), np.asarray(records, dtype=np.int64)
    lane_keys = keys[records]
    for key in np.unique(lane_keys):
        chosen = np.flatnonzero(lane_keys == key)
        for start in range(0, chosen.size, group):
            part = chosen[start:start + group]
            slot = np.full(group, -1, dtype=np.int64)
            record = np.full(group, -1, dtype=np.int64)
            slot[:part.size], record[:part.size] = lanes[part], records[part]
            slots.append(slot)
            rows.append(record)
    return (np.array(slots, dtype=np.int64).reshape(-1, group),
            np.array(rows, dtype=np.int64).reshape(-1, group))
