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

The compiled core counts (core/include/mms/adaptive_stepping.hpp `watch_step`, whose limits these
are), for rk45 and dop853 and for the steps SciPy's radau and bdf hand in alike, on the run's own
`watch`, so every adaptive method crawls into the same one-line error (a 1e30 command after a
reset had dop853 taking steps of 1e-19 s for ever); this module makes the record and says which
limit was crossed.
"""
from __future__ import annotations

import math

import numpy as np

from ..core import vocabulary

STEP_FLOOR = vocabulary["STEP_FLOOR"]       # of max(1 s, t)
FLOOR_STEPS = vocabulary["FLOOR_STEPS"]
BUDGET_STEPS = vocabulary["BUDGET_STEPS"]
BUDGET_SPAN = vocabulary["BUDGET_SPAN"]     # s of simulated time per BUDGET_STEPS steps

# watch[...] entries: steps in a row below the floor; start (s) and steps of the budget's window
WATCH_SHORT, WATCH_MARK, WATCH_STEPS = (vocabulary[name] for name in (
    "WATCH_SHORT", "WATCH_MARK", "WATCH_STEPS"))


def make_watch() -> np.ndarray:
    """One run's count (a new one, or `clear`, after each reset)."""
    watch = np.zeros(3)
    clear(watch)
    return watch


def clear(watch: np.ndarray) -> None:
    watch[:] = (0.0, math.nan, 0.0)


def describe(watch: np.ndarray, t_before: float, h: float) -> str:
    """Which limit the core's watch found crossed at the step h (s) from t_before (s), in words."""
    if watch[WATCH_SHORT] >= FLOOR_STEPS:
        floor = STEP_FLOOR * max(1.0, abs(t_before))
        return (f"its step stayed below the floor of {floor:.0e} s for {FLOOR_STEPS} steps "
                f"in a row (the last {h:.3g} s)")
    covered = t_before + h - watch[WATCH_MARK]
    return (f"{BUDGET_STEPS} steps advanced it only {covered:.3g} s, beyond the step "
            f"budget of {BUDGET_STEPS} steps per {BUDGET_SPAN:g} s")
