"""Embedded explicit Runge–Kutta pairs with error control and dense output, compiled.

Two methods, both with local extrapolation (the step is taken with the higher-order formula):

- ``rk45``: Dormand–Prince 5(4), 6 stages + the FSAL stage f(y₁) (Dormand & Prince 1980;
  Hairer–Nørsett–Wanner, *Solving ODEs I*, §II.5, Table 5.2). Dense output: Shampine's
  4th-order interpolant (Shampine 1986, the optimal c₆ choice), the one SciPy's RK45 uses.
- ``dop853``: Dormand–Prince 8(5,3), 12 stages + f(y₁) (Hairer–Nørsett–Wanner §II.5 and the
  Fortran code DOP853). The error estimate combines the 5th- and 3rd-order embedded formulas as
  Hairer's code does (`error_norm`). Dense output: the 7th-order interpolant, which costs 3 more
  stages per step that needs it (`dense_prepare`), or — where its estimated error is within
  the tolerance — a 6th-order continuous extension from the step's own stages, which costs none
  (`dense_from_stages`). f(y₁) enters neither error estimate, so a rejected step does not
  evaluate it (11 right-hand sides, as in dop853.f; an accepted one 12).

The right-hand side is `engine.system.derivative(system, s, ds)` of the state s = (q, u, e, W)
(n = n_q + n_u + 1 entries; autonomous: efforts are held between calls, so no t argument).
Time is in seconds, h is the step (s); tolerances are per component of s, in its own units.

Every function writes into arrays the caller owns and allocates nothing, so an engine loop can
run them back to back in compiled code. Shapes (n = len(s)):

- ``K``      (MAX_STAGES, n)  stage derivatives k_i = f(y₀ + h Σ_j a_ij k_j); row `n_stages`
                              is f(y₁); DOP853's rows 13..15 are the dense-output stages.
- ``err``    (2, n)           h·Σ e_i k_i for the main embedded estimate (row 0) and, for
                              DOP853, the 3rd-order one (row 1; unused by rk45).
- ``coeffs`` (MAX_DENSE, n)   the interpolant of the last step (`dense_prepare`).

Step-size control follows Hairer/SciPy: ‖err‖ < 1 accepts; h_new = h·min(MAX_FACTOR,
SAFETY·‖err‖^(−1/(p̂+1))) after an accepted step (not growing right after a rejection),
h·max(MIN_FACTOR, SAFETY·‖err‖^(−1/(p̂+1))) after a rejected one, p̂ the error estimator order.
"""
from __future__ import annotations

import math

import numpy as np

from ..dynamics.jit import jit
from .system import derivative
from .tableaus import (  # noqa: F401 (TABLEAUS: for Python callers)
    DOP853,
    DOP853_TABLEAU,
    RK45,
    RK45_TABLEAU,
    TABLEAUS,
)

SAFETY = 0.9        # of the asymptotically optimal step
MIN_FACTOR = 0.2    # the most a step can shrink after a rejection
MAX_FACTOR = 10.0   # the most a step can grow after an acceptance

MAX_STAGES = 16     # rows of K: DOP853's 12 stages, f(y₁) and 3 dense-output stages
MAX_DENSE = 7       # rows of the dense-output coefficients (DOP853's degree-7 interpolant)
# rows of the work array of a solve (`accepted_step`, `adaptive_stepping.Solve`): K, coeffs, f₀,
# f₁, y₁, err (2)
WORK_K, WORK_COEFFS, WORK_F0, WORK_F1, WORK_Y1, WORK_ERR = 0, 16, 23, 24, 25, 26
WORK_ROWS = 28



@jit
def tableau(method_id):
    """The Tableau of a method id (RK45 or DOP853)."""
    if method_id == RK45:
        return RK45_TABLEAU
    return DOP853_TABLEAU


def work_array(n: int) -> np.ndarray:
    """Scratch for `accepted_step` with states of n entries: (WORK_ROWS, n)."""
    return np.zeros((WORK_ROWS, n))


@jit
def _stage_state(s, h, a, n_terms, K, y):
    """y = s + h Σ_{j < n_terms} a_j k_j (the state at which a stage is evaluated)."""
    for i in range(s.shape[0]):
        total = 0.0
        for j in range(n_terms):
            if a[j] != 0.0:
                total += a[j] * K[j, i]
        y[i] = s[i] + h * total


@jit
def _stages(method_id, system, s, f0, h, out, K):
    """The stages k₁..k_{n_stages−1} of a step of length h from s (k₀ = f0) into K, and its
    end state y₁ into out (which doubles as the stage-state scratch: it must not alias s)."""
    tab = tableau(method_id)
    n_stages = tab.n_stages
    for i in range(s.shape[0]):
        K[0, i] = f0[i]
    for stage in range(1, n_stages):
        _stage_state(s, h, tab.A[stage], stage, K, out)
        derivative(system, out, K[stage])
    _stage_state(s, h, tab.B, n_stages, K, out)


@jit
def _end_derivative(method_id, system, out, f_out, K):
    """f(y₁) into f_out and K[n_stages]."""
    n_stages = tableau(method_id).n_stages
    derivative(system, out, f_out)
    for i in range(out.shape[0]):
        K[n_stages, i] = f_out[i]


@jit
def _error_estimates(method_id, h, K, err):
    """err[row] = h·Σ_j E[row, j] k_j."""
    tab = tableau(method_id)
    for row in range(2):
        for i in range(err.shape[1]):
            total = 0.0
            for j in range(tab.n_stages + 1):
                if tab.E[row, j] != 0.0:
                    total += tab.E[row, j] * K[j, i]
            err[row, i] = h * total


@jit
def error_needs_end_derivative(method_id):
    """Whether f(y₁) enters the error estimate (rk45: it is a stage; dop853: not)."""
    tab = tableau(method_id)
    return tab.E[0, tab.n_stages] != 0.0 or tab.E[1, tab.n_stages] != 0.0


@jit
def rk_step(method_id, system, s, f0, h, out, f_out, K, err):
    """One step of length h (s) from s, f0 = f(s): out = y₁, f_out = f(y₁).

    Writes the stage derivatives into K[:n_stages + 1] (row n_stages = f(y₁)) and the error
    estimates into err (see the module docstring). `out` doubles as the stage-state scratch, so
    it must not alias s. Returns the number of right-hand sides evaluated (n_stages: the stages
    after the first, plus f(y₁)).
    """
    _stages(method_id, system, s, f0, h, out, K)
    _end_derivative(method_id, system, out, f_out, K)
    _error_estimates(method_id, h, K, err)
    return tableau(method_id).n_stages


@jit
def error_norm(method_id, err, s, out, rtol, atol):
    """Hairer's scaled error norm of a step s → out, with sc_i = atol + rtol·max(|s_i|, |out_i|).

    rk45: the RMS of err[0]/sc. dop853 (as dop853.f): with e5 = Σ(err[0]/sc)², e3 = Σ(err[1]/sc)²,
    ‖err‖ = e5 / √(n (e5 + 0.01 e3)) — the 5th-order estimate, damped by the 3rd-order one
    where that is small. A step is accepted when the norm is below 1.
    """
    n = s.shape[0]
    e5 = 0.0
    e3 = 0.0
    for i in range(n):
        sc = atol + rtol * max(abs(s[i]), abs(out[i]))
        e5 += (err[0, i] / sc) ** 2
        e3 += (err[1, i] / sc) ** 2
    if method_id == RK45:
        return math.sqrt(e5 / n)
    if e5 == 0.0 and e3 == 0.0:
        return 0.0
    return e5 / math.sqrt(n * (e5 + 0.01 * e3))


@jit
def next_step(method_id, err_norm, h, previous_rejected):
    """The next step size after a step of size h with error norm err_norm (same sign as h).

    Accepted (err_norm < 1): h·min(MAX_FACTOR, SAFETY·err_norm^(−1/(p̂+1))), capped at h when
    this step was itself retried after a rejection (`previous_rejected`). Rejected:
    h·max(MIN_FACTOR, SAFETY·err_norm^(−1/(p̂+1))), the step to retry with.
    """
    exponent = -1.0 / (tableau(method_id).error_order + 1)
    if err_norm < 1.0:
        if err_norm == 0.0:
            factor = MAX_FACTOR
        else:
            factor = min(MAX_FACTOR, SAFETY * err_norm ** exponent)
        if previous_rejected:
            factor = min(1.0, factor)
    else:
        factor = SAFETY * err_norm ** exponent
        if not factor > MIN_FACTOR:   # also when err_norm is NaN
            factor = MIN_FACTOR
    return h * factor


@jit
def _scaled_rms(x, s, rtol, atol):
    """‖x/sc‖ (RMS) with sc_i = atol + rtol|s_i|."""
    total = 0.0
    for i in range(x.shape[0]):
        total += (x[i] / (atol + rtol * abs(s[i]))) ** 2
    return math.sqrt(total / x.shape[0])


@jit
def initial_step(method_id, system, s, f0, span, rtol, atol, max_step, y_scratch, f_scratch):
    """A starting step (s), Hairer's heuristic (HNW I §II.4; SciPy's select_initial_step).

    With sc = atol + rtol|s|, d0 = ‖s/sc‖, d1 = ‖f0/sc‖ (RMS norms): h0 = 0.01 d0/d1 (1e-6 if
    either is below 1e-5); one explicit Euler step gives d2 = ‖(f(s + h0 f0) − f0)/sc‖/h0, and
    h1 = (0.01/max(d1, d2))^(1/(p̂+1)). Returns min(100 h0, h1, span, max_step) for a run over
    `span` seconds. Costs one right-hand side, evaluated at y_scratch into f_scratch.
    """
    n = s.shape[0]
    if span == 0.0:
        return 0.0
    d0 = _scaled_rms(s, s, rtol, atol)
    d1 = _scaled_rms(f0, s, rtol, atol)
    if d0 < 1e-5 or d1 < 1e-5:
        h0 = 1e-6
    else:
        h0 = 0.01 * d0 / d1
    h0 = min(h0, span)
    for i in range(n):
        y_scratch[i] = s[i] + h0 * f0[i]
    derivative(system, y_scratch, f_scratch)
    for i in range(n):
        f_scratch[i] -= f0[i]
    d2 = _scaled_rms(f_scratch, s, rtol, atol) / h0
    if d1 <= 1e-15 and d2 <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max(d1, d2)) ** (1.0 / (tableau(method_id).error_order + 1))
    return min(100.0 * h0, h1, span, max_step)


@jit
def dense_prepare(method_id, system, s, out, f0, f1, h, K, coeffs):
    """The interpolant of the step s → out of length h, from its stages K (after `rk_step`).

    f0 = f(s) and f1 = f(out). rk45 writes coeffs[:4] = Q with Q_j = Σ_i P_ij k_i (state/s);
    dop853 evaluates its 3 dense-output stages into K[13:16] and writes coeffs[:7] = the
    F₀..F₆ of dop853.f (in state units: F₀ = Δy, F₁ = h f0 − Δy, F₂ = 2Δy − h(f0 + f1),
    F₃₊ᵣ = h Σ_i d_ri k_i). coeffs[0] serves as stage-state scratch first. Returns the number
    of right-hand sides evaluated (0 or 3).
    """
    tab = tableau(method_id)
    n = s.shape[0]
    if method_id == RK45:
        for j in range(4):
            for i in range(n):
                total = 0.0
                for k in range(tab.n_stages + 1):
                    total += K[k, i] * tab.P[k, j]
                coeffs[j, i] = total
        return 0
    for stage in range(tab.n_stages + 1, tab.n_extended):
        _stage_state(s, h, tab.A[stage], stage, K, coeffs[0])
        derivative(system, coeffs[0], K[stage])
    for i in range(n):
        dy = out[i] - s[i]
        coeffs[0, i] = dy
        coeffs[1, i] = h * f0[i] - dy
        coeffs[2, i] = 2.0 * dy - h * (f1[i] + f0[i])
    for r in range(4):
        for i in range(n):
            total = 0.0
            for k in range(tab.n_extended):
                if tab.P[r, k] != 0.0:
                    total += tab.P[r, k] * K[k, i]
            coeffs[3 + r, i] = h * total
    return tab.n_extended - tab.n_stages - 1


@jit
def dense_from_stages(method_id, s, out, h, K, coeffs, rtol, atol):
    """dop853: the interpolant of the step s → out of length h from its 13 stages alone (no
    right-hand side), when its estimated error is within the tolerance. Returns True when
    coeffs[:7] holds it (the F₀..F₆ that `dense_eval` reads), False (coeffs untouched) when the
    step needs `dense_prepare`'s 7th-order interpolant; always False for rk45, whose
    interpolant costs nothing anyway.

    The continuous extension is of order 6 (`continuous_extension.py`: one order below the
    7th-order one, whose 3 extra stages it saves). Its error is estimated at θ = 1/2 by its
    difference to the 5th-order extension of the same stages (tab.F_check), in `error_norm`'s
    scaled RMS norm, which must not exceed 1: as the step's error is estimated by lower-order
    formulas, the estimate is that of the lower-order extension, so it bounds the 6th-order one's
    (measured: 1.2-2× its error on the paper robot). The estimate shrinks with h like h⁶
    where the step's own error shrinks like h⁸, so loose tolerances (long steps) pass and
    tight ones fall back.
    """
    if method_id == RK45:
        return False
    tab = tableau(method_id)
    n = s.shape[0]
    total = 0.0
    for i in range(n):
        estimate = 0.0
        for k in range(tab.n_stages + 1):
            estimate += tab.F_check[k] * K[k, i]
        sc = atol + rtol * max(abs(s[i]), abs(out[i]))
        total += (h * estimate / sc) ** 2
    if not math.sqrt(total / n) <= 1.0:   # also when NaN
        return False
    for r in range(7):
        for i in range(n):
            value = 0.0
            for k in range(tab.n_stages + 1):
                value += tab.F[r, k] * K[k, i]
            coeffs[r, i] = h * value
    return True


@jit
def dense_eval(method_id, coeffs, s, h, theta, y_out):
    """The state at t₀ + θh, θ ∈ [0, 1], of the step prepared by `dense_prepare` from s.

    rk45: y = s + h Σ_{j<4} θ^(j+1) Q_j. dop853: y = s + θ(F₀ + (1−θ)(F₁ + θ(F₂ + (1−θ)(F₃
    + θ(F₄ + (1−θ)(F₅ + θF₆)))))) (h is already inside the F's).
    """
    n = s.shape[0]
    if method_id == RK45:
        for i in range(n):
            y_out[i] = 0.0
        power = 1.0
        for j in range(4):
            power *= theta
            for i in range(n):
                y_out[i] += coeffs[j, i] * power
        for i in range(n):
            y_out[i] = h * y_out[i] + s[i]
        return
    for i in range(n):
        y = 0.0
        for r in range(6, -1, -1):
            y += coeffs[r, i]
            y *= theta if (6 - r) % 2 == 0 else 1.0 - theta
        y_out[i] = y + s[i]


@jit
def step_to(t, t_end, h):
    """h, moved by ulps, so that t + h rounds to t_end exactly (t_end − t rounded may miss it by
    one; a step that ended an ulp short of an update instant would leave a step of 1e-18 s)."""
    for _ in range(4):
        if t + h < t_end:
            h = np.nextafter(h, np.inf)
        elif t + h > t_end:
            h = np.nextafter(h, -np.inf)
        else:
            break
    return h


@jit
def accepted_step(method_id, system, s, t, h_abs, t_bound, rtol, atol, work):
    """Steps from (t, s) with f(s) in work[WORK_F0], shrinking h until one is accepted: the new
    state and its f in work[WORK_Y1], work[WORK_F1] (f(y₁) evaluated last), the stages in
    work[WORK_K…]. Returns (h
    taken, next h to try); h taken = −1 when the step fell below 10 ulps of t (s unchanged)."""
    K = work[WORK_K:WORK_K + MAX_STAGES]
    f0, f1, y1 = work[WORK_F0], work[WORK_F1], work[WORK_Y1]
    err = work[WORK_ERR:WORK_ERR + 2]
    min_step = 10.0 * abs(np.nextafter(t, np.inf) - t)
    retried = False
    while True:
        if not h_abs >= min_step:   # also a NaN step (from a NaN error norm): fails, never loops
            return -1.0, h_abs
        t_new = min(t + h_abs, t_bound)
        if t + 1.01 * h_abs >= t_bound:   # (never with t_bound = inf)
            t_new = t_bound   # not a remainder under 1 % of a step left for a step of its own
        h = t_new - t
        if t_new == t_bound:   # cut at the bound: an h whose end t + h is the bound exactly
            h = step_to(t, t_bound, h)
        # f(y₁) only once it is needed: a rejected dop853 step costs 11 right-hand sides, not 12
        end_first = error_needs_end_derivative(method_id)
        _stages(method_id, system, s, f0, h, y1, K)
        if end_first:
            _end_derivative(method_id, system, y1, f1, K)
        _error_estimates(method_id, h, K, err)
        norm = error_norm(method_id, err, s, y1, rtol, atol)
        h_next = next_step(method_id, norm, abs(h), retried)
        if norm < 1.0:   # a NaN norm (an overflow in a stage) rejects the step
            if not end_first:
                _end_derivative(method_id, system, y1, f1, K)
            return h, h_next
        h_abs = h_next
        retried = True
