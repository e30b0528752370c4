"""radau and bdf: SciPy's solver stepped from Python, one step at a time, into the compiled
adaptive core's step in hand — everything else is the core's (`adaptive_stepping.reach`,
`locate_event`: samples, events, the Zeno guard, restarts), on the solver's interpolant as a
power series (`dense.from_scipy`). A mixin of `Simulation`, whose state it steps."""
from __future__ import annotations

import math

import numpy as np

from ..scene.methods import METHODS
from . import adaptive_stepping, dense, step_watch, stepping
from .system import HOLDING_LEAST_MARGIN

SCIPY_MIN_RTOL = 100 * np.finfo(float).eps   # SciPy's own floor; passed as is, it warns on stderr


def scipy_solver(method: str):
    """SciPy's solver class for an adaptive method, imported only when one is used (~56 MB)."""
    from scipy import integrate
    return getattr(integrate, METHODS[method].stepper.split(":")[1])


class ScipySteps:
    """A SciPy solver kept across samples until a discontinuity (a new solve at (t, s))."""

    def _advance_scipy(self, t_end: float) -> None:
        """Step SciPy's solver from Python; everything else is the compiled adaptive core's
        (`adaptive_stepping.reach`, `locate_event`: samples, events, the Zeno guard, restarts),
        on the solver's interpolant as a power series (`dense.from_scipy`)."""
        while not self._reach(*self._core_args, self.s, self._clock, t_end):
            self._collect_impacts()
            if self.stops.failed[0]:
                self._contact_failed()
            self._take_scipy_step()
        self._collect_impacts()

    def _take_scipy_step(self) -> None:
        """One step of the SciPy solver into the adaptive core's step in hand (`Solve`)."""
        solve = self._solve
        in_hand = adaptive_stepping.step_in_hand(solve)[1] != 0.0
        t_before = self._solver.t if in_hand else self.t
        # its evaluations sample them anew
        self.system.data.holding[HOLDING_LEAST_MARGIN] = math.inf
        try:   # overflows are ours to report in one line, not numpy's warnings on stderr
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                solver, message = self._scipy_step(t_before)
        except (ValueError, np.linalg.LinAlgError) as error:   # lu_factor of infinities
            adaptive_stepping.drop_step(solve)
            self._cannot_follow(t_before, f"its linear algebra failed ({error})")
        self._check_scipy_step(solver, t_before, message)
        self._clock[stepping.CLOCK_STEPS] += 1
        if not np.all(np.isfinite(solver.y)):
            self._fail(solver.y)
        series = dense.from_scipy(solver.dense_output()).coeffs
        adaptive_stepping.hand_in_step(solve, solver.t - t_before, solver.y, series)
        if self.resting.any():   # the release check needs f(y₁) evaluated (and watched)
            adaptive_stepping.set_step_end_derivative(
                solve, self.system.derivative(adaptive_stepping.step_end(solve)))
        self._locate_event(*self._core_args)

    def _scipy_step(self, t_before: float):
        """The SciPy solver's next step (a new solver for a new solve): (solver, its message)."""
        if adaptive_stepping.step_in_hand(self._solve)[1] == 0.0:   # a new solve at (t, s)
            derivative = self.system.derivative
            settings = self.settings
            bound = self.next_update   # no step across an update of sampled controllers
            first = adaptive_stepping.next_step(self._solve) or None
            self._solver = scipy_solver(settings.method)(
                lambda _t, y: derivative(y), self.t, self.s.copy(), bound,
                rtol=max(settings.rtol, SCIPY_MIN_RTOL), atol=settings.atol,
                first_step=None if first is None else min(first, bound - self.t))
        solver = self._solver
        adaptive_stepping.begin_step(self._solve, t_before, solver.y)
        return solver, solver.step()

    def _check_scipy_step(self, solver, t_before: float, message) -> None:
        """radau/bdf: a failed step (below ten spacings of t) or a crawl (`step_watch`) is one
        StepLimitError naming the tolerances, instead of steps of 1e-18 s for ever."""
        if solver.status == "failed":
            self._cannot_follow(t_before, message)
        h = solver.t - t_before
        if self._watch_step(self._solve.watch, t_before, h):
            self._cannot_follow(t_before, step_watch.describe(self._solve.watch, t_before, h))
