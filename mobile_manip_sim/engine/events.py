"""Events inside a step, compiled: a rod reaching an end stop, a resting rod pulled off its stop
(the semantics in docs/model.md, "Resting, leaving, and no Zeno").

Both are roots in h' ∈ (0, h] of an event function of the state h' into the step (`step_state`):
for the fixed-step methods the integrator's *own* step ``step(s0, h')`` — so the state at the
located instant is what the integrator itself would reach, with no interpolation error — and for
the adaptive ones the step's dense output (a `dense.Interpolant`, passed as ``dense``):

- crossing of rod k at its stop (side −1 lower, +1 upper): ``g(h') = side · (stop − l_k(h'))``;
  positive inside the stroke;
- release: ``g(h') = min over resting rods of the force its stop pushes with`` (positive while
  every stop still pushes; the rod leaves where it would have to pull).

A crossing is flagged after a step when a rod's end value *or* the extremum of its cubic
Hermite path over the step (values and slopes at both ends) leaves the stroke, so a fast rod that
crosses and comes back within one step is not missed (SciPy's sign-change detection misses it,
scipy #9228); the first crossing is bracketed between 16 samples of the step plus the path's
turning points, then located by the Illinois method.

A release is watched as a crossing is: while a rod rests, every evaluation of the right-hand
side inside a step (each stage, and the step's end) samples the holding forces
(`system.watch_holding`); where one of them saw a stop pull, the margin is sampled at N_SAMPLES
instants of the step itself (`first_release`) and the first pull located by the same root
finder. A pull window is therefore seen when it covers one of the method's evaluation instants
deeply enough: any window at least twice the largest gap between them (docs/model.md states it
per method).

`step_state(...)` is the one place that evaluates the state inside a step for the event
functions, so one Illinois root finder (`locate`) serves every method.

Simultaneous impacts (`simultaneous_hits`): rods that reach their stops within SIMULTANEOUS
(s) of each other take part in one impact, solved together by the multi-contact law
(`stops.impact`): at the located instant, a rod moving into its stop closer to it than its speed
times SIMULTANEOUS (or already past it) is moved onto it and hit with the rest, so the result
does not depend on which crossing round-off places first.

The Zeno guard (`zeno_guard`, `ZENO_*`), the one for every method, fixed-step and adaptive,
reads the impacts alone, never the step. Each rod and stop keeps its own record
(`stops.StopsData.run`), so impacts of other rods in between neither break it nor count towards
it. An impact at a stop is *evidence* of an accumulation point when either
- the last ZENO_RUN intervals between impacts there each shrank and so did the arrival speeds,
  and the tail the last ratio r predicts, interval · r / (1 − r), fits in ZENO_TAIL; or
- the interval since the last impact there is itself within ZENO_TAIL.
Evidence alone never holds a rod: `stops.impact` then solves the impact both ways (the law, and
the law with the contacts held) and holds only when the hold removes at most ZENO_SHARE of the
run's kinetic energy (the largest T⁻ at an impact at that stop since the start or the last
reset) beyond what the law removes. One or two short intervals in a finite cascade fail that
test (the rod still carries its energy); the tail of a true accumulation passes it by orders of
magnitude. A rod bouncing
faster than ``rest_speed`` is held only there, so its impact count does not depend on the
method or the tolerance. The last resort when rods are released and hit again without end is
the fixed-step core's log-room exit (`stepping.CHATTER`).
"""
import math

from ..dynamics.jit import jit, jit_inline
from . import layout
from .dense import interpolate
from .fixed_step import step
from .system import CROSSING_CHECKS, derivative, holding_margin_now, slide_holding_forces

CROSSING, RELEASE = 0, 1
N_SAMPLES = 16
SIMULTANEOUS = 1e-9   # s: stops reached this close together in time are one impact
ZENO_TAIL = 1e-6      # s: a run of impacts whose remaining tail is shorter is evidence of Zeno
ZENO_RUN = 3          # shrinking intervals (and arrival speeds) in a row that make a geometric run
ZENO_SHARE = 1e-6    # a hold removes at most this share of its run's kinetic energy (J / J)
# stops.run[k − 1, stop, ...]: impacts at that stop, time of the last (s), interval before it (s),
# arrival speed of the last (m/s), how many intervals and speeds in a row shrank, the largest
# kinetic energy at an impact there (J)
RUN_COUNT, RUN_LAST, RUN_INTERVAL, RUN_SPEED, RUN_SHRINKS, RUN_ENERGY = range(6)
RUN_FIELDS = 6


@jit
def zeno_guard(run, k, side, t, speed, T):
    """The Zeno guard's evidence (module doc): rod k (1-based) meets its lower (side −1) or upper
    (+1) stop at time t (s) with arrival speed |l̇| ``speed`` (m/s), the kinetic energy being T
    (J). Records the impact in ``run`` ((n, 2, RUN_FIELDS), per rod and stop) and returns the
    energy (J) a hold may remove there beyond the law — ZENO_SHARE of the largest T at an impact
    there since the start — when the impacts there are evidence of an accumulation point, and −1
    when they are not."""
    record = run[k - 1, 0 if side < 0 else 1]
    evidence = False
    if record[RUN_COUNT] > 0.0:
        interval = t - record[RUN_LAST]
        if (record[RUN_COUNT] > 1.0 and interval < record[RUN_INTERVAL]
                and speed < record[RUN_SPEED]):
            record[RUN_SHRINKS] += 1.0
        else:
            record[RUN_SHRINKS] = 0.0
        evidence = interval <= ZENO_TAIL
        if record[RUN_SHRINKS] >= ZENO_RUN:
            ratio = interval / record[RUN_INTERVAL]
            evidence = evidence or interval * ratio <= ZENO_TAIL * (1.0 - ratio)
        record[RUN_INTERVAL] = interval
    record[RUN_COUNT] += 1.0
    record[RUN_LAST] = t
    record[RUN_SPEED] = speed
    record[RUN_ENERGY] = max(record[RUN_ENERGY], T)
    return ZENO_SHARE * record[RUN_ENERGY] if evidence else -1.0


@jit
def simultaneous_hits(system, stops, s, k, side, hits):
    """The rods hit together with rod k at its stop ``side`` at the located state s: hits[r − 1]
    = the stop (−1, +1) rod r meets, 0 for none — rod k, and every other watched rod moving into
    a stop closer to it than |l̇| · SIMULTANEOUS, or already past one. Each is moved exactly
    onto its stop in s (by at most its speed times SIMULTANEOUS). Returns how many."""
    nq, _ = layout.sizes(system)
    count = 0
    for r in range(1, hits.shape[0] + 1):
        hits[r - 1] = 0
        if r == k:
            hits[r - 1] = side
        elif stops.watched[r - 1]:
            lo, hi = stops.stroke[r - 1, 0], stops.stroke[r - 1, 1]
            l_r, v = s[layout.q_slide(r)], s[layout.ld(nq, r)]
            reach = abs(v) * SIMULTANEOUS
            if l_r < lo or v < 0.0 and l_r - lo <= reach:
                hits[r - 1] = -1
                s[layout.q_slide(r)] = lo
            elif l_r > hi or v > 0.0 and hi - l_r <= reach:
                hits[r - 1] = 1
                s[layout.q_slide(r)] = hi
        if hits[r - 1] != 0:
            count += 1
    return count


@jit_inline
def hermite_turns(l0, d0, l1, d1, h):
    """((τ₁, τ₂), c2, c3): where the cubic Hermite with values l0, l1 and slopes d0, d1 over
    [0, h] has zero slope (−1 for a missing root; roots may lie outside (0, h)), and its
    coefficients p(τ) = l0 + d0 τ + c2 τ² + c3 τ³."""
    c2 = (3.0 * (l1 - l0) / h - 2.0 * d0 - d1) / h
    c3 = (d0 + d1 - 2.0 * (l1 - l0) / h) / (h * h)
    a, b, c = 3.0 * c3, 2.0 * c2, d0
    roots = (-1.0, -1.0)
    if a == 0.0:
        if b != 0.0:
            roots = (-c / b, -1.0)
    else:
        disc = b * b - 4.0 * a * c
        if disc >= 0.0:
            # The cancellation-free form: a path that is nearly a parabola (a rod under a constant
            # force) has a ≈ 0 from round-off, and (−b ± √disc)/2a would lose its turning point.
            w = -0.5 * (b + math.copysign(disc ** 0.5, b))
            roots = (w / a, c / w if w != 0.0 else -1.0)
    return roots, c2, c3


@jit_inline
def hermite_extrema(l0, d0, l1, d1, h):
    """(min, max) over [0, h] of the cubic Hermite with values l0, l1 and slopes d0, d1."""
    lo = min(l0, l1)
    hi = max(l0, l1)
    roots, c2, c3 = hermite_turns(l0, d0, l1, d1, h)
    for tau in roots:
        if 0.0 < tau < h:
            p = l0 + tau * (d0 + tau * (c2 + tau * c3))
            lo = min(lo, p)
            hi = max(hi, p)
    return lo, hi


@jit_inline
def crossing_in_step(s0, s1, h, system, watched, stroke):
    """True when a watched rod leaves its stroke during the step s0 → s1 (see module doc)."""
    nq, _ = layout.sizes(system)
    system.counters[CROSSING_CHECKS] += 1
    for k in range(1, watched.shape[0] + 1):
        if not watched[k - 1]:
            continue
        lo, hi = stroke[k - 1, 0], stroke[k - 1, 1]
        i_l, i_ld = layout.q_slide(k), layout.ld(nq, k)
        if s1[i_l] < lo or s1[i_l] > hi:
            return True
        low, high = hermite_extrema(s0[i_l], s0[i_ld], s1[i_l], s1[i_ld], h)
        if low < lo or high > hi:
            return True
    return False


@jit_inline
def holding_margin(system, s, resting, ds, forces):
    """min over resting rods of the force (N) its stop pushes with: > 0 while all are held."""
    derivative(system, s, ds)
    return holding_margin_after(system, resting, forces)


@jit_inline
def holding_margin_after(system, resting, forces):
    """`holding_margin` right after a derivative at the state (which left the forces)."""
    slide_holding_forces(system, resting, forces)
    return holding_margin_now(system)


@jit
def step_state(method, system, s0, h, out, stages, dense=None):
    """The state h (s) into the step from s0 (s0 itself for h ≤ 0), into out: the integrator's
    own step, or the step's dense output when one is given."""
    if h <= 0.0:
        for i in range(s0.shape[0]):
            out[i] = s0[i]
    elif dense is None:   # a plain `is None` test: numba drops the branch a call cannot take
        step(method, system, s0, h, out, stages)
    else:
        interpolate(dense, s0, h, out)


@jit
def event_value(kind, method, system, s0, h, i_l, side, stop, resting, trial, stages, forces,
                dense=None):
    """g(h') of the module doc for `kind` CROSSING (rod at index i_l, side, stop) or RELEASE."""
    step_state(method, system, s0, h, trial, stages, dense)
    if kind == CROSSING:
        return (stop - trial[i_l]) * side
    return holding_margin(system, trial, resting, stages[3], forces)


@jit
def locate(kind, method, system, s0, a, b, i_l, side, stop, resting, trial, stages, forces,
           dense=None):
    """The root of g in (a, b] with g(a) ≥ 0 > g(b), by the Illinois method: the h' with
    g(h') ≤ 0 closest to the root (the state has just reached the event)."""
    h = b - a
    ga = event_value(kind, method, system, s0, a, i_l, side, stop, resting, trial, stages, forces,
                     dense)
    gb = event_value(kind, method, system, s0, b, i_l, side, stop, resting, trial, stages, forces,
                     dense)
    g_root = gb  # g at b itself: the Illinois steps halve gb, which must not pass for convergence
    last = 0
    for _ in range(200):
        # With g(a) = 0 (a rod starting exactly at its stop, as after every impact) the secant
        # lands on a itself, or a round-off above it where g may read ≤ 0: a false root at
        # h' ≈ 0. Bisect until g(a) > 0.
        if gb != ga and ga != 0.0:
            c = b - gb * (b - a) / (gb - ga)
        else:
            c = 0.5 * (a + b)
        if not a < c < b:
            c = 0.5 * (a + b)
        gc = event_value(kind, method, system, s0, c, i_l, side, stop, resting, trial, stages,
                         forces, dense)
        if gc <= 0.0:
            b, gb, g_root = c, gc, gc
            if last == -1:
                ga *= 0.5
            last = -1
        else:
            a, ga = c, gc
            if last == 1:
                gb *= 0.5
            last = 1
        if -1e-13 <= g_root <= 0.0 or b - a <= 1e-15 * h:
            break
    return b


@jit
def insert_sorted(a, m, x):
    """Insert x into the sorted a[:m] (a has room for it); returns m + 1. (The kernels run
    without numba's reference counting, so numpy's sort, which returns its array, is out.)"""
    j = m
    while j > 0 and a[j - 1] > x:
        a[j] = a[j - 1]
        j -= 1
    a[j] = x
    return m + 1


@jit
def first_crossing(method, system, s0, h, watched, resting, stroke, samples, crossed, trial, stages,
                   forces, dense=None):
    """Earliest (h', rod k, side) at which a watched rod meets a stop within the step s0 → h,
    or (−1, 0, 0) when none does (the Hermite path dipped, the step itself did not).
    ``crossed`` (n,) int64 is scratch: the side each rod is past at the bracket's end."""
    nq, _ = layout.sizes(system)
    n = watched.shape[0]
    m = 0
    for j in range(1, N_SAMPLES + 1):
        samples[m] = h * j / N_SAMPLES
        m += 1
    # A rod that crosses and comes back between two samples would be missed: add the instants
    # where each rod's Hermite path over the step (the one `crossing_in_step` flagged) turns.
    step_state(method, system, s0, h, trial, stages, dense)
    for k in range(1, n + 1):
        if watched[k - 1]:
            i_l, i_ld = layout.q_slide(k), layout.ld(nq, k)
            turns, _, _ = hermite_turns(s0[i_l], s0[i_ld], trial[i_l], trial[i_ld], h)
            for tau in turns:
                if 0.0 < tau < h:
                    m = insert_sorted(samples, m, tau)
    # Bracket the first crossing between samples, the state at each serving every rod and stop
    # (an interpolant's round-off right after an impact must not pass for a new crossing at
    # h' ≈ 0): every stop is inside at samples[end − 1], the ones crossed are past at samples[end].
    end = -1
    for j in range(m):
        step_state(method, system, s0, samples[j], trial, stages, dense)
        for k in range(1, n + 1):
            crossed[k - 1] = 0
            if watched[k - 1]:
                l_k = trial[layout.q_slide(k)]
                if l_k < stroke[k - 1, 0]:
                    crossed[k - 1] = -1
                elif l_k > stroke[k - 1, 1]:
                    crossed[k - 1] = 1
                if crossed[k - 1] != 0:
                    end = j
        if end >= 0:
            break
    if end < 0:
        return -1.0, 0, 0
    a = samples[end - 1] if end > 0 else 0.0
    best_h, best_k, best_side = -1.0, 0, 0
    for k in range(1, n + 1):
        side = crossed[k - 1]
        if side == 0:
            continue
        stop = stroke[k - 1, 0] if side < 0 else stroke[k - 1, 1]
        h_hit = locate(CROSSING, method, system, s0, a, samples[end], layout.q_slide(k), side, stop,
                       resting, trial, stages, forces, dense)
        if best_k == 0 or h_hit < best_h:
            best_h, best_k, best_side = h_hit, k, side
    return best_h, best_k, best_side


@jit
def first_release(method, system, s0, h, resting, trial, stages, forces, dense=None):
    """Earliest h' in (0, h] at which a resting rod's stop would start to pull, or −1 when none
    does: the holding margin sampled at N_SAMPLES instants of the step (the integrator's own step,
    or the step's dense output) and located (`locate`) between the last sample where every stop
    pushes and the first where one pulls. Called only when an evaluation inside the step saw a
    stop pull (`system.watch_holding`), so that resting costs nothing more while the stops push."""
    before = 0.0
    for j in range(1, N_SAMPLES + 1):
        h_j = h * j / N_SAMPLES
        if event_value(RELEASE, method, system, s0, h_j, 0, 0, 0.0, resting, trial, stages, forces,
                       dense) < 0.0:
            return locate(RELEASE, method, system, s0, before, h_j, 0, 0, 0.0, resting, trial,
                          stages, forces, dense)
        before = h_j
    return -1.0
