"""Progress limits of the adaptive methods.

An implicit solver facing a solution it cannot follow (a wheel command of 1e30 right after a
reset, a stiff scene at the tightest tolerance) need not fail: it shrinks its step towards the
spacing of floating-point numbers and crawls on, 1e-18 s at a time, for ever. Two limits turn
that into an error (docs/errors.md, "Bad input"):

- the floor: FLOOR_STEPS accepted steps in a row shorter than STEP_FLOOR × max(1 s, t). One short
  step is no crawl: a solver restarted at a discontinuity may begin below the floor, and its step
  grows up to tenfold per step.
- the budget: every BUDGET_STEPS steps must advance simulated time by BUDGET_SPAN at least, an
  average step of 2 µs (the hardest bundled scene, radau at rtol 1e-14, takes under 2000 steps
  per 10 ms).

The compiled rk45/dop853 core (`adaptive_stepping.take_step`) and the SciPy-stepped radau/bdf
(`Simulation._take_scipy_step`) count with the same `watch` on the same record, so every adaptive
method crawls into the same one-line error (a 1e30 command after a reset had dop853 taking steps
of 1e-19 s for ever).
"""
from __future__ import annotations

import math

import numpy as np

from ..dynamics.jit import jit

STEP_FLOOR = 1e-12      # of max(1 s, t)
FLOOR_STEPS = 50
BUDGET_STEPS = 5_000
BUDGET_SPAN = 0.01      # s of simulated time per BUDGET_STEPS steps

# watch[...] entries: steps in a row below the floor; start (s) and steps of the budget's window
WATCH_SHORT, WATCH_MARK, WATCH_STEPS = range(3)


def make_watch() -> np.ndarray:
    """One run's count (a new one, or `clear`, after each reset)."""
    watch = np.zeros(3)
    clear(watch)
    return watch


def clear(watch: np.ndarray) -> None:
    watch[:] = (0.0, math.nan, 0.0)


@jit
def watch_step(watch, t_before, h):
    """After an accepted step h (s) from t_before (s): True when the solver is crawling."""
    if math.isnan(watch[WATCH_MARK]):
        watch[WATCH_MARK] = t_before
    watch[WATCH_STEPS] += 1.0
    short = h < STEP_FLOOR * max(1.0, abs(t_before))
    watch[WATCH_SHORT] = watch[WATCH_SHORT] + 1.0 if short else 0.0
    if watch[WATCH_SHORT] >= FLOOR_STEPS:
        return True
    if watch[WATCH_STEPS] >= BUDGET_STEPS:
        if t_before + h - watch[WATCH_MARK] < BUDGET_SPAN:
            return True
        watch[WATCH_MARK], watch[WATCH_STEPS] = t_before + h, 0.0
    return False


def describe(watch: np.ndarray, t_before: float, h: float) -> str:
    """Which limit `watch_step` found crossed at the step h (s) from t_before (s), in words."""
    if watch[WATCH_SHORT] >= FLOOR_STEPS:
        floor = STEP_FLOOR * max(1.0, abs(t_before))
        return (f"its step stayed below the floor of {floor:.0e} s for {FLOOR_STEPS} steps "
                f"in a row (the last {h:.3g} s)")
    covered = t_before + h - watch[WATCH_MARK]
    return (f"{BUDGET_STEPS} steps advanced it only {covered:.3g} s, beyond the step "
            f"budget of {BUDGET_STEPS} steps per {BUDGET_SPAN:g} s")
