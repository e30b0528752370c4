"""The dense output of one step as a record the compiled event functions (`events.py`) can
evaluate — numba takes no Python closures, so an interpolant travels as data:

- a Dormand–Prince interpolant (`runge_kutta.dense_prepare`): kind `rk.RK45` or `rk.DOP853`;
- a power series in θ = h'/h, y(θ) = y₀ + Σ_j c_j θ^(j+1): kind POWER (SciPy's Radau and BDF
  interpolants, converted by `from_scipy`).

h' is the time (s) into the step, h the step's length (s); y₀ the state at its start.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np
from numpy.polynomial import polynomial

from ..dynamics.jit import jit
from . import runge_kutta as rk

POWER = -1   # kinds: rk.RK45 and rk.DOP853 (their method ids, `methods.IDS`), POWER (no method's)

Interpolant = namedtuple("Interpolant", [
    "kind",    # rk.RK45, rk.DOP853 or POWER
    "coeffs",  # (rows, len(y₀)): the kind's coefficients (runge_kutta.py; c_j for POWER)
    "h",       # length of the step, s
])


@jit
def interpolate(dense, s0, h, out):
    """The state h (s) into the step that starts at s0, into out."""
    theta = h / dense.h
    if dense.kind != POWER:
        rk.dense_eval(dense.kind, dense.coeffs, s0, dense.h, theta, out)
        return
    c = dense.coeffs
    for i in range(s0.shape[0]):
        y = 0.0
        for j in range(c.shape[0] - 1, -1, -1):   # Horner
            y = (y + c[j, i]) * theta
        out[i] = s0[i] + y


def from_scipy(dense_output) -> Interpolant:
    """The POWER interpolant of a SciPy Radau or BDF solver's last step (`solver.dense_output()`).

    Radau: y = y₀ + Q·(x, x², x³) with x = θ already (`RadauDenseOutput`). BDF: the Newton form
    y = D₀ + Σ_k D_k Π_{i<k} (t − (t₁ − i h_B)) / ((i + 1) h_B) (`BdfDenseOutput`, h_B its own
    step), expanded in θ with t = t₀ + θ h; its constant term is y₀ up to round-off and is
    dropped, so that the series starts exactly at the step's start state.
    """
    h = dense_output.t - dense_output.t_old
    if hasattr(dense_output, "Q"):
        return Interpolant(POWER, np.ascontiguousarray(dense_output.Q.T), h)
    order, D = dense_output.order, dense_output.D
    series = np.zeros((order + 1, D.shape[1]))
    factor = np.array([1.0])   # Π so far, as a polynomial in θ (lowest power first)
    for k in range(1, order + 1):
        shift = dense_output.t_shift[k - 1] - dense_output.t_old   # t₁ − (k−1) h_B − t₀
        factor = polynomial.polymul(factor, np.array([-shift, h]) / dense_output.denom[k - 1])
        series[:factor.size] += np.outer(factor, D[k])
    return Interpolant(POWER, np.ascontiguousarray(series[1:]), h)
