"""The arm's command interface of `Simulation` (CONTROL_API: position, velocity and trajectory
references for the arm controller of `arm_control.py`), checked like every input.

Each command replaces the reference (`arm_reference.py`), resets the reference clock τ to 0 and
takes effect as any command does (`Simulation._command_changed`: adaptive solves restart, a rod
pulled off its stop is released). The PID integrals z are kept, as a ros2_control PID keeps its
integral across set-point changes. A command for another mode than the one in force, or any arm
reference in effort mode, is a UserError naming the command.
"""
from __future__ import annotations

import numpy as np

from ..scene.arm_controller import MODES
from ..scene.controller import outside_stroke
from ..scene.coordinates import ARM_U, arm_u, arm_width
from ..scene.errors import UserError
from ..scene.limits import DURATION, REVOLUTE_TARGET, SPEED, TRAJECTORY_POINTS
from . import arm_reference, layout
from .arm_control import LAST_TAU
from .arm_reference import Q_REF, QD_REF, QDD_REF


class ArmCommands:
    """Mixed into `Simulation` (which provides s, q, u, model, effects, dynamics, system)."""

    # --- commands -------------------------------------------------------------------------
    def set_arm_positions(self, q_ref) -> None:
        """Position mode: hold q_ref (n_arm values: rad, m) from now on, q̇_ref = 0."""
        self._arm_mode_is("position", "arm.positions")
        q_ref = self._arm_vector(q_ref, "arm.positions")
        self._check_points(q_ref[None, :], "arm.positions")
        self._set_reference(*arm_reference.hold(q_ref))

    def set_arm_velocities(self, qd_ref) -> None:
        """Velocity mode: q_ref(τ) = q(now) + q̇_ref τ (rad/s, m/s) from now on."""
        self._arm_mode_is("velocity", "arm.velocities")
        qd_ref = self._arm_vector(qd_ref, "arm.velocities", bound=SPEED)
        self._set_reference(*arm_reference.ramp(self._arm_now()[0], qd_ref))

    def set_arm_trajectory(self, times, positions, velocities=None, accelerations=None) -> None:
        """joint_trajectory mode: follow the points (`arm_reference.trajectory`) from the
        arm's state now; `times` are each point's time_from_start (s), strictly increasing,
        the first ≥ 0; positions (and velocities, accelerations if given) (m, n_arm)."""
        self._arm_mode_is("joint_trajectory", "arm.trajectory")
        times = self._trajectory_times(times)
        m = times.size
        P = self._arm_rows(positions, m, "arm.trajectory.positions")
        V = None if velocities is None else self._arm_rows(velocities, m,
                                                           "arm.trajectory.velocities", SPEED)
        A = None if accelerations is None else self._arm_rows(
            accelerations, m, "arm.trajectory.accelerations", 1e9)
        if A is not None and V is None:
            raise UserError("arm.trajectory.accelerations", "need velocities too (quintic "
                                                            "interpolation takes both)")
        self._check_points(P, "arm.trajectory.positions")
        q0, qd0 = self._arm_now()
        self._set_reference(*arm_reference.trajectory(q0, qd0, times, P, V, A))

    def hold_arm(self) -> None:
        """Cancel the reference: hold the arm where it is now (a position set-point)."""
        self._arm_mode_is(None, "arm.hold")
        self._set_reference(*arm_reference.hold(self._arm_now()[0]))

    # --- what acts now --------------------------------------------------------------------
    def arm_reference(self, t_ahead: float = 0.0):
        """(q_ref, q̇_ref, q̈_ref) of the reference t_ahead s from now (n_arm each)."""
        self._arm_mode_is(None, "arm.reference")
        tau = self.s[layout.reference_clock(self.nq, self.nu)] + float(t_ahead)
        out = self._reference_at(tau)
        return out[Q_REF].copy(), out[QD_REF].copy(), out[QDD_REF].copy()

    def joint_efforts_applied(self) -> np.ndarray:
        """(n_arm,) the arm efforts acting now: the controller's output after saturation, or
        the commanded efforts (saturated) in effort mode."""
        if not self.arm_controller.active:
            return np.array(self.joint_efforts, dtype=float)
        self.acceleration()   # one evaluation at s (uncounted): leaves the efforts in arm_ref
        return self.system.arm_ref[LAST_TAU].copy()

    # --- helpers ----------------------------------------------------------------------------
    def _start_arm(self) -> None:
        """At reset: hold the initial pose, then the scene section's command if the settings
        came from the scene (a position set-point, velocities or a trajectory, at t = 0)."""
        self._set_reference(*arm_reference.hold(self._arm_now()[0]))
        section = self._arm_section
        if section is None or section.command is None:
            return
        setter = getattr(self, self.arm_controller.row.setter)
        if self.arm_controller.row.array:
            setter(section.command)
        else:
            setter(*section.command)

    def _arm_mode_is(self, mode, key) -> None:
        current = self.arm_controller.mode
        if not self.arm_controller.active:
            *others, last = (name for name, row in MODES.items() if row.controlled)
            raise UserError(key, f"the arm is in {current} mode: choose an arm controller "
                                 f"({', '.join(others)} or {last})")
        if mode is not None and current != mode:
            raise UserError(key, f"the arm controller is {current!r}, this command needs {mode!r}")

    def _arm_now(self):
        q, u = self.q, self.u
        return q[layout.arm_q(0):].copy(), u[ARM_U].copy()

    def _set_reference(self, starts, coeffs) -> None:
        data = self.system.data
        self.system.set_reference(starts, coeffs)
        if self.system.data is not data:   # the record grew: the stepper takes the new arrays
            self._reference_arrays_changed()
        self.s[layout.reference_clock(self.nq, self.nu)] = 0.0
        self._command_changed()

    def _arm_vector(self, values, key, bound=None) -> np.ndarray:
        n_arm = arm_width(self.nu)
        try:
            array = np.array(values, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise UserError(key, f"expected {n_arm} numbers, got {values!r}") from None
        if array.size != n_arm:
            raise UserError(key, f"expected {n_arm} values (one per arm joint), got {array.size}")
        if not np.all(np.isfinite(array)):
            raise UserError(key, f"values must be finite, got {array.tolist()}")
        if bound is not None and np.any(np.abs(array) > bound):
            raise UserError(key, f"values must be within ±{bound:g}, got {array.tolist()}")
        return array

    def _arm_rows(self, values, m, key, bound=None) -> np.ndarray:
        n_arm = arm_width(self.nu)
        if isinstance(values, np.ndarray) and values.shape == (m, n_arm):
            # checked at once (a 100,000-point trajectory's arrays); a bad row is then checked
            # alone, for its message
            rows = values.astype(float)
            bad = ~np.isfinite(rows) if bound is None else ~(np.abs(rows) <= bound)
            if bad.any():
                i = int(np.flatnonzero(bad.any(axis=1))[0])
                self._arm_vector(rows[i], f"{key}[{i}]", bound)
            return rows
        try:
            rows = list(values)
        except TypeError:
            raise UserError(key, f"expected {m} rows, got {values!r}") from None
        if len(rows) != m:
            raise UserError(key, f"expected {m} rows (one per point), got {len(rows)}")
        return np.array([self._arm_vector(row, f"{key}[{i}]", bound)
                         for i, row in enumerate(rows)]).reshape(m, n_arm)

    def _trajectory_times(self, times) -> np.ndarray:
        key = "arm.trajectory.times"
        try:
            times = np.array(times, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise UserError(key, f"expected a list of times (s), got {times!r}") from None
        if not 1 <= times.size <= TRAJECTORY_POINTS:
            raise UserError(key, f"expected 1 to {TRAJECTORY_POINTS} points, got {times.size}")
        if not np.all(np.isfinite(times)) or times[0] < 0.0 or times[-1] > DURATION[1]:
            raise UserError(key, f"times must be finite, in [0, {DURATION[1]:g}] s, got "
                                 f"{times.tolist()[:4]}")
        if np.any(np.diff(times) <= 0.0):
            i = int(np.flatnonzero(np.diff(times) <= 0.0)[0]) + 1
            raise UserError(f"{key}[{i}]", f"{times[i]} s is not after the previous point's "
                                           f"{times[i - 1]} s (times must increase strictly)")
        return times

    def _check_points(self, points: np.ndarray, key: str) -> None:
        """Every point within its rod's stroke (when stroke limits are on), and held against
        gravity within the effort limits (when set): else a UserError naming the joint."""
        names = self.model.joint_names()[ARM_U]
        revolute = np.abs(points[:, 0::2]) > REVOLUTE_TARGET   # the arm's columns: q1, l1, …
        if revolute.any():
            i, j = (int(v) for v in np.argwhere(revolute)[0])
            where = f"{key}[{i}]" if points.shape[0] > 1 else key
            raise UserError(names[2 * j], f"{points[i, 2 * j]:g} rad ({where}) is beyond "
                                          f"±{REVOLUTE_TARGET:g} rad")
        stroke = np.asarray(self.model.stroke).reshape(-1, 2)
        limits = self.effects.effort_limits
        if self.stop_law is not None and stroke.size:   # every point at once, then the first out
            lengths = points[:, 1::2]
            out = ~((stroke[:, 0] <= lengths) & (lengths <= stroke[:, 1]))
            if out.any():
                i = int(np.flatnonzero(out.any(axis=1))[0])
                where = f"{key}[{i}]" if points.shape[0] > 1 else key
                found = outside_stroke(points[i], stroke)
                raise UserError(names[found[0]], f"{found[1]} ({where})")
        if limits is None or self.dynamics.gravity == 0.0:
            return
        for i, point in enumerate(points):
            where = f"{key}[{i}]" if points.shape[0] > 1 else key
            q = np.concatenate([self.q[:5], point])
            gravity = self.dynamics.inverse_dynamics(q, np.zeros(self.nu), np.zeros(self.nu))[ARM_U]
            over = np.flatnonzero(np.abs(gravity) > limits[ARM_U])
            if over.size:
                j = int(over[0])
                unit = "N·m" if j % 2 == 0 else "N"
                raise UserError(names[j], f"holding the pose of {where} against gravity takes "
                                          f"{abs(gravity[j]):.4g} {unit}, beyond its effort limit "
                                          f"{limits[arm_u(j)]:g} {unit}")
