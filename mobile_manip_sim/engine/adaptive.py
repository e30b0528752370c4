"""The compiled Dormand–Prince methods (`runge_kutta.py`) behind the small solver interface the
engine's adaptive loop steps (`t`, `y`, `status`, `step()`, `dense_output()`), the one SciPy's
solvers have, so that rk45/dop853 run compiled and radau/bdf through SciPy in the same loop.

One solve runs from its start until a discontinuity (an impact, a release, a command change):
the step is never capped at the sample interval, samples come from the dense output, and the
interpolant of a step is built only when a sample or an event needs it (3 right-hand sides for
dop853, none for rk45).
"""
from __future__ import annotations

import math

import numpy as np

from . import runge_kutta as rk
from .system import derivative


class CompiledSolver:
    def __init__(self, method: str, system, t0: float, y0: np.ndarray, rtol: float, atol: float,
                 first_step: float | None = None):
        self.method_id = rk.METHOD_IDS[method]
        self.system = system
        self.t, self.y = float(t0), np.array(y0, dtype=float)
        self.rtol, self.atol = float(rtol), float(atol)
        self.status = "running"
        self.work = rk.work_array(self.y.size)
        derivative(system, self.y, self.work[rk.WORK_F0])
        if first_step:
            self.h_abs = float(first_step)
        else:
            self.h_abs = rk.initial_step(self.method_id, system, self.y, self.work[rk.WORK_F0],
                                         math.inf, self.rtol, self.atol, math.inf,
                                         self.work[rk.WORK_Y1], self.work[rk.WORK_F1])
        self._step = None

    def step(self) -> str | None:
        h, self.h_abs = rk.accepted_step(self.method_id, self.system, self.y, self.t, self.h_abs,
                                         math.inf, self.rtol, self.atol, self.work)
        if h < 0.0:
            self.status = "failed"
            return f"the step fell below 10 ulps of t (h = {self.h_abs:.3g} s)"
        work = self.work
        # what the interpolant of this step needs, kept until the next step
        self._step = (self.y.copy(), work[rk.WORK_Y1].copy(), work[rk.WORK_F0].copy(),
                      work[rk.WORK_F1].copy(), work[rk.WORK_K:rk.WORK_K + rk.MAX_STAGES].copy(),
                      self.t, h)
        self.y[:] = work[rk.WORK_Y1]
        work[rk.WORK_F0] = work[rk.WORK_F1]   # FSAL: f(y₁) starts the next step
        self.t += h
        return None

    def dense_output(self):
        s0, s1, f0, f1, K, t0, h = self._step
        coeffs = np.zeros((rk.MAX_DENSE, s0.size))
        prepared = []

        def at(t: float) -> np.ndarray:
            if not prepared:
                rk.dense_prepare(self.method_id, self.system, s0, s1, f0, f1, h, K, coeffs)
                prepared.append(True)
            y = np.empty_like(s0)
            rk.dense_eval(self.method_id, coeffs, s0, h, (t - t0) / h, y)
            return y
        return at
