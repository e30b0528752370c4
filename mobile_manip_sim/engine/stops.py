"""Stroke end stops, compiled: the impact law, resting at a stop and leaving it (the semantics
in docs/model.md, "Resting, leaving, and no Zeno").

- Impact (`impact`): docs/model.md's unilateral impact law — one solve for every stop in contact at
  that instant: the rods reaching their stops within `events.SIMULTANEOUS` of each other (each
  with its restitution, 0 for one arriving slower than rebounds are kept) and those resting
  (e = 0), each stop only pushing (`contact_impulses`, `solve_contacts`) — or the paper's
  `reflect` law; one row per rod hit goes to the stop log (`StopsData.log`), from which
  `Simulation` builds its `Impact` list (`impact_log.py`). The contact problem itself, at the
  level of impulses or of accelerations, is contacts.py's.
- Resting: a rod whose rebound would be slower than ``rest_speed`` stops dead at its stop (e = 0)
  and is held there (its l̇ degree of freedom is locked, not stiffly pushed back). At an
  accumulation point of impacts (the Zeno guard, `events.zeno_guard`, on the impact times alone)
  every contact of the impact is held.
- Leaving (`release`): a resting rod leaves when its stop would have to pull to hold it — at an
  impact, at a command change, or at the instant located inside a step where its holding force
  changes sign (`events.py`); which rods leave together is decided by the same contact law at
  the level of accelerations, so freeing one never leaves another one pulled.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np

from ..dynamics import kernels
from ..dynamics.jit import jit, jit_inline
from . import layout
from .contacts import contact_matrix, solve_contacts
from .events import RUN_ENERGY, RUN_FIELDS, ZENO_SHARE, simultaneous_hits, zeno_guard
from .impact_log import (
    LOG_COLUMNS,
    LOG_HELD,
    LOG_HOLD_BOUND,
    LOG_HOLD_LOST,
    LOG_LD_AFTER,
    LOG_LD_BEFORE,
    LOG_LINK,
    LOG_LOST,
    LOG_RESTING,
    LOG_SIDE,
    LOG_TIME,
)
from .system import HOLDING_ON, derivative, slide_holding_forces

IMPULSE, REFLECT = 0, 1
LAW_IDS = {"impulse": IMPULSE, "reflect": REFLECT}
# StopsData.failed[0]: why the stops failed the run (0: they did not)
CONTACT_SOLVE_FAILED = 1
# which contacts an impact solve holds (bilateral): none (the law), the rods found at their stop
# not moving into it, or every contact (an accumulation point: the Zeno guard)
HOLD_NONE, HOLD_PRESSED, HOLD_ALL = 0, 1, 2
LOG_ROOM = 64   # rows of the impact log per stop (see `make_stops`)

StopsData = namedtuple("StopsData", [
    "watched",    # (n,) bool: rod k's stops are checked for crossings (not while it rests)
    "resting",    # (n,) int64: −1 / +1 rod held at its lower / upper stop, 0 free
    "stroke",     # (n, 2) [min, max] of each l_k, m
    "permanent",  # (n_u,) bool: locked by the scene (locked joints, fixed base)
    "law",        # StopLaw: the impact law and its parameters
    "log",        # (capacity, LOG_COLUMNS) one row per impact
    "log_q",      # (capacity, n_q) configuration at each impact
    "log_u",      # (capacity, 2, n_u) u⁻ and u⁺ of each impact
    "log_free",   # (capacity, n_u) bool: the pseudo-velocities free at each impact
    "count",      # (1,) int64: rows of the log in use
    "run",        # (n, 2, events.RUN_FIELDS) the Zeno guard's record per rod and stop (0 lower,
                  # 1 upper) (`events.zeno_guard`); cleared on reset
    "failed",     # (1,) int64: why the stops failed the run (CONTACT_SOLVE_FAILED), 0 while not
])

StopLaw = namedtuple("StopLaw", [
    "kind",         # IMPULSE (docs/model.md's unilateral law) or REFLECT (the paper's: l̇
                    # reversed alone)
    "restitution",  # e ∈ [0, 1]
    "rest_speed",   # m/s: a rod that would rebound slower than this stops dead and is held
])

ImpactScratch = namedtuple("ImpactScratch", [
    "M",         # (n_u, n_u) mass matrix
    "L",         # (n_u, n_u) its Cholesky factor
    "vectors",   # (4, n_u) scratch for the mass-matrix kernel and the solve
    "free",      # (n_u,) int64: the free pseudo-velocities, padded with −1
    "rods",      # (n,) int64: the rods in contact (those hit first)
    "hits",      # (n,) int64: the stop (−1, +1) each rod meets at this impact, 0 none
    "index",     # (n,) int64: the solve's active contacts
    "flags",     # (2, n) bool: each contact bilateral (held), active
    "contact",   # (6, n) per contact: σ, e, c⁻, (1 + e) c⁻, impulse P, w = W P + q
    "MinvE",     # (n, n_u) M⁻¹ E, one row per contact
    "W",         # (n, n) the Delassus matrix Eᵀ M⁻¹ E
    "cholesky",  # (n, n + 1) the solve's factor and right-hand side
    "saved_u",   # (2, n_u) u⁻ of an impact, and u⁺ of the law (an impact solved both ways)
    "saved_flags",  # (4, n) int64: resting and watched before the impact, and after the law
])


def make_stops(model, stop_law, permanently_locked, resting) -> StopsData:
    """The stops of `model` under the scene's `StrokeLimits` (None: no stops, never watched);
    ``resting`` (n,) int64 is the system's own array (`system.SystemData.resting`)."""
    n, nq, nu = model.n_links, model.n_q, model.n_u
    # Half of it is room for one step's impacts: LOG_ROOM at each stop of every rod and
    # 4·LOG_ROOM more — far more than a run of impacts takes to reach its accumulation point
    # (`events.zeno_guard`), so that the log-room exit (`stepping.CHATTER`) is a last resort.
    capacity = 4 * LOG_ROOM * (n + 2)
    permanent = np.zeros(nu, dtype=np.bool_)
    permanent[list(permanently_locked)] = True
    law = (StopLaw(LAW_IDS[stop_law.law], float(stop_law.restitution),
                   float(stop_law.rest_speed)) if stop_law else StopLaw(IMPULSE, 0.0, 0.0))
    return StopsData(np.zeros(n, dtype=np.bool_), resting,
                     np.array(model.stroke, dtype=float), permanent, law,
                     np.zeros((capacity, LOG_COLUMNS)), np.zeros((capacity, nq)),
                     np.zeros((capacity, 2, nu)), np.zeros((capacity, nu), dtype=np.bool_),
                     np.zeros(1, dtype=np.int64), np.zeros((n, 2, RUN_FIELDS)),
                     np.zeros(1, dtype=np.int64))


def make_impact_scratch(nu: int, n: int) -> ImpactScratch:
    """Everything one impact needs, preallocated: the kernels allocate nothing
    (`dynamics/jit.py`)."""
    n = max(n, 1)
    return ImpactScratch(np.zeros((nu, nu)), np.zeros((nu, nu)), np.zeros((4, nu)),
                         np.zeros(nu, dtype=np.int64), np.zeros(n, dtype=np.int64),
                         np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64),
                         np.zeros((2, n), dtype=np.bool_),
                         np.zeros((6, n)), np.zeros((n, nu)), np.zeros((n, n)),
                         np.zeros((n, n + 1)), np.zeros((2, nu)),
                         np.zeros((4, n), dtype=np.int64))


@jit
def relock(system, stops):
    """system.free = the pseudo-velocities neither locked by the scene nor held at a stop; the
    holding forces are watched at every evaluation while a rod rests (`system.watch_holding`)."""
    nu = system.free.shape[0]
    system.holding[HOLDING_ON] = 1.0 if any_resting(stops) else 0.0
    m = 0
    for j in range(nu):
        locked = stops.permanent[j]
        if j >= 2 and j % 2 == 1 and stops.resting[(j - 1) // 2 - 1] != 0:
            locked = True
        if not locked:
            system.free[m] = j
            m += 1
    for j in range(m, nu):
        system.free[j] = -1


@jit
def release(system, stops, s, scratch, ds, forces, at_root):
    """Free the resting rods that their stops would have to pull at s (``at_root``, s a located
    release instant: also one whose stop no longer pushes). With several resting rods, which
    ones leave is docs/model.md's contact law at the level of accelerations: holding forces λ ≥ 0,
    contact accelerations a = a₀ + W λ ≥ 0, λ ⊥ a, a₀ those with every resting rod free
    (`solve_contacts`), so freeing one never leaves another one pulled. Returns how many left."""
    derivative(system, s, ds)
    slide_holding_forces(system, stops.resting, forces)
    nq, _ = layout.sizes(system)
    rods, sigma, sides = scratch.rods, scratch.contact[0], scratch.hits
    pulled = False
    m = 0
    for k in range(1, stops.resting.shape[0] + 1):
        if stops.resting[k - 1] != 0:
            pull = stops.resting[k - 1] * forces[layout.u_slide(k)]
            pulled = pulled or pull > 0.0 or at_root and pull >= 0.0
            rods[m], sigma[m], sides[m] = k, -float(stops.resting[k - 1]), stops.resting[k - 1]
            m += 1
    if not pulled:
        return 0
    for c in range(m):
        stops.resting[rods[c] - 1] = 0
    if m > 1:
        relock(system, stops)
        derivative(system, s, ds)
        a0, P, w = scratch.contact[2], scratch.contact[4], scratch.contact[5]
        for c in range(m):
            a0[c] = sigma[c] * ds[nq + layout.u_slide(rods[c])]
        contact_matrix(system, stops, s, m, scratch)
        bilateral, active = scratch.flags[0, :m], scratch.flags[1, :m]
        for c in range(m):
            bilateral[c] = False
        if solve_contacts(scratch.W[:m, :m], a0[:m], bilateral, active, P[:m], w[:m],
                          scratch.cholesky[:m, :m + 1], scratch.index[:m]) < 0:
            stops.failed[0] = CONTACT_SOLVE_FAILED   # the run ends here (`Simulation`)
            return 0
        largest = 0.0
        for c in range(m):
            largest = max(largest, abs(P[c]))
        for c in range(m):
            # at a located root, the force that crossed zero is zero up to round-off
            if active[c] and P[c] > (1e-12 * largest if at_root else 0.0):
                stops.resting[rods[c] - 1] = sides[c]
    freed = 0
    for c in range(m):
        if stops.resting[rods[c] - 1] == 0:
            stops.watched[rods[c] - 1] = True
            freed += 1
    relock(system, stops)
    return freed


@jit_inline
def any_resting(stops):
    for k in range(stops.resting.shape[0]):
        if stops.resting[k] != 0:
            return True
    return False


@jit
def kinetic_energy(system, s):
    nq, nu = layout.sizes(system)
    kernels.frames(system.model, s[:nq], system.ws)
    return kernels.kinetic_energy(system.model, s[:nq], s[nq:nq + nu], system.ws)


@jit
def contact_impulses(system, stops, s, m, scratch):
    """One impact of the m contacts set up in scratch (rods, σ = +1 at a lower stop: away = +l,
    restitution e, bilateral flag): docs/model.md "Several stops at once", u⁺ = u⁻ + M⁻¹ E P with
    P ≥ 0 ⊥ c⁺ + e c⁻ ≥ 0, in place on s. Rods are unlocked for the impulse; afterwards a
    resting rod whose stop gave no impulse and that moves away leaves it (resting → 0). A
    bilateral contact (held: the Zeno guard, or a rod found at its stop not moving into it)
    takes an impulse of either sign and ends with c⁺ = 0. When the solve fails (`solve_contacts`
    returns −1), s is left as it was and stops.failed says so: the run ends there."""
    nq, _ = layout.sizes(system)
    rods = scratch.rods
    sigma, e, c_minus, qv, P, w = (scratch.contact[0], scratch.contact[1], scratch.contact[2],
                                   scratch.contact[3], scratch.contact[4], scratch.contact[5])
    n_free = contact_matrix(system, stops, s, m, scratch)
    free, MinvE = scratch.free, scratch.MinvE
    bilateral, active = scratch.flags[0, :m], scratch.flags[1, :m]
    for a in range(m):
        c_minus[a] = sigma[a] * s[nq + layout.u_slide(rods[a])]
        qv[a] = (1.0 + e[a]) * c_minus[a]
    if solve_contacts(scratch.W[:m, :m], qv[:m], bilateral, active, P[:m], w[:m],
                      scratch.cholesky[:m, :m + 1], scratch.index[:m]) < 0:
        stops.failed[0] = CONTACT_SOLVE_FAILED
        return
    for c in range(m):
        if P[c] != 0.0:
            for a in range(n_free):
                s[nq + free[a]] += P[c] * MinvE[c, a]
    for c in range(m):
        j = nq + layout.u_slide(rods[c])
        if active[c]:
            s[j] = -e[c] * c_minus[c] * sigma[c]   # exact: c⁺ = −e c⁻ on an active contact
        elif stops.resting[rods[c] - 1] != 0:
            stops.resting[rods[c] - 1] = 0          # its stop would have had to pull: it leaves
            stops.watched[rods[c] - 1] = True
    relock(system, stops)


@jit
def solve_impact(system, stops, s, first, row, scratch, holds):
    """Apply the impact of log rows first..row (the rods hit) and every resting rod to s, holding
    (bilateral, e = 0) the contacts ``holds`` says (HOLD_NONE: the law alone; HOLD_PRESSED: the
    rods found at their stop not moving into it; HOLD_ALL: every contact)."""
    nq, _ = layout.sizes(system)
    law, restitution, rest_speed = stops.law.kind, stops.law.restitution, stops.law.rest_speed
    rods, sigma, e = scratch.rods, scratch.contact[0], scratch.contact[1]
    bilateral = scratch.flags[0]
    m = 0
    for i in range(first, row):
        r, side = int(stops.log[i, LOG_LINK]), stops.log[i, LOG_SIDE]
        u_before = stops.log[i, LOG_LD_BEFORE]
        pressed = side * u_before <= 0.0
        held = holds == HOLD_ALL or holds == HOLD_PRESSED and pressed
        e_r = 0.0 if held or abs(restitution * u_before) < rest_speed else restitution
        if law == REFLECT:
            s[nq + layout.u_slide(r)] = -e_r * u_before
        rods[m], sigma[m], e[m], bilateral[m] = r, -side, e_r, held
        m += 1
    if law == IMPULSE:
        for r in range(1, stops.resting.shape[0] + 1):
            if stops.resting[r - 1] != 0:
                rods[m], sigma[m], e[m] = r, -float(stops.resting[r - 1]), 0.0
                bilateral[m] = holds == HOLD_ALL
                m += 1
        contact_impulses(system, stops, s, m, scratch)


@jit_inline
def save_outcome(system, stops, s, scratch, which):
    """Keep u and the resting and watched flags of s as scratch.saved_u[which] (0: before the
    impact, 1: after the law)."""
    nq, nu = layout.sizes(system)
    for j in range(nu):
        scratch.saved_u[which, j] = s[nq + j]
    for r in range(stops.resting.shape[0]):
        scratch.saved_flags[2 * which, r] = stops.resting[r]
        scratch.saved_flags[2 * which + 1, r] = 1 if stops.watched[r] else 0


@jit_inline
def restore_outcome(system, stops, s, scratch, which):
    nq, nu = layout.sizes(system)
    for j in range(nu):
        s[nq + j] = scratch.saved_u[which, j]
    for r in range(stops.resting.shape[0]):
        stops.resting[r] = scratch.saved_flags[2 * which, r]
        stops.watched[r] = scratch.saved_flags[2 * which + 1, r] != 0
    relock(system, stops)


@jit
def impact(system, stops, s, k, side, t, scratch, ds, forces):
    """Rod k (1-based) meets its lower (side −1) or upper (+1) stop at time t (s), s the located
    state (l_k at the stop): one impact of every rod reaching its stop within
    `events.SIMULTANEOUS` of t (`events.simultaneous_hits`) and every resting rod; a rod whose
    rebound would be slower than rest_speed stops dead (e = 0) and rests, the others rebound.

    Holds (docs/model.md, "Resting, leaving, and no Zeno"): where the Zeno guard sees evidence of
    an accumulation point (`events.zeno_guard`), the impact is solved both ways, by the law and
    with every contact held, and held only when the hold removes no more than the guard allows
    beyond the law; a rod found at its stop not moving into it is always held (its rebound is too
    small to resolve in time). One log row per rod hit; on the first, the energy the law removed
    (LOG_LOST), the energy the hold removed beyond it (LOG_HOLD_LOST) and what a Zeno hold may
    remove there (LOG_HOLD_BOUND, `events.ZENO_SHARE` of the run's kinetic energy). Then a
    resting rod that its stop would have to pull leaves (`release`). Returns (energy the law
    removed (J), energy the hold removed (J), 1.0 for a hold or 0.0)."""
    nq, nu = layout.sizes(system)
    n = stops.resting.shape[0]
    hits = scratch.hits
    simultaneous_hits(system, stops, s, k, side, hits)
    T_before = kinetic_energy(system, s)
    allowance = -1.0   # what a hold may remove beyond the law (J); −1: no evidence of Zeno
    bound = 0.0        # ZENO_SHARE of the largest run energy among the stops hit (J)
    for r in range(1, n + 1):
        if hits[r - 1] != 0:
            allowed = zeno_guard(stops.run, r, hits[r - 1], t,
                                 abs(s[nq + layout.u_slide(r)]), T_before)
            if allowed >= 0.0:
                allowance = allowed if allowance < 0.0 else min(allowance, allowed)
            bound = max(bound, ZENO_SHARE * stops.run[r - 1, 0 if hits[r - 1] < 0 else 1,
                                                      RUN_ENERGY])
    row = stops.count[0]
    first = row
    pressed = False
    for r in range(1, n + 1):
        if hits[r - 1] != 0:
            for i in range(nq):
                stops.log_q[row, i] = s[i]
            for i in range(nu):
                stops.log_u[row, 0, i] = s[nq + i]
                stops.log_free[row, i] = False
            for a in range(nu):
                if system.free[a] >= 0:
                    stops.log_free[row, system.free[a]] = True
            log = stops.log[row]
            log[LOG_TIME], log[LOG_LINK], log[LOG_SIDE] = t, r, hits[r - 1]
            log[LOG_LD_BEFORE] = s[nq + layout.u_slide(r)]
            # A crossing located with the rod at the stop but not moving into it is found at
            # the very instant the rod left: its rebound is too small to resolve in time, i.e.
            # the rod is pressed against the stop. Hold it there; ignoring the crossing would
            # restart the event loop at this same instant forever (a Zeno stall).
            log[LOG_HELD] = 1.0 if hits[r - 1] * log[LOG_LD_BEFORE] <= 0.0 else 0.0
            pressed = pressed or log[LOG_HELD] != 0.0
            row += 1
    holds = HOLD_NONE
    if allowance < 0.0 and not pressed:
        solve_impact(system, stops, s, first, row, scratch, HOLD_NONE)
        T_law = kinetic_energy(system, s)
    else:
        # solved both ways: the law (booked as the impact's loss), then with the holds
        save_outcome(system, stops, s, scratch, 0)
        solve_impact(system, stops, s, first, row, scratch, HOLD_NONE)
        T_law = kinetic_energy(system, s)
        if allowance >= 0.0 and stops.failed[0] == 0:
            save_outcome(system, stops, s, scratch, 1)
            restore_outcome(system, stops, s, scratch, 0)
            solve_impact(system, stops, s, first, row, scratch, HOLD_ALL)
            holds = HOLD_ALL
            if T_law - kinetic_energy(system, s) > allowance:   # no accumulation: the law
                holds = HOLD_NONE
                restore_outcome(system, stops, s, scratch, 1)
        if holds == HOLD_NONE and pressed and stops.failed[0] == 0:
            restore_outcome(system, stops, s, scratch, 0)
            solve_impact(system, stops, s, first, row, scratch, HOLD_PRESSED)
            holds = HOLD_PRESSED
    if stops.failed[0] != 0:
        return 0.0, 0.0, 0.0
    for i in range(first, row):
        r = int(stops.log[i, LOG_LINK])
        if holds == HOLD_ALL:
            stops.log[i, LOG_HELD] = 1.0
        elif holds == HOLD_NONE:
            stops.log[i, LOG_HELD] = 0.0
        if s[nq + layout.u_slide(r)] == 0.0:   # stopped dead (e = 0, active): held at its stop
            s[nq + layout.u_slide(r)] = 0.0     # (not −0.0)
            stops.resting[r - 1] = hits[r - 1]
            stops.watched[r - 1] = False
    for i in range(first, row):
        r = int(stops.log[i, LOG_LINK])
        stops.log[i, LOG_LD_AFTER] = s[nq + layout.u_slide(r)]
        stops.log[i, LOG_LOST] = 0.0
        stops.log[i, LOG_HOLD_LOST] = 0.0
        stops.log[i, LOG_HOLD_BOUND] = 0.0
        stops.log[i, LOG_RESTING] = 1.0 if stops.resting[r - 1] != 0 else 0.0
        for j in range(nu):
            stops.log_u[i, 1, j] = s[nq + j]
    stops.count[0] = row
    relock(system, stops)
    lost = T_before - T_law
    removed = T_law - kinetic_energy(system, s) if holds != HOLD_NONE else 0.0
    stops.log[first, LOG_LOST] = lost
    stops.log[first, LOG_HOLD_LOST] = removed
    stops.log[first, LOG_HOLD_BOUND] = bound
    if any_resting(stops):
        release(system, stops, s, scratch, ds, forces, False)
    return lost, removed, 1.0 if holds != HOLD_NONE else 0.0
