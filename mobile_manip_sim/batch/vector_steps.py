"""The vector step of a block of four lanes (`blocks.py`): the lanes' plain grid step with the
dynamics of every stage in vector lanes (`dynamics.lanes.rates`, `Vec4`), everything else of
`system.derivative` and `fixed_step.step` lane by lane in their order, and the check that decides
whether a lane takes it (`take_vector_step`) or steps alone.

Also the compile options of the batch's block kernels (`compiled`, …): numba's, cached on disk,
no fast-math (no contraction into fused multiply-adds), as `dynamics/jit.py`'s.
Compiled into `blocks.py`'s kernels, these modules are read by the stale-cache sweep of
`dynamics/jit.py` (which looks for '@jit' in a source) like every module numba compiles into
others.
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
from ..engine.stepping import CLOCK_DT, any_watched, copy_into, finite
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

WIDTH = 4   # lanes per block: four float64 in a 256-bit register

if ENABLED:
    import numba
    from llvmlite import ir
    from numba import types
    from numba.core import cgutils
    from numba.extending import intrinsic
    from numba.typed.listobject import ll_list_type, ll_voidptr_type

    def compiled(function):
        return numba.njit(cache=True, nogil=True, error_model="numpy",
                          fastmath=False)(function)

    def compiled_inline(function):
        return numba.njit(cache=True, nogil=True, error_model="numpy", fastmath=False,
                          inline="always", _nrt=False)(function)

    def compiled_parallel(function):
        return numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy",
                          fastmath=False)(function)

    def compiled_borrowing(function):
        """Compiled without reference counting and without a Python entry: called from compiled
        code only, it may read typed lists' items with `borrowed`."""
        return numba.njit(cache=True, nogil=True, error_model="numpy", fastmath=False,
                          _nrt=False, no_cpython_wrapper=True)(function)

    @intrinsic
    def borrowed(typingctx, items, index):
        """items[index] of a typed list, borrowed: nothing counted up or down. Reading a record
        of some fifty arrays from a typed list in reference-counted code counts each of them up
        and down, atomically: more than a lane's whole step costs. Only in `compiled_borrowing`
        code, while the list lives (the caller holds it)."""
        if not isinstance(items, types.ListType):
            return None

        def codegen(context, builder, sig, args):
            listed, index = args
            proxy = cgutils.create_struct_proxy(sig.args[0])(context, builder, value=listed)
            meminfo = builder.bitcast(proxy.meminfo, cgutils.voidptr_t.as_pointer())
            data = builder.load(cgutils.gep(builder, meminfo, 3))   # NRT_MemInfo's data
            handle = builder.load(builder.bitcast(data, ll_list_type.as_pointer()))
            base = builder.call(cgutils.get_or_insert_function(
                builder.module, ir.FunctionType(ll_voidptr_type, [ll_list_type]),
                "numba_list_base_ptr"), [handle])
            item = context.get_data_type(sig.args[0].item_type)
            pointer = cgutils.gep(builder, builder.bitcast(base, item.as_pointer()), index)
            return context.data_model_manager[sig.args[0].item_type].load_from_data_pointer(
                builder, pointer)
        return items.item_type(items, index), codegen

    def compiled_bare(function):
        return numba.njit(cache=True, nogil=True, error_model="numpy", fastmath=False,
                          _nrt=False)(function)

    prange = numba.prange
else:
    def compiled(function):
        return function

    compiled_inline = compiled_parallel = compiled_bare = compiled_borrowing = compiled

    def borrowed(items, index):
        return items[index]
    prange = range


@compiled_inline
def _block_workspace(w):
    return Workspace(wrap(w.R), wrap(w.O), wrap(w.x), wrap(w.z), wrap(w.F), wrap(w.N),
                     wrap(w.S), wrap(w.V), wrap(w.C), wrap(w.U), wrap(w.D_inv), wrap(w.u_art),
                     wrap(w.I_art), wrap(w.p_art), w.moving, wrap(w.slide),
                     wrap(w.slide_force))


@compiled_inline
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


@compiled_inline
def _margin(wraw, qb, rest, j):
    """`system.holding_margin_now` of lane j right after a `_block_derivative`."""
    margin = math.inf
    for k in range(1, rest.shape[0] + 1):
        if rest[k - 1, j] != 0:
            i = layout.u_slide(k)
            margin = min(margin, -rest[k - 1, j] * (wraw.slide_force[k, j] - qb[i, j]))
    return margin


@compiled_inline
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
    every = True
    for j in range(WIDTH):
        least[j] = math.inf
        every = every and have_k1[j]
    if not every:   # (while rods rest, every lane usually carries its first stage over)
        for i in range(size):
            for j in range(WIDTH):
                k4[i, j] = k1[i, j]   # the lanes' own first stages, kept aside
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


@compiled_inline
def plain(system):
    """The lane's next grid step can be computed by the vector right-hand side: no wheel-speed
    loop, no arm controller (resting rods and their holding watch are in it)."""
    return system.control[WHEEL_VELOCITY_MODE] == 0.0 and system.arm[ARM_ON] == 0.0


@compiled_inline
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


@compiled_inline
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


@compiled_bare
def fill_slot(stack, gravity, b, j, system):
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


@compiled
def new_stack(blocks, n):
    return ModelStack(np.zeros((blocks, 6, WIDTH)), np.zeros((blocks, 3, WIDTH)),
                      np.zeros((blocks, n, 3, 3, WIDTH)), np.zeros((blocks, n, WIDTH)),
                      np.zeros((blocks, n, WIDTH)), np.zeros((blocks, n, 3, 3, WIDTH)),
                      np.zeros((blocks, 1, WIDTH)))


@compiled
def new_workspace(n):
    """`records.make_workspace(n)` with four lanes in every field (locks aside)."""
    return Workspace(np.zeros((n + 1, 3, 3, WIDTH)), np.zeros((n + 2, 3, WIDTH)),
                     np.zeros((n + 1, 3, WIDTH)), np.zeros((n + 1, 3, WIDTH)),
                     np.zeros((n + 2, 3, WIDTH)), np.zeros((n + 2, 3, WIDTH)),
                     np.zeros((n + 1, 6, 2, WIDTH)), np.zeros((n + 1, 6, WIDTH)),
                     np.zeros((n + 1, 6, WIDTH)), np.zeros((n + 1, 6, 2, WIDTH)),
                     np.zeros((n + 1, 3, WIDTH)), np.zeros((n + 1, 2, WIDTH)),
                     np.zeros((6, 6, WIDTH)), np.zeros((6, WIDTH)), np.zeros(2 * n + 2),
                     np.zeros((n + 1, 7, WIDTH)), np.zeros((n + 1, WIDTH)))


