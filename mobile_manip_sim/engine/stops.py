"""Stroke end stops: finding a crossing inside a step, the impact law, resting and leaving.

A rod k (1-based) has ``l_k = s[4 + 2k]`` and ``l̇_k = s[n_q + 2k + 1]`` in the state vector.

- Detection: after every step, each watched rod's path over the step is the cubic Hermite
  interpolant of (l, l̇) at both ends; a crossing is flagged when the end value *or* the
  interpolant's extremum leaves the stroke — so a fast rod that crosses and comes back within
  one step is not missed (SciPy's sign-change detection misses it, scipy #9228).
- Location (`locate`): the root in h' of l(step(s, h')) − stop, by the Illinois method on the
  real integrator step, so the overshoot is at round-off, not at the interpolant's error. It is
  bracketed by samples of the step that include the interpolant's turning points
  (`hermite_turns`), where a rod that only grazes past its stop is out of the stroke.
- Impact (`impact`): MODEL.md's generalized impulse along e_k, or the paper's `reflect` law.
- Resting: a rod whose rebound speed is below ``rest_speed`` is held at the stop (its l̇ degree
  of freedom is locked, not stiffly pushed back), and so is a rod whose rebounds are too small
  to resolve (the Zeno guards in `simulation.py`). It leaves when the stop would have to pull to
  hold it (`release_wanted`: the constraint force changes sign), checked after every step and
  whenever the command changes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..dynamics.jit import jit
from . import layout
from .system import CROSSING_CHECKS, derivative, holding_forces


@jit
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


@jit
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


@jit
def crossing_in_step(s0, s1, h, system, watched, stroke, scratch_a, scratch_b):
    """True when a watched rod leaves its stroke during the step s0 → s1 (see module doc)."""
    nq, _ = layout.sizes(system)
    system.counters[CROSSING_CHECKS] += 1
    for k in range(1, watched.shape[0] + 1):
        if not watched[k - 1]:
            continue
        lo, hi = stroke[k - 1, 0], stroke[k - 1, 1]
        i_l, i_ld = layout.l(k), layout.ld(nq, k)
        if s1[i_l] < lo or s1[i_l] > hi:
            return True
        low, high = hermite_extrema(s0[i_l], s0[i_ld], s1[i_l], s1[i_ld], h)
        if low < lo or high > hi:
            return True
    return False


@jit
def release_wanted(system, s, resting, ds, forces):
    """True when a rod resting at a stop would need the stop to pull to stay there."""
    derivative(system, s, ds)
    holding_forces(system, s, ds, forces)
    for k in range(1, resting.shape[0] + 1):
        side = resting[k - 1]
        # The stop pushes outward only: +l at the lower stop (side −1), −l at the upper (+1).
        if side != 0 and side * forces[layout.u_l(k)] > 0.0:
            return True
    return False


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


def apply_impact(dynamics, free: list[int], q, u, k: int, restitution: float, law: str) -> np.ndarray:
    """u⁺ after rod k (1-based) hits a stop: MODEL.md's impulse law, or ``reflect``.

    impulse: u⁺ = u⁻ − (1 + e) (e_kᵀ u⁻ / (e_kᵀ M⁻¹ e_k)) M⁻¹ e_k, with M restricted to the
    free (unlocked) degrees of freedom; reflect (the paper): l̇_k⁺ = −e l̇_k⁻, nothing else.
    """
    j = 2 * k + 1
    u_after = np.array(u, dtype=float)
    if law == "reflect":
        u_after[j] = -restitution * u[j]
        return u_after
    M = dynamics.mass_matrix(q)[np.ix_(free, free)]
    e_k = np.zeros(len(free))
    e_k[free.index(j)] = 1.0
    w = np.linalg.solve(M, e_k)
    u_after[free] -= (1.0 + restitution) * (u[j] / w[free.index(j)]) * w
    u_after[j] = -restitution * u[j]  # exact, free of round-off
    return u_after


def locate(g, a: float, b: float, tol: float = 1e-13) -> float:
    """The root of g in (a, b] with g(a) ≥ 0 > g(b), by the Illinois method.

    Returns the h' with g(h') ≤ 0 closest to the root (the state just reached the stop).
    """
    h = b - a
    ga, gb = g(a), g(b)
    g_root = gb  # g at b itself: the Illinois steps halve gb, which must not pass for convergence
    side = 0
    for _ in range(200):
        # With g(a) = 0 (a rod starting exactly at its stop, as after every impact) the secant
        # lands on a itself, or a round-off above it where g may read ≤ 0: a false root at
        # h' ≈ 0. Bisect until g(a) > 0.
        c = b - gb * (b - a) / (gb - ga) if gb != ga and ga != 0.0 else 0.5 * (a + b)
        if not a < c < b:
            c = 0.5 * (a + b)
        gc = g(c)
        if gc <= 0.0:
            b, gb, g_root = c, gc, gc
            if side == -1:
                ga *= 0.5
            side = -1
        else:
            a, ga = c, gc
            if side == 1:
                gb *= 0.5
            side = 1
        if -tol <= g_root <= 0.0 or b - a <= 1e-15 * h:
            break
    return b
