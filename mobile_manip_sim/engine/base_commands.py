"""The base's velocity interface of `Simulation`: cmd_vel through the wheel-speed PI loop inside
the simulated system (`System.wheel_speed_torques`), its gains, the torques acting; and the
checks every effort or velocity command goes through (`command`, `finite_forces`).
"""
from __future__ import annotations

import math

import numpy as np

from ..scene.errors import UserError
from . import layout
from .system import (
    WHEEL_KI,
    WHEEL_KP,
    WHEEL_LIMIT_L,
    WHEEL_LIMIT_R,
    WHEEL_TARGET_L,
    WHEEL_TARGET_R,
    WHEEL_VELOCITY_MODE,
)


class BaseCommands:
    """Mixed into `Simulation` (which provides s, model, dynamics, effects, system,
    wheel_efforts and `_command_changed`, `_restart`)."""

    def set_base_velocity(self, v: float, omega: float) -> None:
        """Drive the base at forward speed v (m/s) and yaw rate ω (rad/s) from now on: the wheel
        torques come from the wheel-speed PI loop (`set_wheel_speed_gains`) inside the simulated
        system, recomputed at every evaluation of the right-hand side and clipped to each wheel's
        own effort limit, its integral back-calculated while that wheel is saturated
        (core/include/mms/system.hpp `wheel_drive`). `set_efforts(wheels=...)` returns the wheels
        to torque commands."""
        target = command([v, omega], 2, "cmd_vel")
        r, b = self.model.base.wheel_radius, self.model.base.half_track
        control = self.system.control
        v, omega = float(target[0]), float(target[1])
        wheel_speeds = finite_forces(lambda: ((v + b * omega) / r, (v - b * omega) / r),
                                      "cmd_vel", target)
        # the PI loop's forces at rest, kp times the wheel speeds: finite, or refused
        finite_forces(
            lambda: self.dynamics.wheel_forces(*(control[WHEEL_KP] * w for w in wheel_speeds)),
            "cmd_vel", target)
        before = control.copy()
        control[WHEEL_TARGET_R], control[WHEEL_TARGET_L] = wheel_speeds
        if not control[WHEEL_VELOCITY_MODE]:
            e = layout.controller(self.nq, self.nu)
            self.s[e:e + 2] = 0.0   # a fresh loop: no integral carried over from an earlier one
            # sampled, the loop's torques come at its next update; until then the wheels keep
            # the torques they were commanded, as a drive holds its last command
            self.system.held[:2] = self.wheel_efforts
            self._resume_updates()
            control[WHEEL_VELOCITY_MODE] = 1.0
        if not np.array_equal(before, control):
            self._command_changed()

    def set_wheel_speed_gains(self, kp: float, ki: float, torque_limit: float = math.inf) -> None:
        """Gains of the wheel-speed PI loop: kp (N·m·s/rad) on the speed error, ki (N·m/rad) on
        its integral; each wheel's torque within ±torque_limit (N·m) and its own effort limit of
        the scene (τ_R within the right wheel's, τ_L within the left's)."""
        for name, value in (("kp", kp), ("ki", ki)):
            if not (math.isfinite(value) and value >= 0.0):
                raise UserError(f"wheel_speed.{name}",
                                f"must be a finite number ≥ 0, got {value!r}")
        if not torque_limit > 0.0:
            raise UserError("wheel_speed.torque_limit", f"must be positive, got {torque_limit!r}")
        limits = [torque_limit, torque_limit]
        if self.effects.effort_limits is not None:   # (τ_R, τ_L, …): each wheel its own
            limits = [min(torque_limit, float(w)) for w in self.effects.effort_limits[:2]]
        control = self.system.control
        control[WHEEL_KP], control[WHEEL_KI] = kp, ki
        control[WHEEL_LIMIT_R], control[WHEEL_LIMIT_L] = limits
        self._restart()

    def wheel_torques(self) -> np.ndarray:
        """(τ_R, τ_L) acting now, N·m: the commanded ones, or the PI loop's in velocity mode
        (sampled: those of its last update, held)."""
        if not self.velocity_mode:
            return np.array(self.wheel_efforts, dtype=float)
        if self.system.data.rate > 0.0:
            return self.system.held[:2].copy()
        return np.array(self.system.wheel_speed_torques(self.s))

    @property
    def velocity_mode(self) -> bool:
        return bool(self.system.control[WHEEL_VELOCITY_MODE])


def finite_forces(compute, group, values) -> tuple:
    """compute() of what a command gives (its generalized forces, its wheel speeds), checked:
    a command whose results overflow (|τ_R + τ_L|/r beyond 1.8e308) is refused, or the
    integrators would meet infinities at their first stage."""
    with np.errstate(over="ignore", invalid="ignore"):
        results = tuple(float(x) for x in compute())
    if not all(math.isfinite(x) for x in results):
        raise UserError(f"efforts.{group}", f"{np.asarray(values, dtype=float).tolist()} "
                        f"overflows: its generalized forces would not be finite")
    return results


def command(values, size, group) -> np.ndarray:
    try:
        array = np.array(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise UserError(f"efforts.{group}", f"expected {size} numbers, got {values!r}") from None
    if array.size != size:
        raise UserError(f"efforts.{group}", f"expected {size} values, got {array.size}")
    if not np.all(np.isfinite(array)):
        raise UserError(f"efforts.{group}", f"values must be finite, got {array.tolist()}")
    return array

