"""Progress limits of the SciPy-stepped methods (radau, bdf).

An implicit solver facing a solution it cannot follow (a wheel command of 1e30 right after a
reset, a stiff scene at the tightest tolerance) need not fail: it shrinks its step towards the
spacing of floating-point numbers and crawls on, 1e-18 s at a time, for ever. Two limits turn
that into an error (README, "Bad input"):

- the floor: FLOOR_STEPS accepted steps in a row shorter than STEP_FLOOR × max(1 s, t). One short
  step is no crawl: a solver restarted at a discontinuity may begin below the floor, and its step
  grows up to tenfold per step.
- the budget: every BUDGET_STEPS steps must advance simulated time by BUDGET_SPAN at least, an
  average step of 2 µs (the hardest bundled scene, radau at rtol 1e-14, takes under 2000 steps
  per 10 ms).

Every SciPy step returns to Python, so signals, pause and reset act between steps.
"""
from __future__ import annotations

STEP_FLOOR = 1e-12      # of max(1 s, t)
FLOOR_STEPS = 50
BUDGET_STEPS = 5_000
BUDGET_SPAN = 0.01      # s of simulated time per BUDGET_STEPS steps


class StepWatch:
    """Counts one run's accepted steps (a new watch after each reset)."""

    def __init__(self):
        self._t_mark = None    # start of the budget's current window
        self._steps = 0        # steps in that window
        self._short = 0        # steps in a row below the floor

    def problem(self, t_before: float, h: float) -> str | None:
        """After an accepted step h (s) from t_before (s): why the solver is crawling, or None."""
        if self._t_mark is None:
            self._t_mark = t_before
        self._steps += 1
        floor = STEP_FLOOR * max(1.0, abs(t_before))
        self._short = self._short + 1 if h < floor else 0
        if self._short >= FLOOR_STEPS:
            return (f"its step stayed below the floor of {floor:.0e} s for {FLOOR_STEPS} steps "
                    f"in a row (the last {h:.3g} s)")
        if self._steps >= BUDGET_STEPS:
            covered = t_before + h - self._t_mark
            if covered < BUDGET_SPAN:
                return (f"{BUDGET_STEPS} steps advanced it only {covered:.3g} s, beyond the step "
                        f"budget of {BUDGET_STEPS} steps per {BUDGET_SPAN:g} s")
            self._t_mark, self._steps = t_before + h, 0
        return None
