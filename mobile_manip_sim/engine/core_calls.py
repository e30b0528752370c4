"""The engine's calls between steps — which rods rest (the locks), whether a stop pulls, a
release, a restart of an adaptive solve, the step in hand — made by whichever core runs the
simulation's method: the compiled C++ stepper (`core_stepping.py`), or the numba kernels and
records where it does not run (``MOBILE_MANIP_SIM_CORE=numba``), and the arm controller's
reference and the sampled controllers' update between steps. A mixin of
`Simulation`, as `base_commands.py` and `arm_commands.py` are; the numba branches leave with
numba.
"""
from __future__ import annotations

import numpy as np

from ..scene.coordinates import arm_width
from ..scene.methods import METHODS
from . import adaptive_stepping, arm_reference, core_stepping, layout
from .arm_control import ARM_SEGMENTS
from .events import holding_margin
from .stops import release, relock


class CoreCalls:
    def _compiled_stepper(self):
        """The compiled C++ stepper of this simulation's own records (`core_stepping.py`; for
        radau and bdf, SciPy's steps are handed into it: `scipy_steps.py`), or None where the
        numba kernels run (``MOBILE_MANIP_SIM_CORE=numba``). Made at every reset: a batch lane, a
        copy of its template's records, gets its own."""
        method = METHODS[self.settings.method]
        if core_stepping.CORE != "cpp":
            return None
        return core_stepping.compiled_stepper(self.dynamics, method.name, self.system, self.stops,
                                              self._scratch, self._solve)

    def _reference_arrays_changed(self) -> None:
        """The system record's reference arrays were replaced (they grew): the stepper reads the
        new ones."""
        if self._stepper is not None:
            core_stepping.drive_arm(self._stepper, self.system.data)

    def _sampled_update(self, s) -> bool:
        """The sampled controllers' update at ``s`` (in place; `sampling.update_at_instant`; the
        clock's count is the caller's): True when a release it made failed its contact solve."""
        if self._stepper is not None:
            return self._stepper.update(s)
        return self._update(self.system.data, self.stops, self._scratch, s)

    def _reference_at(self, tau: float) -> np.ndarray:
        """(3, n_arm) q_ref, q̇_ref, q̈_ref of the arm's reference at its clock τ."""
        if self._stepper is not None:
            return self._stepper.arm_reference(tau)
        data = self.system.data
        out = np.zeros((3, arm_width(self.nu)))
        arm_reference.reference(data.ref_starts, data.ref_coeffs, int(data.arm[ARM_SEGMENTS]), tau,
                                out, 0)
        return out

    def load_kernels(self) -> None:
        """Load now (compile, if the warm-up did not) every compiled kernel that this
        simulation's run may call from Python later — a step, an adaptive step's interpolation,
        the release check of a command, a switch to cmd_vel and the wheel-speed loop's torques,
        the arm's reference and efforts, and what a node's publication reads: q̇, u̇, T and V —
        by calling each once on a twin (same scene, settings and arm controller; this one is
        untouched), so that no compile happens while a node runs (the kernels are bound per
        argument types, which the twin shares)."""
        twin = type(self)(self.scene, self.settings,
                          None if self._arm_section is not None else self.arm_controller,
                          self.control_rate)
        twin.advance_to(twin.t + 1e-3)
        twin.acceleration()
        twin.qdot()
        twin.dynamics.energy(twin.q, twin.u)
        twin.set_base_velocity(0.0, 0.0)
        twin.wheel_torques()
        if twin.sampled:
            twin._sampled_update(twin.s)
        twin._holding_margin()
        twin._release()
        if twin.arm_controller.active:
            twin.arm_reference()
            twin.joint_efforts_applied()

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
