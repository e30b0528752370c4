"""Stroke end stops, compiled: the impact law, resting at a stop and leaving it.

- Impact (`impact`): docs/model.md's unilateral impact law — one solve for every stop in contact at
  that instant, the one hit and those resting, each stop only pushing (`contact_impulses`,
  `solve_contacts`) — or the paper's `reflect` law; the record of every impact
  goes to the stop log (`StopsData.log`), from which `Simulation` builds its `Impact` list.
- Resting: a rod whose rebound speed is below ``rest_speed`` is held at the stop (its l̇ degree
  of freedom is locked, not stiffly pushed back), and so is a rod whose rebounds are too small
  to resolve (the Zeno guard, `events.zeno_guard`, called by both cores at each impact, its
  runs kept here in `StopsData.run`). It leaves when the stop would have to pull to hold it
  (`release`: the holding force changes sign), located inside the step like an impact
  (`events.py`) and checked whenever the command changes.
"""
from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass

import numpy as np

from ..dynamics import kernels
from ..dynamics.jit import jit, jit_inline
from . import layout
from .events import ZENO_IMPACTS, holding_margin
from .system import derivative, slide_holding_forces

IMPULSE, REFLECT = 0, 1
LAW_IDS = {"impulse": IMPULSE, "reflect": REFLECT}
# log[i, ...] columns
LOG_TIME, LOG_LINK, LOG_SIDE, LOG_LD_BEFORE, LOG_LD_AFTER, LOG_LOST, LOG_RESTING, LOG_HELD = range(8)
LOG_COLUMNS = 8

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
    "run",        # (n, 2, 2) the Zeno guard's run per rod and stop (0 lower, 1 upper): impacts,
                  # time of the first (s) (`events.zeno_guard`); zeros: none; cleared on reset
])

StopLaw = namedtuple("StopLaw", [
    "kind",         # IMPULSE (docs/model.md's unilateral law) or REFLECT (the paper's: l̇ reversed alone)
    "restitution",  # e ∈ [0, 1]
    "rest_speed",   # m/s: a rod rebounding slower than this is held at its stop
])

ImpactScratch = namedtuple("ImpactScratch", [
    "M",         # (n_u, n_u) mass matrix
    "L",         # (n_u, n_u) its Cholesky factor
    "vectors",   # (4, n_u) scratch for the mass-matrix kernel and the solve
    "free",      # (n_u,) int64: the free pseudo-velocities, padded with −1
    "rods",      # (n,) int64: the rods in contact (the one hit first)
    "index",     # (n,) int64: the solve's active contacts
    "flags",     # (2, n) bool: each contact bilateral, active
    "contact",   # (6, n) per contact: σ, e, c⁻, (1 + e) c⁻, impulse P, w = W P + q
    "MinvE",     # (n, n_u) M⁻¹ E, one row per contact
    "W",         # (n, n) the Delassus matrix Eᵀ M⁻¹ E
    "cholesky",  # (n, n + 1) the solve's factor and right-hand side
])


def make_stops(model, stop_law, permanently_locked) -> StopsData:
    """The stops of `model` under the scene's `StrokeLimits` (None: no stops, never watched)."""
    n, nq, nu = model.n_links, model.n_q, model.n_u
    # Half of it is room for one step's impacts: a run of ZENO_IMPACTS at each stop of every
    # rod (the Zeno guard holds the rod at the last) and 4·ZENO_IMPACTS more, so that the
    # log-room exit (`stepping.CHATTER`) is a last resort.
    capacity = 4 * ZENO_IMPACTS * (n + 2)
    permanent = np.zeros(nu, dtype=np.bool_)
    permanent[list(permanently_locked)] = True
    return StopsData(np.zeros(n, dtype=np.bool_), np.zeros(n, dtype=np.int64),
                     np.array(model.stroke, dtype=float), permanent,
                     StopLaw(LAW_IDS[stop_law.law], float(stop_law.restitution),
                             float(stop_law.rest_speed)) if stop_law else StopLaw(IMPULSE, 0.0, 0.0),
                     np.zeros((capacity, LOG_COLUMNS)), np.zeros((capacity, nq)),
                     np.zeros((capacity, 2, nu)), np.zeros((capacity, nu), dtype=np.bool_),
                     np.zeros(1, dtype=np.int64), np.zeros((n, 2, 2)))


def make_impact_scratch(nu: int, n: int) -> ImpactScratch:
    """Everything one impact needs, preallocated: the kernels allocate nothing (`dynamics/jit.py`)."""
    n = max(n, 1)
    return ImpactScratch(np.zeros((nu, nu)), np.zeros((nu, nu)), np.zeros((4, nu)),
                         np.zeros(nu, dtype=np.int64), np.zeros(n, dtype=np.int64),
                         np.zeros(n, dtype=np.int64), np.zeros((2, n), dtype=np.bool_),
                         np.zeros((6, n)), np.zeros((n, nu)), np.zeros((n, n)), np.zeros((n, n + 1)))


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
def release(system, stops, s, ds, forces, at_root):
    """Free every resting rod whose stop would have to pull at s; ``at_root`` (s is a located
    release instant): also those whose stop no longer pushes (force ≥ 0). Returns how many."""
    derivative(system, s, ds)
    slide_holding_forces(system, stops.resting, forces)
    freed = 0
    for k in range(1, stops.resting.shape[0] + 1):
        pull = stops.resting[k - 1] * forces[layout.u_l(k)]
        if stops.resting[k - 1] != 0 and (pull > 0.0 or at_root and pull >= 0.0):
            stops.resting[k - 1] = 0
            stops.watched[k - 1] = True
            freed += 1
    if freed:
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
def contact_impulses(system, stops, s, k_hit, side_hit, restitution, settling, scratch):
    """One impact with every stop in contact at this instant: the one rod k_hit meets (Newton
    restitution e) and those resting (e = 0), each stop only pushing (docs/model.md "Several stops at
    once"): u⁺ = u⁻ + M⁻¹ E P, in place on s. Rods are unlocked for the impulse; afterwards a
    resting rod whose stop gave no impulse and that moves away leaves it (resting → 0).

    ``settling``: the rod arrives slower than the rest speed (or the Zeno guard holds it): every
    contact is then held (bilateral, c⁺ = 0) — below the rest speed, rods touching their stops are
    in persistent contact, and the holding forces decide when each leaves (`release`). Solving
    such an impact unilaterally instead would throw a pressed neighbour off with a speed below
    the rest speed, to land again at once: two rods trading impacts without end (Zeno)."""
    nq, nu = layout.sizes(system)
    n = stops.resting.shape[0]
    q = s[:nq]
    # contacts: the rod hit first, then the resting ones; σ = +1 at a lower stop (away = +l)
    rods, free = scratch.rods, scratch.free
    sigma, e, c_minus, qv, P, w = (scratch.contact[0], scratch.contact[1], scratch.contact[2],
                                   scratch.contact[3], scratch.contact[4], scratch.contact[5])
    for i in range(n):
        e[i] = 0.0
    rods[0], sigma[0], e[0] = k_hit, -float(side_hit), restitution
    m = 1
    for k in range(1, n + 1):
        if k != k_hit and stops.resting[k - 1] != 0:
            rods[m], sigma[m] = k, -float(stops.resting[k - 1])
            m += 1
    # free DOFs for the impulse: all but the scene's locked ones
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
    # M⁻¹ E, one column per contact (over the free DOFs, in free order)
    MinvE = scratch.MinvE
    for c in range(m):
        j = layout.u_l(rods[c])
        for i in range(nu):
            unit[i] = 0.0
        unit[j] = sigma[c]
        kernels.cholesky_solve(scratch.M, unit, free, n_free, scratch.L, MinvE[c])
    W = scratch.W[:m, :m]
    for a in range(m):
        c_minus[a] = sigma[a] * s[nq + layout.u_l(rods[a])]
        for b in range(m):
            # W_ab = E_aᵀ M⁻¹ E_b: row a of E picks DOF j_a, which sits at position pos in free
            j = layout.u_l(rods[a])
            pos = 0
            while free[pos] != j:
                pos += 1
            W[a, b] = sigma[a] * MinvE[b, pos]
    bilateral, active = scratch.flags[0, :m], scratch.flags[1, :m]
    for a in range(m):
        qv[a] = (1.0 + e[a]) * c_minus[a]
        bilateral[a] = settling
        active[a] = False
    solve_contacts(W, qv[:m], bilateral, active, P[:m], w[:m], scratch.cholesky[:m, :m + 1],
                   scratch.index[:m])
    for c in range(m):
        if P[c] != 0.0:
            for a in range(n_free):
                s[nq + free[a]] += P[c] * MinvE[c, a]
    for c in range(m):
        j = nq + layout.u_l(rods[c])
        if active[c]:
            s[j] = -e[c] * c_minus[c] * sigma[c]   # exact: c⁺ = −e c⁻ on an active contact
        elif c > 0 and stops.resting[rods[c] - 1] != 0:
            stops.resting[rods[c] - 1] = 0          # its stop would have had to pull: it leaves
            stops.watched[rods[c] - 1] = True
    relock(system, stops)


@jit
def impact(system, stops, s, k, side, t, hold, scratch, ds, forces):
    """Rod k (1-based) meets its lower (side −1) or upper (+1) stop at time t (s): the impact
    law, then a rebound or rest, logged. ``hold`` stops it at rest whatever its speed."""
    nq, nu = layout.sizes(system)
    j = layout.u_l(k)
    law, restitution, rest_speed = stops.law.kind, stops.law.restitution, stops.law.rest_speed
    u_before = s[nq + j]
    row = stops.count[0]
    held = hold or side * u_before <= 0.0
    # A crossing located with the rod at the stop but not moving into it is found at the very
    # instant the rod left: its rebound is too small to resolve in time, i.e. the rod is
    # pressed against the stop. Hold it there; ignoring the crossing would restart the event
    # loop at this same instant forever (a Zeno stall, e.g. with rest_speed 0).
    for i in range(nq):
        stops.log_q[row, i] = s[i]
    for i in range(nu):
        stops.log_u[row, 0, i] = s[nq + i]
        stops.log_free[row, i] = False
    for a in range(nu):
        if system.free[a] >= 0:
            stops.log_free[row, system.free[a]] = True
    T_before = kinetic_energy(system, s)
    e = restitution
    if held or law == IMPULSE and abs(restitution * u_before) < rest_speed:
        e = 0.0
    if law == REFLECT:
        s[nq + j] = -e * u_before
    else:
        contact_impulses(system, stops, s, k, side, e, held or abs(u_before) < rest_speed, scratch)
    resting = held or abs(s[nq + j]) < rest_speed
    if resting:
        s[nq + j] = 0.0
    T_after = kinetic_energy(system, s)
    for i in range(nu):
        stops.log_u[row, 1, i] = s[nq + i]
    log = stops.log[row]
    log[LOG_TIME], log[LOG_LINK], log[LOG_SIDE] = t, k, side
    log[LOG_LD_BEFORE], log[LOG_LD_AFTER], log[LOG_LOST] = u_before, s[nq + j], T_before - T_after
    log[LOG_RESTING] = 1.0 if resting else 0.0
    log[LOG_HELD] = 1.0 if held else 0.0
    stops.count[0] = row + 1
    if resting:
        stops.resting[k - 1] = side
        stops.watched[k - 1] = False
        relock(system, stops)
        if holding_margin(system, s, stops.resting, ds, forces) < 0.0:
            release(system, stops, s, ds, forces, False)
    return T_before - T_after


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
