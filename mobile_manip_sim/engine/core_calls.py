"""The engine's calls between steps — which rods rest (the locks), whether a stop pulls, a
release, a restart of an adaptive solve, the step in hand — made by whichever core runs the
simulation's method: the compiled C++ stepper (`core_stepping.py`), or the numba kernels and
records where it does not run yet (an arm controller; SciPy's radau and bdf). A mixin of
`Simulation`, as `base_commands.py` and `arm_commands.py` are; the numba branches leave with
numba.
"""
from __future__ import annotations

from ..scene.methods import METHODS
from . import adaptive_stepping, core_stepping
from .events import holding_margin
from .stops import release, relock


class CoreCalls:
    def _compiled_stepper(self):
        """The compiled C++ stepper of this simulation's own records (`core_stepping.py`), or None
        where the numba kernels or SciPy run it (radau, bdf; an arm controller). Made at every
        reset: a batch lane, a copy of its template's records, gets its own."""
        method = METHODS[self.settings.method]
        if (core_stepping.CORE != "cpp" or self._core is None or self.arm_controller.active):
            return None
        return core_stepping.compiled_stepper(self.dynamics, method.name, self.system, self.stops,
                                              self._scratch, self._solve)

    def _step_in_hand(self) -> tuple[float, float]:
        """An adaptive run's step in hand: (start, length) in s; length 0: none."""
        if self._stepper is not None:
            return self._stepper.step_in_hand()
        return adaptive_stepping.step_in_hand(self._solve)

    def _restart(self) -> None:
        """The right-hand side changes here: adaptive solves end at the current (t, s)."""
        if self._stepper is not None:
            self._stepper.restart()
        elif self._solve is not None:
            adaptive_stepping.restart(self._solve)

    # --- the stops' kernels: the compiled stepper's where it runs the method -------------------
    def _relock(self) -> None:
        """The locks from the stops (the scene's locked DOFs, the resting rods)."""
        if self._stepper is not None:
            self._stepper.relock()
        else:
            relock(self.system.data, self.stops)

    def _holding_margin(self) -> float:
        """The least force a resting rod's stop pushes with now (N; +inf: none rests)."""
        if self._stepper is not None:
            return self._stepper.holding_margin(self.s)
        scr = self._scratch
        return holding_margin(self.system.data, self.s, self.resting, scr.stages[3], scr.forces)

    def _release(self) -> None:
        """Free, now, the resting rods their stops would have to pull."""
        if self._stepper is not None:
            self._stepper.release(self.s, False)
            return
        scr = self._scratch
        release(self.system.data, self.stops, self.s, scr.impact, scr.stages[3], scr.forces,
                False)
