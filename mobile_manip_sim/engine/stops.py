"""Stroke end stops, compiled: the impact law, resting at a stop and leaving it.

- Impact (`impact`): MODEL.md's generalized impulse along e_k (with the degrees of freedom that
  are locked at that instant removed), or the paper's `reflect` law; the record of every impact
  goes to the stop log (`StopsData.log`), from which `Simulation` builds its `Impact` list.
- Resting: a rod whose rebound speed is below ``rest_speed`` is held at the stop (its l̇ degree
  of freedom is locked, not stiffly pushed back), and so is a rod whose rebounds are too small
  to resolve (the Zeno guards). It leaves when the stop would have to pull to hold it
  (`release`: the holding force changes sign), located inside the step like an impact
  (`events.py`) and checked whenever the command changes.
"""
from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass

import numpy as np

from ..dynamics import kernels
from ..dynamics.jit import jit
from . import layout
from .events import holding_margin
from .system import derivative, holding_forces

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
    "law",        # (3,) law id, restitution e, rest speed (m/s)
    "log",        # (capacity, LOG_COLUMNS) one row per impact
    "log_q",      # (capacity, n_q) configuration at each impact
    "log_u",      # (capacity, 2, n_u) u⁻ and u⁺ of each impact
    "log_free",   # (capacity, n_u) bool: the pseudo-velocities free at each impact
    "count",      # (1,) int64: rows of the log in use
])

ImpactScratch = namedtuple("ImpactScratch", [
    "M",        # (n_u, n_u) mass matrix
    "L",        # (n_u, n_u) its Cholesky factor
    "vectors",  # (4, n_u) scratch for the mass-matrix kernel and the solve
])


def make_stops(model, law, restitution, rest_speed, permanently_locked, capacity=1024) -> StopsData:
    n, nq, nu = model.n_links, model.n_q, model.n_u
    permanent = np.zeros(nu, dtype=np.bool_)
    permanent[list(permanently_locked)] = True
    return StopsData(np.zeros(n, dtype=np.bool_), np.zeros(n, dtype=np.int64),
                     np.array(model.stroke, dtype=float), permanent,
                     np.array([LAW_IDS.get(law, IMPULSE), restitution, rest_speed]),
                     np.zeros((capacity, LOG_COLUMNS)), np.zeros((capacity, nq)),
                     np.zeros((capacity, 2, nu)), np.zeros((capacity, nu), dtype=np.bool_),
                     np.zeros(1, dtype=np.int64))


def make_impact_scratch(nu: int) -> ImpactScratch:
    return ImpactScratch(np.zeros((nu, nu)), np.zeros((nu, nu)), np.zeros((4, nu)))


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
def release(system, stops, s, ds, forces):
    """Free every resting rod that its stop would have to pull at s. Returns how many."""
    derivative(system, s, ds)
    holding_forces(system, s, ds, forces)
    freed = 0
    for k in range(1, stops.resting.shape[0] + 1):
        side = stops.resting[k - 1]
        if side != 0 and side * forces[layout.u_l(k)] > 0.0:
            stops.resting[k - 1] = 0
            stops.watched[k - 1] = True
            freed += 1
    if freed:
        relock(system, stops)
    return freed


@jit
def release_at_root(system, stops, s, ds, forces):
    """At a located release instant: free every resting rod whose stop no longer pushes (≥ 0)."""
    derivative(system, s, ds)
    holding_forces(system, s, ds, forces)
    for k in range(1, stops.resting.shape[0] + 1):
        side = stops.resting[k - 1]
        if side != 0 and side * forces[layout.u_l(k)] >= 0.0:
            stops.resting[k - 1] = 0
            stops.watched[k - 1] = True
    relock(system, stops)


@jit
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
def impulse(system, s, j, restitution, scratch):
    """MODEL.md's law on rod pseudo-velocity j with the free DOFs of `system.free`:
    u⁺ = u⁻ − (1 + e) (e_jᵀ u⁻ / (e_jᵀ M⁻¹ e_j)) M⁻¹ e_j, in place on s."""
    nq, nu = layout.sizes(system)
    q = s[:nq]
    zeros, unit, column, w = scratch.vectors[0], scratch.vectors[1], scratch.vectors[2], scratch.vectors[3]
    kernels.frames(system.model, q, system.ws)
    for i in range(nu):
        zeros[i] = 0.0
    kernels.mass_matrix(system.model, q, system.ws, zeros, unit, column, scratch.M)
    n_free = 0
    a_j = -1
    for a in range(nu):
        i = system.free[a]
        if i < 0:
            break
        unit[i] = 1.0 if i == j else 0.0
        if i == j:
            a_j = a
        n_free += 1
    kernels.cholesky_solve(scratch.M, unit, system.free, n_free, scratch.L, w)
    u_j = s[nq + j]
    scale = (1.0 + restitution) * u_j / w[a_j]
    for a in range(n_free):
        s[nq + system.free[a]] -= scale * w[a]
    s[nq + j] = -restitution * u_j   # exact, free of round-off


@jit
def impact(system, stops, s, k, side, t, hold, scratch, ds, forces):
    """Rod k (1-based) meets its lower (side −1) or upper (+1) stop at time t (s): the impact
    law, then a rebound or rest, logged. ``hold`` stops it at rest whatever its speed."""
    nq, nu = layout.sizes(system)
    j = layout.u_l(k)
    law, restitution, rest_speed = stops.law[0], stops.law[1], stops.law[2]
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
        impulse(system, s, j, e, scratch)
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
            release(system, stops, s, ds, forces)
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


def apply_impact(dynamics, free: list[int], q, u, k: int, restitution: float, law: str) -> np.ndarray:
    """u⁺ after rod k (1-based) hits a stop, in plain numpy (a reference for tests): MODEL.md's
    impulse law with M restricted to the free DOFs, or ``reflect``: l̇_k⁺ = −e l̇_k⁻ alone."""
    j = layout.u_l(k)
    u_after = np.array(u, dtype=float)
    if law == "reflect":
        u_after[j] = -restitution * u[j]
        return u_after
    M = dynamics.mass_matrix(q)[np.ix_(free, free)]
    e_k = np.zeros(len(free))
    e_k[free.index(j)] = 1.0
    w = np.linalg.solve(M, e_k)
    u_after[free] -= (1.0 + restitution) * (u[j] / w[free.index(j)]) * w
    u_after[j] = -restitution * u[j]
    return u_after
