"""Lanes stepped four at a time: the plain grid steps of lanes that share a right-hand side computed
together in vector lanes.

A group is up to GROUP lanes of one method and one state layout (`block_keys`), run by one thread.
Each lane keeps its own records and follows exactly the calls of a run alone (`lanes.fixed_lane`:
one `stepping.advance` per sample, its step budget, the impact log emptied after every call): the
group runs that control flow for each lane separately (`until_step`, a resumable copy of `advance`
and `fixed_lane` around the grid step, `lane_flow.py`) up to the point where the lane needs its
next whole grid step. The lanes that are there together and may share a right-hand side (`plain`:
no wheel-speed loop, no arm controller; `same_right_hand_side`: one method, the same locks) form
blocks of four (`form_blocks`); a block of at least MIN_VECTOR lanes takes that step together:
every stage's dynamics in `dynamics.lanes.rates` (`Vec4`, four lanes per instruction, each lane
performing the scalar kernels' operations in their order), the efforts, damping, work rate, holding
watch and stage sums lane by lane in scalar code as `system.derivative`, `system.watch_holding` and
`fixed_step.step` do them (`vector_steps.py`). Then each lane's end state is checked by the very
tests the scalar grid step runs after a step (non-finite, the crossing check, the resting rods'
holding margins); a lane whose step has nothing else to do takes it (its counters, holding watch,
f(end) and holding forces left as the scalar step leaves them), any other lane throws the vector
result away and takes the step with the scalar `stepping.grid_step_calling` from its untouched
state — events, impacts, releases and failures then run exactly as in its run alone. So every
lane is bit for bit its own run; the blocks only decide who computes a plain step.

A block goes on with its next steps in the same call (`block_steps`) while every lane takes them
and none reaches the end of its `advance` call or its step budget (`steps_together`): between two
grid steps a lane's own flow only counts, so the round trip through the flows, the forming of
blocks and the call's some three hundred words of arguments are paid once per sample, not once
per step.



The kernels here are cached on disk; the stale-cache sweep of `dynamics/jit.py` reads this
module for its '@jit', as it reads `vector_steps.py` and `lane_flow.py`, whose code is compiled
into them.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np

from ..engine import layout
from ..engine.fixed_step import EULER, SEMI_IMPLICIT_EULER
from ..engine.stepping import CLOCK_DT, CLOCK_K, DONE, grid_step_calling
from ..engine.stops import any_resting
from ..engine.system import HOLDING_ON
from .lane_flow import ENDING, IN_CALL, K1_READY, NEED_STEP, TAKEN, WHOLE, stepped, until_step
from .vector_steps import (
    WIDTH,
    borrowed,
    compiled,
    compiled_borrowing,
    compiled_inline,
    compiled_parallel,
    fill_slot,
    new_stack,
    new_workspace,
    plain,
    prange,
    same_right_hand_side,
    take_vector_step,
    vector_step,
)

MIN_VECTOR = 2       # lanes ready together for the vector step to pay (one lane: scalar)
# paths[lane, ...]: grid steps taken by the vector right-hand side, by the scalar one
VECTOR_STEPS, SCALAR_STEPS = range(2)



# ------------------------------------------------------------------- a group, and all of them

@compiled_inline
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
            lead = records[members[b, 0]]
            if count[b] < WIDTH and same_right_hand_side(
                    borrowed(systems, lead), borrowed(systems, r), methods[lead], methods[r],
                    borrowed(states, lead).shape[0], borrowed(states, r).shape[0]):
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


@compiled_inline
def steps_together(clocks, records, phase, aim, members, b, count, budget):
    """Whole grid steps every lane of block b takes before its flow needs anything but its next
    grid step (`until_step`): up to its call's last whole step and within its step budget (a
    plain step leaves its impact log's room as it is)."""
    steps = budget
    for j in range(count):
        slot = members[b, j]
        clock = borrowed(clocks, records[slot])
        steps = min(steps, int(aim[slot, WHOLE] - clock[CLOCK_K]), budget - phase[slot, TAKEN])
    return max(steps, 1)


@compiled_borrowing
def block_steps(method, stack, b, gravity, free, wraw, nq, nu, x, out, k, qcmd, damp, qb, h,
                has_damping, watch, have_k1, rest, least, end, steps, systems, stops, scratches,
                states, clocks, slots, records, members, count, phase, paths, ready):
    """Up to `steps` grid steps of block b's lanes (x, have_k1 and k[0] filled from their
    records) in vector lanes: after each, every lane takes its step as it would after its own
    `vector_step` (`take_vector_step`, booked by `stepped`); the block stops at the first step
    some lane does not take (that lane then steps alone from its untouched state). Between two
    steps a lane's own flow does nothing but count the step (`until_step`), and a taken step
    changes neither the lane's locks, rests, holding watch nor efforts: the next step starts
    from the states taken, with f(end) as first stage where a rod rests, as a new round would."""
    size = x.shape[0]
    stages = 1 if method == EULER or method == SEMI_IMPLICIT_EULER else 4
    for m in range(steps):
        vector_step(method, stack, b, gravity, free, wraw, nq, nu, x, out, k, qcmd, damp, qb, h,
                    has_damping, watch, have_k1, rest, least, end)
        every = True
        for j in range(count):
            slot = members[b, j]
            r = records[slot]
            taken, k1_ready = take_vector_step(borrowed(systems, r), borrowed(stops, r),
                                               borrowed(scratches, r), borrowed(states, r),
                                               borrowed(clocks, r), out, k, wraw, qb, least, j,
                                               stages, have_k1[j])
            if taken:
                stepped(borrowed(clocks, r), phase[slot], DONE, k1_ready)
                paths[slots[slot], VECTOR_STEPS] += 1
                ready[slot] = False
                have_k1[j] = k1_ready
            else:
                every = False
        if not every or m == steps - 1:
            return
        for j in range(count, WIDTH):   # the block's spare slots repeat its first lane
            have_k1[j] = have_k1[0]
        for i in range(size):
            for j in range(WIDTH):
                x[i, j] = out[i, j]
                if have_k1[j]:
                    k[0, i, j] = k[4, i, j]
        for j in range(count):
            ready[members[b, j]] = True   # (its flow wants its next step: counted above)


GroupScratch = namedtuple("GroupScratch", [
    "stack", "gravity", "wraw", "owner", "x", "out", "k", "qcmd", "damp", "qb", "h", "least",
    "watch", "have_k1", "rest", "phase", "aim", "active", "ready", "eligible", "block_of",
    "members", "count"])


@compiled
def _new_scratch(width, n, nu, size):
    """A group's scratch (`run_group`): the blocks' models and workspace, the step's columns,
    the lanes' phases."""
    return GroupScratch(
        new_stack(width, n), np.zeros((width, 1, WIDTH)), new_workspace(n),
        np.full((width, WIDTH), -1, dtype=np.int64), np.zeros((size, WIDTH)),
        np.zeros((size, WIDTH)), np.zeros((5, size, WIDTH)), np.zeros((nu, WIDTH)),
        np.zeros((nu, WIDTH)), np.zeros((nu, WIDTH)), np.zeros(WIDTH), np.zeros(WIDTH),
        np.zeros(WIDTH, dtype=np.bool_), np.zeros(WIDTH, dtype=np.bool_),
        np.zeros((max(n, 1), WIDTH), dtype=np.int64), np.zeros((width, 4), dtype=np.int64),
        np.zeros((width, 2)), np.zeros(width, dtype=np.bool_), np.zeros(width, dtype=np.bool_),
        np.zeros(width, dtype=np.bool_), np.zeros(width, dtype=np.int64),
        np.zeros((width, WIDTH), dtype=np.int64), np.zeros(width, dtype=np.int64))


@compiled_borrowing
def run_group(methods, systems, stops, scratches, states, clocks, slots, records, times, last,
              rows, rows_t, write, budget, code, next_sample, failure, logs, paths, vector, gs):
    """The lanes slots[j] (−1: none) of one group from their next_sample towards sample `last`,
    each as `lanes.fixed_lane` runs it alone, in rounds: each lane is brought to its next whole
    grid step (`until_step`), then those ready together with one right-hand side
    (`form_blocks`) take it in vector lanes, at least MIN_VECTOR at a time (`vector_step`,
    `take_vector_step`), the rest with the scalar grid step. paths[lane] counts both.

    Compiled without reference counting: the lanes' records are read from the typed lists
    `borrowed`, at no cost."""
    width = slots.shape[0]
    nq, nu = layout.sizes(borrowed(systems, records[0]))
    n = borrowed(systems, records[0]).model.L.shape[0]
    size = borrowed(states, records[0]).shape[0]
    stack, gravity, wraw, owner = gs.stack, gs.gravity, gs.wraw, gs.owner
    x, out, k, qcmd, damp, qb = gs.x, gs.out, gs.k, gs.qcmd, gs.damp, gs.qb
    h, least, watch, have_k1, rest = gs.h, gs.least, gs.watch, gs.have_k1, gs.rest
    phase, aim, active, ready, eligible = gs.phase, gs.aim, gs.active, gs.ready, gs.eligible
    block_of, members, count = gs.block_of, gs.members, gs.count
    for j in range(width):
        phase[j, IN_CALL] = 0
        phase[j, ENDING] = -1
        active[j] = slots[j] >= 0
    while True:
        waiting = 0
        for j in range(width):
            ready[j] = False
            if not active[j]:
                continue
            lane, r = slots[j], records[j]
            c, status = until_step(methods[r], borrowed(systems, r), borrowed(stops, r),
                                   borrowed(scratches, r), borrowed(states, r),
                                   borrowed(clocks, r), times, last, rows[lane], rows_t[lane],
                                   write, budget, logs.log[lane], logs.log_q[lane],
                                   logs.log_u[lane], logs.log_free[lane],
                                   logs.count[lane:lane + 1], phase[j], aim[j],
                                   next_sample[lane:lane + 1])
            if c == NEED_STEP:
                ready[j] = True
                eligible[j] = vector and plain(borrowed(systems, r))
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
            lead = members[b, 0]
            for j in range(WIDTH):
                slot = members[b, j] if j < count[b] else lead
                r = records[slot]
                if owner[b, j] != r:
                    fill_slot(stack, gravity, b, j, borrowed(systems, r))
                    owner[b, j] = r
                s, own, lane_stops = borrowed(states, r), borrowed(systems, r), borrowed(stops, r)
                h[j] = borrowed(clocks, r)[CLOCK_DT]
                for i in range(size):
                    x[i, j] = s[i]
                for i in range(nu):
                    qcmd[i, j] = own.Q_cmd[i]
                    damp[i, j] = own.damping[i] if own.damping.shape[0] > 0 else 0.0
                watch[j] = own.holding[HOLDING_ON] != 0.0
                have_k1[j] = phase[slot, K1_READY] != 0
                if have_k1[j]:
                    for i in range(size):
                        k[0, i, j] = borrowed(scratches, r).stages[0, i]
                for i in range(n):
                    rest[i, j] = lane_stops.resting[i]
            end = False
            for j in range(count[b]):
                end = end or any_resting(borrowed(stops, records[members[b, j]]))
            system, method = borrowed(systems, records[lead]), methods[records[lead]]
            steps = steps_together(clocks, records, phase, aim, members, b, count[b], budget)
            block_steps(method, stack, b, gravity, system.free, wraw, nq, nu, x, out, k, qcmd,
                        damp, qb, h, system.damping.shape[0] > 0, watch, have_k1, rest, least,
                        end, steps, systems, stops, scratches, states, clocks, slots, records,
                        members, count[b], phase, paths, ready)
        for j in range(width):
            if ready[j]:
                r = records[j]
                status, k1_ready = grid_step_calling(
                    methods[r], borrowed(systems, r), borrowed(stops, r), borrowed(scratches, r),
                    borrowed(states, r), borrowed(clocks, r), phase[j, K1_READY] != 0)
                stepped(borrowed(clocks, r), phase[j], status, k1_ready)
                paths[slots[j], SCALAR_STEPS] += 1


@compiled_parallel
def advance_blocks(methods, systems, stops, scratches, states, clocks, slots, records, times,
                   last, rows, rows_t, write, budget, code, next_sample, failure, logs, paths,
                   vector):
    """Every group of lanes (slots[g], their records records[g]: `group_slots`) from each lane's
    next_sample towards sample `last`, the groups in parallel (`run_group`); each lane's outcome
    in code, next_sample and failure, as `lanes.advance_fixed` gives it."""
    for g in prange(slots.shape[0]):
        r = records[g]
        first = systems[r[0]]
        gs = _new_scratch(slots.shape[1], first.model.L.shape[0], first.Q_cmd.shape[0],
                          states[r[0]].shape[0])
        run_group(methods, systems, stops, scratches, states, clocks, slots[g], r, times, last,
                  rows, rows_t, write, budget, code, next_sample, failure, logs, paths, vector,
                  gs)


GROUP = 32   # lanes per group: one thread's lanes, among which the vector blocks are formed


def block_keys(sims) -> np.ndarray:
    """A number per lane: lanes of one number may share a group (one method, one state size,
    damping on in all or none, no arm controller)."""
    keys = [(sim._core_args[0], sim.s.size, sim.system.data.damping.size, sim.system.arm_on)
            for sim in sims]
    _, numbers = np.unique(np.array(keys, dtype=np.int64).reshape(len(keys), 4), axis=0,
                           return_inverse=True)
    return numbers.reshape(-1).astype(np.int64)


def group_slots(lanes: np.ndarray, records: np.ndarray, keys: np.ndarray, group: int = 0):
    """(slots, records) of the groups of these lanes, (groups, group) each (group 0: GROUP),
    slots −1 past a group's lanes (their records: the first lane's): lanes of one key
    (`block_keys`, indexed by record) in order, `group` at a time."""
    group = group or GROUP
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
            record[part.size:] = records[part[0]]   # (never stepped: its slot is −1)
            slots.append(slot)
            rows.append(record)
    return (np.array(slots, dtype=np.int64).reshape(-1, group),
            np.array(rows, dtype=np.int64).reshape(-1, group))
