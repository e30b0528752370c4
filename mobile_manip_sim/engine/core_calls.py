"""The engine's calls between steps — which rods rest (the locks), whether a stop pulls, a
release, a restart of an adaptive solve, the step in hand, the arm controller's reference and the
sampled controllers' update — made on the simulation's compiled stepper (`core_stepping.py`). A
mixin of `Simulation`, as `base_commands.py` and `arm_commands.py` are.
"""
from __future__ import annotations

import numpy as np

from ..scene.methods import METHODS
from . import core_stepping, layout


class CoreCalls:
    def _compiled_stepper(self):
        """The compiled C++ stepper of this simulation's own records (`core_stepping.py`; for
        radau and bdf, SciPy's steps are handed into it: `scipy_steps.py`). Made at every reset:
        a batch lane, a copy of its template's records, gets its own."""
        method = METHODS[self.settings.method]
        stepper = core_stepping.compiled_stepper(self.dynamics, method.name, self.system,
                                                 self.stops, self._scratch, self._solve)
        self.system.stepper = stepper
        return stepper

    def _reference_arrays_changed(self) -> None:
        """The system record's reference arrays were replaced (they grew): the stepper reads the
        new ones."""
        core_stepping.drive_arm(self._stepper, self.system.data)

    def _sampled_update(self, s) -> bool:
        """The sampled controllers' update at ``s`` (in place; core/include/mms/stepping.hpp; the
        clock's count is the caller's): True when a release it made failed its contact solve."""
        return self._stepper.update(s)

    def _reference_at(self, tau: float) -> np.ndarray:
        """(3, n_arm) q_ref, q̇_ref, q̈_ref of the arm's reference at its clock τ."""
        return self._stepper.arm_reference(tau)

    def _step_in_hand(self) -> tuple[float, float]:
        """An adaptive run's step in hand: (start, length) in s; length 0: none."""
        return self._stepper.step_in_hand()

    def _restart(self) -> None:
        """The right-hand side changes here: adaptive solves end at the current (t, s) (none
        before the first `reset` has made the stepper)."""
        if self._stepper is not None:
            self._stepper.restart()

    def _relock(self) -> None:
        """The locks from the stops (the scene's locked DOFs, the resting rods)."""
        self._stepper.relock()

    def _holding_margin(self) -> float:
        """The least force a resting rod's stop pushes with now (N; +inf: none rests)."""
        return self._stepper.holding_margin(self.s)

    def _release(self) -> None:
        """Free, now, the resting rods their stops would have to pull."""
        self._stepper.release(self.s, False)

    def _hold_pressed_rods(self) -> None:
        """A rod exactly at one of its stops and at rest (l̇ = 0) rests there from this instant,
        held, when its stop pushes: set resting, then freed again at once if its stop would
        have to pull (`stops.release`: the contact law at the level of accelerations, every
        such rod together). Left free, a rod pressed into its stop would hit it at the first
        step, and with a rebound of the size of the round-off (e > 0) hit it again a few µs
        later, without end: its rebound is too small to resolve in time."""
        if self.stop_law is None:
            return
        stroke, resting, watched = self.stroke, self.resting, self.watched
        found = False
        for k in range(1, len(resting) + 1):
            if resting[k - 1] or not watched[k - 1] or self.s[layout.ld(self.nq, k)] != 0.0:
                continue
            l_k = self.s[layout.q_slide(k)]
            side = -1 if l_k == stroke[k - 1, 0] else 1 if l_k == stroke[k - 1, 1] else 0
            if side:
                resting[k - 1], watched[k - 1] = side, False
                found = True
        if found:
            self._relock()
            self._release()
            if self.stops.failed[0]:
                self._contact_failed()
