"""radau and bdf: SciPy's solver stepped from Python, one step at a time, into the adaptive
core's step in hand — everything else is the core's (`reach`, `locate_event`: samples, events,
the Zeno guard, restarts), on the solver's interpolant as a power series (`power_series`).
The core is the compiled C++ stepper (`core_stepping.py`; SciPy's right-hand side is its counted,
watched `derivative`). A mixin of `Simulation`, whose state it steps."""
from __future__ import annotations

import math

import numpy as np

from ..scene.methods import METHODS
from . import step_watch, stepping
from .system import HOLDING_LEAST_MARGIN

SCIPY_MIN_RTOL = 100 * np.finfo(float).eps   # SciPy's own floor; passed as is, it warns on stderr


def scipy_solver(method: str):
    """SciPy's solver class for an adaptive method, imported only when one is used (~56 MB)."""
    from scipy import integrate
    return getattr(integrate, METHODS[method].stepper.split(":")[1])


def power_series(dense_output) -> np.ndarray:
    """A SciPy Radau or BDF solver's last step (`solver.dense_output()`) as the power series the
    core evaluates: rows c_j of y(θ) = y₀ + Σ_j c_j θ^(j+1), θ = (t − t₀)/h in the step.

    Radau: y = y₀ + Q·(x, x², x³) with x = θ already (`RadauDenseOutput`). BDF: the Newton form
    y = D₀ + Σ_k D_k Π_{i<k} (t − (t₁ − i h_B)) / ((i + 1) h_B) (`BdfDenseOutput`, h_B its own
    step), expanded in θ with t = t₀ + θ h; its constant term is y₀ up to round-off and is
    dropped, so that the series starts exactly at the step's start state.
    """
    from numpy.polynomial import polynomial  # here: bdf's alone (0.1 s of every start)
    h = dense_output.t - dense_output.t_old
    if hasattr(dense_output, "Q"):
        return np.ascontiguousarray(dense_output.Q.T)
    order, D = dense_output.order, dense_output.D
    series = np.zeros((order + 1, D.shape[1]))
    factor = np.array([1.0])   # Π so far, as a polynomial in θ (lowest power first)
    for k in range(1, order + 1):
        shift = dense_output.t_shift[k - 1] - dense_output.t_old   # t₁ − (k−1) h_B − t₀
        factor = polynomial.polymul(factor, np.array([-shift, h]) / dense_output.denom[k - 1])
        series[:factor.size] += np.outer(factor, D[k])
    return np.ascontiguousarray(series[1:])


class ScipySteps:
    """A SciPy solver kept across samples until a discontinuity (a new solve at (t, s))."""

    def _advance_scipy(self, t_end: float) -> None:
        """Step SciPy's solver from Python; everything else is the core's (`reach`,
        `locate_event`: samples, events, the Zeno guard, restarts), on the solver's interpolant
        as a power series (`power_series`)."""
        core = self._stepper
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
        series = power_series(solver.dense_output())
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
