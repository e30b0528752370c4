"""radau and bdf: SciPy's solver stepped from Python, one step at a time, into the adaptive
core's step in hand — everything else is the core's (`reach`, `locate_event`: samples, events,
the Zeno guard, restarts), on the solver's interpolant as a power series (`dense.from_scipy`).
The core is the compiled C++ stepper (`core_stepping.py`; SciPy's right-hand side is its counted,
watched `derivative`), or the numba kernels on `adaptive_stepping.Solve` (`NumbaSteps`, the
reference while both exist). A mixin of `Simulation`, whose state it steps."""
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


class NumbaSteps:
    """The calls of the compiled stepper that SciPy's steps use (`core.Stepper`), made by the
    numba kernels on a simulation's `adaptive_stepping.Solve`; leaves with numba."""

    def __init__(self, sim):
        self.sim, self.solve = sim, sim._solve

    def step_in_hand(self) -> tuple[float, float]:
        return adaptive_stepping.step_in_hand(self.solve)

    def next_step(self) -> float:
        return adaptive_stepping.next_step(self.solve)

    def drop_step(self) -> None:
        adaptive_stepping.drop_step(self.solve)

    def begin_step(self, t0: float, y0) -> None:
        adaptive_stepping.begin_step(self.solve, t0, y0)

    def hand_in_step(self, h: float, y1, series) -> None:
        adaptive_stepping.hand_in_step(self.solve, h, y1, series)

    def step_end_derivative(self) -> None:
        solve = self.solve
        adaptive_stepping.set_step_end_derivative(
            solve, self.sim.system.derivative(adaptive_stepping.step_end(solve)))

    def locate_event(self) -> None:
        self.sim._locate_event(*self.sim._core_args)

    def reach(self, s, clock, t_end: float) -> bool:
        return self.sim._reach(*self.sim._core_args, s, clock, t_end)

    def watch_step(self, t_before: float, h: float) -> bool:
        return self.sim._watch_step(self.solve.watch, t_before, h)

    def derivative(self, s):
        return self.sim.system.derivative(s)


class ScipySteps:
    """A SciPy solver kept across samples until a discontinuity (a new solve at (t, s))."""

    def _scipy_core(self):
        """The core around SciPy's steps: the compiled stepper, or the numba kernels."""
        return self._stepper if self._stepper is not None else NumbaSteps(self)

    def _advance_scipy(self, t_end: float) -> None:
        """Step SciPy's solver from Python; everything else is the core's (`reach`,
        `locate_event`: samples, events, the Zeno guard, restarts), on the solver's interpolant
        as a power series (`dense.from_scipy`)."""
        core = self._scipy_core()
        while not core.reach(self.s, self._clock, t_end):
            self._collect_impacts()
            if self.stops.failed[0]:
                self._contact_failed()
            self._take_scipy_step(core)
        self._collect_impacts()

    def _take_scipy_step(self, core) -> None:
        """One step of the SciPy solver into the core's step in hand."""
        in_hand = core.step_in_hand()[1] != 0.0
        t_before = self._solver.t if in_hand else self.t
        # its evaluations sample them anew
        self.system.data.holding[HOLDING_LEAST_MARGIN] = math.inf
        try:   # overflows are ours to report in one line, not numpy's warnings on stderr
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                solver, message = self._scipy_step(core, t_before)
        except (ValueError, np.linalg.LinAlgError) as error:   # lu_factor of infinities
            core.drop_step()
            self._cannot_follow(t_before, f"its linear algebra failed ({error})")
        self._check_scipy_step(core, solver, t_before, message)
        self._clock[stepping.CLOCK_STEPS] += 1
        if not np.all(np.isfinite(solver.y)):
            self._fail(solver.y)
        series = dense.from_scipy(solver.dense_output()).coeffs
        core.hand_in_step(solver.t - t_before, solver.y, series)
        if self.resting.any():   # the release check needs f(y₁) evaluated (and watched)
            core.step_end_derivative()
        core.locate_event()

    def _scipy_step(self, core, t_before: float):
        """The SciPy solver's next step (a new solver for a new solve): (solver, its message)."""
        if core.step_in_hand()[1] == 0.0:   # a new solve at (t, s)
            derivative = core.derivative
            settings = self.settings
            bound = self.next_update   # no step across an update of sampled controllers
            first = core.next_step() or None
            self._solver = scipy_solver(settings.method)(
                lambda _t, y: derivative(y), self.t, self.s.copy(), bound,
                rtol=max(settings.rtol, SCIPY_MIN_RTOL), atol=settings.atol,
                first_step=None if first is None else min(first, bound - self.t))
        solver = self._solver
        core.begin_step(t_before, solver.y)
        return solver, solver.step()

    def _check_scipy_step(self, core, solver, t_before: float, message) -> None:
        """radau/bdf: a failed step (below ten spacings of t) or a crawl (`step_watch`) is one
        StepLimitError naming the tolerances, instead of steps of 1e-18 s for ever."""
        if solver.status == "failed":
            self._cannot_follow(t_before, message)
        h = solver.t - t_before
        if core.watch_step(t_before, h):
            self._cannot_follow(t_before, step_watch.describe(self._solve.watch, t_before, h))
