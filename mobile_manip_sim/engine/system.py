"""The simulated ODE's records: what the compiled core's right-hand side reads of the effects a
scene turns on, and the commands in force.

State vector ``s = (q, u, e, W)`` (`layout.py`): configuration (n_q), pseudo-velocities (n_u),
the wheel-speed controller's two error integrals e = (e_R, e_L) (rad; zero and constant while the
wheels take torque commands), and W, the work done on the robot so far by the wheel and joint
efforts (the arm controller's included) and by dissipation (J), so that the energy balance
``T + V − W = const`` (minus impact losses) can be checked on any run. When a controller drives
the arm (`arm_control.py`), its PID integrals z and reference clock τ follow W.

Generalized forces are kept by source, as in docs/model.md: ``Q_cmd`` (commanded efforts, already
saturated by `effort_limits`), the wheel-speed PI loop's wheel torques when the base takes a
velocity command, the arm controller's efforts when one drives the arm, ``Q_damp = −c ⊙ u``
(joint and wheel damping), and the velocity products and gravity inside the dynamics. The
right-hand side itself is the C++ core's (core/include/mms/system.hpp `rates`, u̇ by the
articulated-body recursion, O(n)), which reads these arrays in place (`core_stepping.py`). An
effect that is off adds no stage: no damping pass, no controller, no locked-joint bookkeeping.
``counters`` counts the stages actually run (tests use it to prove that an effect that is off
costs nothing).
"""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from ..core import vocabulary
from ..scene.coordinates import arm_width
from . import layout
from .arm_control import ARM_SEGMENT, ARM_SEGMENTS, N_ARM_SETTINGS
from .arm_reference import WIDTH

# The records' indices are the core's (core/include/mms/run.hpp, `core.vocabulary`).
# counters[...] indices
(RHS_EVALS, DAMPING_STAGE, REDUCED_SOLVE, CROSSING_CHECKS, CONTROL_STAGE,
 ARM_CONTROL_STAGE) = (vocabulary[name] for name in (
    "RHS_EVALS", "DAMPING_STAGE", "REDUCED_SOLVE", "CROSSING_CHECKS", "CONTROL_STAGE",
    "ARM_CONTROL_STAGE"))
N_COUNTERS = ARM_CONTROL_STAGE + 1

# holding[...] entries: the resting rods' holding forces, watched at every evaluation while a rod
# rests: on while one rests; the smallest margin (N) since the watch was cleared
HOLDING_ON, HOLDING_LEAST_MARGIN = vocabulary["HOLDING_ON"], vocabulary["HOLDING_LEAST_MARGIN"]

# control[...] entries: the wheel-speed PI loop (system.hpp's WheelLoop); each wheel its own limit
(WHEEL_VELOCITY_MODE, WHEEL_KP, WHEEL_KI, WHEEL_LIMIT_R, WHEEL_LIMIT_L, WHEEL_TARGET_R,
 WHEEL_TARGET_L) = (vocabulary[name] for name in (
    "WHEEL_VELOCITY_MODE", "WHEEL_KP", "WHEEL_KI", "WHEEL_LIMIT_R", "WHEEL_LIMIT_L",
    "WHEEL_TARGET_R", "WHEEL_TARGET_L"))
N_CONTROL = WHEEL_TARGET_L + 1

SystemData = namedtuple("SystemData", [
    "gravity",   # g, m/s² along −z
    "damping",   # (n_u,) viscous coefficients on u, or (0,) when no damping effect is on
    "free",      # (n_u,) indices of the free pseudo-velocities, padded with −1
    "Q_cmd",     # (n_u,) commanded generalized forces (wheels' part unused in velocity mode)
    "control",   # (7,) wheel-speed PI loop: mode (0 effort, 1 velocity), kp, ki, the limits
                 # and the target speeds of the right and left wheels
    "counters",  # (N_COUNTERS,) stage counters
    "resting",   # (n,) int64: −1 / +1 rod held at its lower / upper stop, 0 free (the stops'
                 # own array, `stops.StopsData.resting`)
    "holding",   # (2,) the holding forces' watch: HOLDING_ON, HOLDING_LEAST_MARGIN
    # the arm controller (`arm_control.py`; empty arrays, and arm[ARM_ON] = 0, in effort mode)
    "arm",          # (N_ARM_SETTINGS,) on, feedforward kind, reference segments in use
    "arm_gains",    # (3, n_arm) kp, ki, kd
    "arm_limits",   # (n_arm,) effort limits, inf where none
    "ref_starts",   # (capacity,) s: the reference's segment starts (`arm_reference.py`)
    "ref_coeffs",   # (capacity, n_arm, arm_reference.WIDTH) their coefficients
    "arm_ref",      # (5, n_arm) scratch: q_ref, q̇_ref, q̈_ref, feedforward, applied efforts
    "ff_masses",    # the feed-forward's masses: (0,) for the plant's own, else a model
                    # error's (`arm_control.feedforward_masses`)
    # the sampled controllers (core/include/mms/stepping.hpp)
    "rate",      # Hz, the controllers' update rate; 0: continuous controllers
    "held",      # (n_u,) the efforts the sampled controllers hold between updates, laid out as
                 # the efforts τ = (τ_R, τ_L, τ_1, F_1, …): the wheel-speed loop's wheel torques
                 # (N·m), the arm controller's joint efforts; read only while they drive
])


class System:
    """Holds the `SystemData` record the compiled core reads and the Python-side view of the
    effects; its right-hand side is the stepper's (`stepper`, made by `Simulation.reset`)."""

    def __init__(self, dynamics, damping: np.ndarray | None, locked: list[int], arm=None,
                 ff_masses=None, rate: float = 0.0):
        """`arm`: the arm controller's (settings, gains, limits) of `arm_control.arm_settings`,
        or None (effort mode: no controller states, no controller stage); `ff_masses` the
        feed-forward's masses of `arm_control.feedforward_masses` (None: the plant's);
        `rate` the controllers' update rate (Hz; 0: continuous; core/include/mms/stepping.hpp)."""
        self.dynamics = dynamics
        nu = dynamics.model.n_u
        n_arm = arm_width(nu) if arm is not None else 0
        self.arm_on = arm is not None
        self.Q_cmd = np.zeros(nu)
        self.damping = np.zeros(0) if damping is None else np.asarray(damping, dtype=float)
        self.free = np.full(nu, -1, dtype=np.int64)
        self.counters = np.zeros(N_COUNTERS, dtype=np.int64)
        self.control = np.zeros(N_CONTROL)
        self.control[WHEEL_LIMIT_R] = self.control[WHEEL_LIMIT_L] = math.inf
        self.permanently_locked = tuple(sorted(locked))
        settings, gains, limits = arm if arm is not None else (
            np.zeros(N_ARM_SETTINGS), np.zeros((3, 0)), np.zeros(0))
        self.arm_ref = np.zeros((5, n_arm))
        self.data = SystemData(float(dynamics.gravity), self.damping, self.free, self.Q_cmd,
                               self.control, self.counters,
                               np.zeros(dynamics.model.n_links, dtype=np.int64),
                               np.array([0.0, math.inf]), settings, gains, limits, np.zeros(1),
                               np.zeros((1, n_arm, WIDTH)), self.arm_ref,
                               np.zeros(0) if ff_masses is None else ff_masses,
                               float(rate), np.zeros(nu))
        self.stepper = None   # the compiled core's stepper on these arrays (`Simulation.reset`)
        self.held = self.data.held
        self.set_locked(())
        size = layout.state_size(nu) + (layout.arm_state_size(nu) if arm is not None else 0)
        self.size = size   # entries of s

    def set_reference(self, starts: np.ndarray, coeffs: np.ndarray) -> None:
        """The arm's reference from now on (`arm_reference.py`): copied into the compiled
        record, whose arrays grow when too small and shrink to fit when four times too large
        (the record is rebuilt: re-read ``data``): a node that ran a 100,000-point trajectory
        kept its 24 MB of coefficients for as long as it ran."""
        count = starts.size
        size = self.data.ref_starts.size
        if count > size or 4 * count < size:
            capacity = max(count, 2 * size) if count > size else count
            self.data = self.data._replace(ref_starts=np.zeros(capacity),
                                           ref_coeffs=np.zeros((capacity,) + coeffs.shape[1:]))
        self.data.ref_starts[:count] = starts
        self.data.ref_coeffs[:count] = coeffs
        self.data.arm[ARM_SEGMENTS] = count
        self.data.arm[ARM_SEGMENT] = 0

    def set_locked(self, extra: tuple) -> None:
        """Lock the scene's locked DOFs plus `extra` (rods resting at a stop)."""
        locked = set(self.permanently_locked) | set(extra)
        free = [k for k in range(len(self.Q_cmd)) if k not in locked]
        self.free[:] = -1
        self.free[:len(free)] = free
        self.locked = tuple(sorted(locked))

    def state(self, q, u) -> np.ndarray:
        """The state vector s = (q, u, e = 0, W = 0) of a configuration and its pseudo-velocities
        (and z = 0, τ = 0 when a controller drives the arm)."""
        extra = layout.arm_state_size(len(self.Q_cmd)) if self.arm_on else 0
        return np.concatenate([np.asarray(q, dtype=float), np.asarray(u, dtype=float),
                               [0.0, 0.0, 0.0], np.zeros(extra)])

    def _check(self, s: np.ndarray) -> np.ndarray:
        s = np.ascontiguousarray(s, dtype=float)
        if s.shape != (self.size,):
            raise ValueError(f"state vector of length {s.size}, expected {self.size} "
                             f"(layout.py)")
        return s

    def derivative(self, s: np.ndarray) -> np.ndarray:
        """ds/dt at s with the locks and commands in force (counted among the evaluations)."""
        return self.stepper.derivative(self._check(s))

    def constraint_forces(self, s: np.ndarray) -> np.ndarray:
        """M u̇ + h − Q_cmd − Q_damp at s with the current locks (nonzero only on locked DOFs):
        one inverse-dynamics pass after the right-hand side."""
        return self.stepper.constraint_forces(self._check(s))

    def wheel_speed_torques(self, s: np.ndarray) -> tuple[float, float]:
        """(τ_R, τ_L), N·m: the continuous wheel-speed loop's torques at s."""
        return self.stepper.wheel_torques(self._check(s))
