"""Stroke end stops, compiled: the impact law, resting at a stop and leaving it (the semantics
in docs/model.md, "Resting, leaving, and no Zeno").

- Impact (`impact`): docs/model.md's unilateral impact law — one solve for every stop in contact at
  that instant: the rods reaching their stops within `events.SIMULTANEOUS` of each other (each
  with its restitution, 0 for one arriving slower than rebounds are kept) and those resting
  (e = 0), each stop only pushing (`contact_impulses`, `solve_contacts`) — or the paper's
  `reflect` law; one row per rod hit goes to the stop log (`StopsData.log`), from which
  `Simulation` builds its `Impact` list.
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

import math
from collections import namedtuple
from dataclasses import dataclass

import numpy as np

from ..dynamics import kernels
from ..dynamics.jit import jit, jit_inline
from . import layout
from .events import simultaneous_hits, zeno_guard
from .system import derivative, slide_holding_forces

IMPULSE, REFLECT = 0, 1
LAW_IDS = {"impulse": IMPULSE, "reflect": REFLECT}
# log[i, ...] columns
(LOG_TIME, LOG_LINK, LOG_SIDE, LOG_LD_BEFORE, LOG_LD_AFTER, LOG_LOST, LOG_RESTING,
 LOG_HELD) = range(8)
LOG_COLUMNS = 8
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
    "run",        # (n, 2, 3) the Zeno guard's record per rod and stop (0 lower, 1 upper): impacts,
                  # time of the last (s), interval before it (s) (`events.zeno_guard`); cleared
                  # on reset
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
])


def make_stops(model, stop_law, permanently_locked) -> StopsData:
    """The stops of `model` under the scene's `StrokeLimits` (None: no stops, never watched)."""
    n, nq, nu = model.n_links, model.n_q, model.n_u
    # Half of it is room for one step's impacts: LOG_ROOM at each stop of every rod and
    # 4·LOG_ROOM more — far more than a run of impacts takes to reach its accumulation point
    # (`events.zeno_guard`), so that the log-room exit (`stepping.CHATTER`) is a last resort.
    capacity = 4 * LOG_ROOM * (n + 2)
    permanent = np.zeros(nu, dtype=np.bool_)
    permanent[list(permanently_locked)] = True
    law = (StopLaw(LAW_IDS[stop_law.law], float(stop_law.restitution),
                   float(stop_law.rest_speed)) if stop_law else StopLaw(IMPULSE, 0.0, 0.0))
    return StopsData(np.zeros(n, dtype=np.bool_), np.zeros(n, dtype=np.int64),
                     np.array(model.stroke, dtype=float), permanent, law,
                     np.zeros((capacity, LOG_COLUMNS)), np.zeros((capacity, nq)),
                     np.zeros((capacity, 2, nu)), np.zeros((capacity, nu), dtype=np.bool_),
                     np.zeros(1, dtype=np.int64), np.zeros((n, 2, 3)))


def make_impact_scratch(nu: int, n: int) -> ImpactScratch:
    """Everything one impact needs, preallocated: the kernels allocate nothing
    (`dynamics/jit.py`)."""
    n = max(n, 1)
    return ImpactScratch(np.zeros((nu, nu)), np.zeros((nu, nu)), np.zeros((4, nu)),
                         np.zeros(nu, dtype=np.int64), np.zeros(n, dtype=np.int64),
                         np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64),
                         np.zeros((2, n), dtype=np.bool_),
                         np.zeros((6, n)), np.zeros((n, nu)), np.zeros((n, n)),
                         np.zeros((n, n + 1)))


@jit
def relock(system, stops):
    """system.free = the pseudo-velocities neither locked by the scene nor held at a stop."""
    nu = system.free.shape[0]
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
        solve_contacts(scratch.W[:m, :m], a0[:m], bilateral, active, P[:m], w[:m],
                       scratch.cholesky[:m, :m + 1], scratch.index[:m])
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
def solve_contacts(W, q, bilateral, active, P, w, scratch, idx):
    """The impact LCP of docs/model.md, exactly: P ≥ 0, w = W P + q ≥ 0, Pᵀw = 0 (W m×m symmetric
    positive definite, so the solution is unique), by Murty's least-index principal pivoting:
    solve on the active set, toggle the first contact that is wrong (a negative impulse, or an
    inactive one moving into its stop), repeat — finite for a P-matrix. A ``bilateral`` contact
    is always active with an impulse of either sign (a rod held by the Zeno guard). ``scratch`` is
    (m, m + 1), ``idx`` (m,) int64. Returns the pivots taken."""
    m = q.shape[0]
    for i in range(m):
        active[i] = bilateral[i]
    scale = 0.0
    for i in range(m):
        scale = max(scale, abs(q[i]))
    tol = 1e-13 * scale
    for pivots in range(1 << min(m + 4, 30)):
        # P_A = −W_AA⁻¹ q_A by Cholesky on the active rows, zero elsewhere
        L = scratch
        n = 0
        for i in range(m):
            if active[i]:
                idx[n] = i
                n += 1
        for a in range(n):
            for c in range(a + 1):
                s = W[idx[a], idx[c]]
                for k in range(c):
                    s -= L[a, k] * L[c, k]
                if a == c:
                    L[a, a] = math.sqrt(s) if s > 0.0 else math.nan
                else:
                    L[a, c] = s / L[c, c]
        y = L[:, m]
        for a in range(n):
            s = -q[idx[a]]
            for k in range(a):
                s -= L[a, k] * y[k]
            y[a] = s / L[a, a]
        for a in range(n - 1, -1, -1):
            s = y[a]
            for k in range(a + 1, n):
                s -= L[k, a] * y[k]
            y[a] = s / L[a, a]
        for i in range(m):
            P[i] = 0.0
        for a in range(n):
            P[idx[a]] = y[a]
        for i in range(m):
            s = q[i]
            for j in range(m):
                s += W[i, j] * P[j]
            w[i] = s
        wrong = -1
        for i in range(m):
            if bilateral[i]:
                continue
            if active[i] and P[i] < -tol or not active[i] and w[i] < -tol:
                wrong = i
                break
        if wrong < 0:
            for i in range(m):
                if not active[i]:
                    P[i] = 0.0
            return pivots
        active[wrong] = not active[wrong]
    return -1


@jit
def contact_matrix(system, stops, s, m, scratch):
    """W = Eᵀ M⁻¹ E (into scratch.W[:m, :m]) and M⁻¹ E (scratch.MinvE, one row per contact, over
    the free DOFs in free order) for the m contacts scratch.rods[:m] with directions σ in
    scratch.contact[0], every DOF free but the scene's locked ones (into scratch.free). Returns
    how many DOFs are free."""
    nq, nu = layout.sizes(system)
    q = s[:nq]
    rods, free, sigma = scratch.rods, scratch.free, scratch.contact[0]
    for j in range(nu):
        free[j] = -1
    n_free = 0
    for j in range(nu):
        if not stops.permanent[j]:
            free[n_free] = j
            n_free += 1
    zeros, unit, column = scratch.vectors[0], scratch.vectors[1], scratch.vectors[2]
    kernels.frames(system.model, q, system.ws)
    for i in range(nu):
        zeros[i] = 0.0
    kernels.mass_matrix(system.model, q, system.ws, zeros, unit, column, scratch.M)
    MinvE = scratch.MinvE
    for c in range(m):
        for i in range(nu):
            unit[i] = 0.0
        unit[layout.u_slide(rods[c])] = sigma[c]
        kernels.cholesky_solve(scratch.M, unit, free, n_free, scratch.L, MinvE[c])
    W = scratch.W
    for a in range(m):
        # W_ab = E_aᵀ M⁻¹ E_b: row a of E picks DOF j_a, which sits at position pos in free
        j = layout.u_slide(rods[a])
        pos = 0
        while free[pos] != j:
            pos += 1
        for b in range(m):
            W[a, b] = sigma[a] * MinvE[b, pos]
    return n_free


@jit
def contact_impulses(system, stops, s, m, scratch):
    """One impact of the m contacts set up in scratch (rods, σ = +1 at a lower stop: away = +l,
    restitution e, bilateral flag): docs/model.md "Several stops at once", u⁺ = u⁻ + M⁻¹ E P with
    P ≥ 0 ⊥ c⁺ + e c⁻ ≥ 0, in place on s. Rods are unlocked for the impulse; afterwards a
    resting rod whose stop gave no impulse and that moves away leaves it (resting → 0). A
    bilateral contact (held: the Zeno guard, or a rod found at its stop not moving into it)
    takes an impulse of either sign and ends with c⁺ = 0."""
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
    solve_contacts(scratch.W[:m, :m], qv[:m], bilateral, active, P[:m], w[:m],
                   scratch.cholesky[:m, :m + 1], scratch.index[:m])
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
def impact(system, stops, s, k, side, t, scratch, ds, forces):
    """Rod k (1-based) meets its lower (side −1) or upper (+1) stop at time t (s), s the located
    state (l_k at the stop): one impact of every rod reaching its stop within
    `events.SIMULTANEOUS` of t (`events.simultaneous_hits`) and every resting rod; a rod whose
    rebound would be slower than rest_speed stops dead (e = 0) and rests, the others rebound.
    One log row per rod hit (the impact's whole energy loss on the first). Then a resting rod
    that its stop would have to pull leaves (`release`). Returns the energy lost (J)."""
    nq, nu = layout.sizes(system)
    n = stops.resting.shape[0]
    law, restitution, rest_speed = stops.law.kind, stops.law.restitution, stops.law.rest_speed
    hits = scratch.hits
    simultaneous_hits(system, stops, s, k, side, hits)
    hold = False   # an accumulation point at any stop hit: every contact is held
    for r in range(1, n + 1):
        if hits[r - 1] != 0 and zeno_guard(stops.run, r, hits[r - 1], t):
            hold = True
    row = stops.count[0]
    first = row
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
            log[LOG_HELD] = 1.0 if hold or hits[r - 1] * log[LOG_LD_BEFORE] <= 0.0 else 0.0
            row += 1
    T_before = kinetic_energy(system, s)
    rods, sigma, e = scratch.rods, scratch.contact[0], scratch.contact[1]
    bilateral = scratch.flags[0]
    m = 0
    for i in range(first, row):
        r, u_before = int(stops.log[i, LOG_LINK]), stops.log[i, LOG_LD_BEFORE]
        held = stops.log[i, LOG_HELD] != 0.0
        e_r = 0.0 if held or abs(restitution * u_before) < rest_speed else restitution
        if law == REFLECT:
            s[nq + layout.u_slide(r)] = -e_r * u_before
        rods[m], sigma[m], e[m], bilateral[m] = r, -float(stops.log[i, LOG_SIDE]), e_r, held
        m += 1
    if law == IMPULSE:
        for r in range(1, n + 1):
            if stops.resting[r - 1] != 0:
                rods[m], sigma[m], e[m], bilateral[m] = r, -float(stops.resting[r - 1]), 0.0, hold
                m += 1
        contact_impulses(system, stops, s, m, scratch)
    for i in range(first, row):
        r = int(stops.log[i, LOG_LINK])
        if s[nq + layout.u_slide(r)] == 0.0:   # stopped dead (e = 0, active): held at its stop
            s[nq + layout.u_slide(r)] = 0.0     # (not −0.0)
            stops.resting[r - 1] = hits[r - 1]
            stops.watched[r - 1] = False
    for i in range(first, row):
        r = int(stops.log[i, LOG_LINK])
        stops.log[i, LOG_LD_AFTER] = s[nq + layout.u_slide(r)]
        stops.log[i, LOG_LOST] = 0.0
        stops.log[i, LOG_RESTING] = 1.0 if stops.resting[r - 1] != 0 else 0.0
        for j in range(nu):
            stops.log_u[i, 1, j] = s[nq + j]
    stops.count[0] = row
    relock(system, stops)
    lost = T_before - kinetic_energy(system, s)
    stops.log[first, LOG_LOST] = lost
    if any_resting(stops):
        release(system, stops, s, scratch, ds, forces, False)
    return lost


@dataclass(frozen=True)
class Impact:
    """One end-stop impact, as runs and bags report it."""

    time: float            # s
    link: int              # 1-based
    stop: str              # "lower" or "upper"
    ld_before: float       # l̇_k before (m/s)
    ld_after: float        # l̇_k after (m/s)
    energy_lost: float     # J: T⁻ − T⁺
    resting: bool          # held at the stop afterwards

    def as_dict(self) -> dict:
        return dict(self.__dict__)

    @staticmethod
    def from_log(row) -> "Impact":
        # Plain Python numbers (not numpy scalars), so records serialise anywhere (CSV, YAML, bags).
        return Impact(float(row[LOG_TIME]), int(row[LOG_LINK]),
                      "lower" if row[LOG_SIDE] < 0 else "upper", float(row[LOG_LD_BEFORE]),
                      float(row[LOG_LD_AFTER]), float(row[LOG_LOST]), bool(row[LOG_RESTING]))
