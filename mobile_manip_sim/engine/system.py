"""The right-hand side of the simulated ODE, assembled from the effects a scene turns on.

State vector ``s = (q, u, e, W)`` (`layout.py`): configuration (n_q), pseudo-velocities (n_u),
the wheel-speed controller's two error integrals e = (e_R, e_L) (rad; zero and constant while the
wheels take torque commands), and W, the work done on the robot so far by the wheel and joint
efforts (the arm controller's included) and by dissipation (J), so that the energy balance
``T + V − W = const`` (minus impact losses) can be checked on any run. When a controller drives
the arm (`arm_control.py`), its PID integrals z and reference clock τ follow W.

Generalized forces are kept by source, as in docs/model.md: ``Q_cmd`` (commanded efforts, already
saturated by `effort_limits`), the wheel-speed PI loop's wheel torques when the base takes a
velocity command, the arm controller's efforts when one drives the arm (`arm_control.py`),
``Q_damp = −c ⊙ u`` (joint and wheel damping), and the velocity products and gravity inside
the dynamics. u̇ comes from the articulated-body recursion, O(n)
(`dynamics/articulated.py`); the mass matrix is never formed here. An effect that is off adds no
stage: no damping pass, no controller, no locked-joint bookkeeping. ``counters`` counts the
stages actually run (tests use it to prove that an effect that is off costs nothing).
"""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from ..dynamics import kernels
from ..dynamics.articulated import articulated_forward_dynamics
from ..dynamics.jit import ENABLED, jit, jit_inline
from ..scene.coordinates import OMEGA, V, arm_width
from . import layout
from .arm_control import (
    ARM_ON,
    ARM_SEGMENT,
    ARM_SEGMENTS,
    N_ARM_SETTINGS,
    arm_efforts,
    held_arm_efforts,
)
from .arm_reference import WIDTH

# counters[...] indices
(RHS_EVALS, DAMPING_STAGE, REDUCED_SOLVE, CROSSING_CHECKS, CONTROL_STAGE,
 ARM_CONTROL_STAGE) = range(6)
N_COUNTERS = 6

# holding[...] entries: the resting rods' holding forces watched at every evaluation
# (`watch_holding`): on while a rod rests; the smallest margin (N) since `clear_holding`
HOLDING_ON, HOLDING_LEAST_MARGIN = range(2)

# control[...] entries: the wheel-speed PI loop (`wheel_speed_loop`); each wheel its own limit
(WHEEL_VELOCITY_MODE, WHEEL_KP, WHEEL_KI, WHEEL_LIMIT_R, WHEEL_LIMIT_L, WHEEL_TARGET_R,
 WHEEL_TARGET_L) = range(7)
N_CONTROL = 7

SystemData = namedtuple("SystemData", [
    "model",     # the dynamics' model record (`dynamics.records.Model`)
    "gravity",   # g, m/s² along −z
    "damping",   # (n_u,) viscous coefficients on u, or (0,) when no damping effect is on
    "free",      # (n_u,) indices of the free pseudo-velocities, padded with −1
    "Q_cmd",     # (n_u,) commanded generalized forces (wheels' part unused in velocity mode)
    "control",   # (7,) wheel-speed PI loop: mode (0 effort, 1 velocity), kp, ki, the limits
                 # and the target speeds of the right and left wheels
    "ws",        # the dynamics workspace (`dynamics.records.Workspace`)
    "Q",         # (n_u,) scratch: applied generalized forces of the current evaluation
    "counters",  # (N_COUNTERS,) stage counters
    "resting",   # (n,) int64: −1 / +1 rod held at its lower / upper stop, 0 free (the stops'
                 # own array, `stops.StopsData.resting`)
    "holding",   # (2,) the holding forces' watch: HOLDING_ON, HOLDING_LEAST_MARGIN
                 # (`watch_holding`)
    # the arm controller (`arm_control.py`; empty arrays, and arm[ARM_ON] = 0, in effort mode)
    "arm",          # (N_ARM_SETTINGS,) on, feedforward kind, reference segments in use
    "arm_gains",    # (3, n_arm) kp, ki, kd
    "arm_limits",   # (n_arm,) effort limits, inf where none
    "ref_starts",   # (capacity,) s: the reference's segment starts (`arm_reference.py`)
    "ref_coeffs",   # (capacity, n_arm, arm_reference.WIDTH) their coefficients
    "arm_ref",      # (5, n_arm) scratch: q_ref, q̇_ref, q̈_ref, feedforward, applied efforts
    "arm_scratch",  # (5, n_u) scratch of the inverse-dynamics passes (row SCRATCH_ZERO stays zero)
    "ff_masses",    # the feed-forward's masses: (0,) for the plant's own, else a model
                    # error's (`arm_control.feedforward_masses`, read by `feedforward_model`)
    # the sampled controllers (`sampling.py`)
    "rate",      # Hz, the controllers' update rate; 0: continuous controllers
    "held",      # (n_u,) the efforts the sampled controllers hold between updates, laid out as
                 # the efforts τ = (τ_R, τ_L, τ_1, F_1, …): the wheel-speed loop's wheel torques
                 # (N·m), the arm controller's joint efforts; read only while they drive
])

# The record of a system without an arm controller (effort mode): the same fields, a class of its
# own. Compiled code is specialised by the record's class, and this one's leaves the controller's
# stage out altogether (`arm_stage`): the stage's mere presence, a call that hands `arm_efforts`
# the whole record word by word (some 330 words for the paper robot), cost every right-hand side
# of an effort-mode run about 35 ns of its 340, on a call that never happens there. The price is a
# second compile of every kernel that takes the record, which the warm-up pays.
EffortSystemData = namedtuple("EffortSystemData", SystemData._fields)


def system_data(data) -> SystemData:
    """The same arrays in a `SystemData`: the batch's lanes share one record class, whatever each
    lane's arm controller (the compiled lanes are typed once, for all)."""
    return data if type(data) is SystemData else SystemData(*data)


@jit_inline
def arm_controller_stage(system, s, ds):
    """The arm controller's efforts while it is on: its law at s (`arm_control.arm_efforts`),
    or, sampled, the efforts of its last update held (`arm_control.held_arm_efforts`)."""
    if system.arm[ARM_ON] != 0.0:
        system.counters[ARM_CONTROL_STAGE] += 1
        if system.rate > 0.0:
            held_arm_efforts(system, s, ds)
        else:
            arm_efforts(system, s, ds)


@jit_inline
def arm_law_while_on(system, s, ds):
    if system.arm[ARM_ON] != 0.0:
        arm_efforts(system, s, ds)


def arm_law(system, s, ds):
    """The arm controller's law at s (`arm_control.arm_efforts`) while it is on, whether sampled
    or not: the sampled update's (`sampling.py`); compiled, nothing at all for an
    `EffortSystemData` (`_arm_law_by_class`), which need not compile the law."""
    arm_law_while_on(system, s, ds)


def arm_stage(system, s, ds):
    """The arm's stage of `applied_forces`: `arm_controller_stage`; compiled, nothing at all for
    an `EffortSystemData` (`_arm_stage_by_class`)."""
    arm_controller_stage(system, s, ds)


if ENABLED:
    from numba.extending import overload

    def _inline_the_empty_stage(expr, caller, callee):
        """An effort-mode record's stage, which is nothing, is inlined; the controller's is a
        call of its own. Inlined, its two copies in one function (`fixed_step.inlined_step`
        holds two right-hand sides) shared the names of their variables, as numba caches an
        overload's IR, and numba's SSA pass lost one (NumbaIRAssumptionWarning)."""
        return callee.signature.args[0].instance_class is EffortSystemData

    @overload(arm_stage, inline=_inline_the_empty_stage)
    def _arm_stage_by_class(system, s, ds):
        if system.instance_class is EffortSystemData:
            return lambda system, s, ds: None
        return lambda system, s, ds: arm_controller_stage(system, s, ds)

    @overload(arm_law, inline=_inline_the_empty_stage)
    def _arm_law_by_class(system, s, ds):
        if system.instance_class is EffortSystemData:
            return lambda system, s, ds: None
        return lambda system, s, ds: arm_law_while_on(system, s, ds)


@jit_inline
def wheel_drive(kp, ki, target, speed, integral, limit, tracking):
    """One wheel's PI speed loop: (τ, ė). τ = sat(kp (θ̇* − θ̇) + ki e) within ±limit. Its
    anti-windup:
    - `tracking` (the continuous loop): back-calculation, control_toolbox's BACK_CALCULATION
      with its default tracking time constant T_t = kp/ki for a PI: ki ė = ki (θ̇* − θ̇) +
      (τ − raw)/T_t, i.e. ė = (θ̇* − θ̇) + (τ − raw)/kp. The rate is continuous in the state (τ
      has a kink at the limit, no jump), so an adaptive method meets no switch it cannot step
      across; unsaturated, τ − raw = 0 and ė is the error exactly. (kp = 0: conditional.)
    - otherwise (the sampled loop's update): conditional integration, control_toolbox's
      CONDITIONAL_INTEGRATION: e stops while τ is saturated in the direction of the error (the
      arm's PID does the same)."""
    error = target - speed
    raw = kp * error + ki * integral
    tau = min(max(raw, -limit), limit)
    if tracking and kp > 0.0:
        return tau, error + (tau - raw) / kp
    rate = 0.0 if (raw > limit and error > 0.0) or (raw < -limit and error < 0.0) else error
    return tau, rate


@jit
def wheel_speed_loop(control, r, b, s, nq, nu, tracking):
    """(τ_R, τ_L, ė_R, ė_L): the wheel-speed loop of each wheel (`wheel_drive`; `tracking`:
    the continuous loop's anti-windup), with θ̇_R/L = (v ± b ω)/r, e_R/L held in the state and
    each wheel's own torque limit.

    Compiled on its own and handed the few numbers it reads, not inlined into the right-hand
    side: there its code made every right-hand side slower, those of runs in effort mode too."""
    v, om = s[nq + V], s[nq + OMEGA]
    i_e = layout.controller(nq, nu)
    kp, ki = control[WHEEL_KP], control[WHEEL_KI]
    tau_R, rate_R = wheel_drive(kp, ki, control[WHEEL_TARGET_R], (v + b * om) / r, s[i_e],
                                control[WHEEL_LIMIT_R], tracking)
    tau_L, rate_L = wheel_drive(kp, ki, control[WHEEL_TARGET_L], (v - b * om) / r, s[i_e + 1],
                                control[WHEEL_LIMIT_L], tracking)
    return tau_R, tau_L, rate_R, rate_L


@jit
def wheel_speed_torques(system, s):
    """(τ_R, τ_L), N·m: the torques of the wheel-speed loop at s (`wheel_speed_loop`)."""
    nq, nu = layout.sizes(system)
    base = system.model.base
    tau_R, tau_L, _, _ = wheel_speed_loop(system.control, base.wheel_radius, base.half_track,
                                          s, nq, nu, True)
    return tau_R, tau_L


@jit_inline
def applied_forces(system, s, ds):
    """Q = commanded efforts (or the PI loop's wheel torques, the arm controller's efforts) +
    damping, into ``system.Q``; also writes ė (the wheel loop's error rates), and ż, τ̇ when a
    controller drives the arm, into ds. Returns the power Q·u (W)."""
    model, damping, Q_cmd, Q = system.model, system.damping, system.Q_cmd, system.Q
    control = system.control
    nq, nu = layout.sizes(system)
    i_e = layout.controller(nq, nu)
    for k in range(nu):
        Q[k] = Q_cmd[k]
    ds[i_e] = 0.0
    ds[i_e + 1] = 0.0
    if control[WHEEL_VELOCITY_MODE] != 0.0:
        system.counters[CONTROL_STAGE] += 1
        r, b = model.base.wheel_radius, model.base.half_track
        if system.rate > 0.0:   # sampled: the torques of the last update, held (ė = 0)
            tau_R, tau_L = system.held[0], system.held[1]
        else:
            tau_R, tau_L, ds[i_e], ds[i_e + 1] = wheel_speed_loop(control, r, b, s, nq, nu,
                                                                  True)
        Q[V] = (tau_R + tau_L) / r
        Q[OMEGA] = b * (tau_R - tau_L) / r
    arm_stage(system, s, ds)
    power = 0.0
    for k in range(nu):
        power += Q[k] * s[nq + k]
    if damping.shape[0] > 0:
        system.counters[DAMPING_STAGE] += 1
        for k in range(nu):
            u_k = s[nq + k]
            Q[k] -= damping[k] * u_k
            power -= damping[k] * u_k * u_k
    return power


@jit
def derivative(system, s, ds):
    """ds/dt for s = (q, u, e, W): q̇ from the constraints, u̇ = M⁻¹(Q − h) by articulated bodies
    (locked pseudo-velocities get u̇ = 0), ė from the wheel-speed loop, Ẇ = Q·u."""
    derivative_inline(system, s, ds)


@jit_inline
def derivative_inline(system, s, ds):
    """`derivative` inlined into its caller: for the steps (`fixed_step.inlined_step`, in which
    rk4 evaluates its four stages through one copy)."""
    nq, nu = layout.sizes(system)
    system.counters[RHS_EVALS] += 1
    q = s[:nq]
    u = s[nq:nq + nu]
    kernels.frames(system.model, q, system.ws)
    kernels.configuration_rate(system.model, q, u, ds[:nq])
    power = applied_forces(system, s, ds)
    if system.free[nu - 1] < 0:
        system.counters[REDUCED_SOLVE] += 1
    articulated_forward_dynamics(system.model, q, u, system.Q, system.gravity, system.free,
                                 system.ws, ds[nq:nq + nu])
    ds[layout.work(nq, nu)] = power
    if system.holding[HOLDING_ON] != 0.0:
        watch_holding(system)


@jit_inline
def holding_margin_now(system):
    """min over resting rods of the force (N) its stop pushes with, right after a `derivative`
    (> 0 while every stop pushes; +inf when none rests)."""
    margin = math.inf
    resting = system.resting
    for k in range(1, resting.shape[0] + 1):
        if resting[k - 1] != 0:
            # The stop pushes outward only: +l at the lower stop (side −1), −l at the upper (+1).
            j = layout.u_slide(k)
            margin = min(margin, -resting[k - 1] * (system.ws.slide_force[k] - system.Q[j]))
    return margin


@jit_inline
def watch_holding(system):
    """While a rod rests, every evaluation of the right-hand side — each stage of every step —
    samples the holding forces: holding[HOLDING_LEAST_MARGIN] keeps the smallest margin since
    `clear_holding`, so that a pull inside a step is noticed where a stage saw it (the steppers
    then locate it on the step itself, `events.first_release`). Costs nothing while none rests."""
    margin = holding_margin_now(system)
    if margin < system.holding[HOLDING_LEAST_MARGIN]:
        system.holding[HOLDING_LEAST_MARGIN] = margin


@jit_inline
def clear_holding(system):
    system.holding[HOLDING_LEAST_MARGIN] = math.inf


@jit
def holding_forces(system, s, ds, out):
    """Generalized force each locked pseudo-velocity needs to stay locked, M u̇ + h − Q, at s right
    after ds = derivative(s) (which left the frames of s in the workspace and Q in system.Q), into
    out[:n_u] (zero on the free ones up to round-off): one inverse-dynamics pass, O(n); the mass
    matrix is not needed. The engine reads the resting rods' forces off the derivative itself
    (`slide_holding_forces`); this full pass serves `System.constraint_forces` and the tests."""
    nq, nu = layout.sizes(system)
    q = s[:nq]
    kernels.gibbs_appell(system.model, q, s[nq:nq + nu], ds[nq:nq + nu], system.gravity,
                         system.ws, out[:nu])
    for k in range(nu):
        out[k] -= system.Q[k]


@jit_inline
def slide_holding_forces(system, resting, out):
    """The force (N) the stop of each resting rod k must push with along the rod to hold it,
    M u̇ + h − Q of its l̇_k, into out[u_slide(k)], right after a `derivative` with the rod locked:
    read off the articulated-body pass (`dynamics/articulated.py`), no inverse dynamics."""
    for k in range(1, resting.shape[0] + 1):
        if resting[k - 1] != 0:
            j = layout.u_slide(k)
            out[j] = system.ws.slide_force[k] - system.Q[j]


class System:
    """Holds the compiled `SystemData` record and the Python-side view of the effects."""

    def __init__(self, dynamics, damping: np.ndarray | None, locked: list[int], arm=None,
                 ff_masses=None, rate: float = 0.0):
        """`arm`: the arm controller's (settings, gains, limits) of `arm_control.arm_settings`,
        or None (effort mode: no controller states, no controller stage); `ff_masses` the
        feed-forward's masses of `arm_control.feedforward_masses` (None: the plant's);
        `rate` the controllers' update rate (Hz; 0: continuous, `sampling.py`)."""
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
        record = SystemData if arm is not None else EffortSystemData
        self.data = record(dynamics.model_record, float(dynamics.gravity), self.damping,
                               self.free, self.Q_cmd, self.control, dynamics.ws, np.zeros(nu),
                               self.counters, np.zeros(dynamics.model.n_links, dtype=np.int64),
                               np.array([0.0, math.inf]), settings, gains, limits, np.zeros(1),
                               np.zeros((1, n_arm, WIDTH)), self.arm_ref,
                               np.zeros((5, nu if arm is not None else 0)),
                               np.zeros(0) if ff_masses is None else ff_masses,
                               float(rate), np.zeros(nu))
        self.held = self.data.held
        self.set_locked(())
        size = layout.state_size(nu) + (layout.arm_state_size(nu) if arm is not None else 0)
        self._scratch = np.zeros(size)

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
        s = np.asarray(s, dtype=float)
        if s.shape != self._scratch.shape:   # compiled code does not check bounds
            raise ValueError(f"state vector of length {s.size}, expected {self._scratch.size} "
                             f"(layout.py)")
        return s

    def derivative(self, s: np.ndarray) -> np.ndarray:
        s = self._check(s)
        ds = np.empty_like(s)
        derivative(self.data, s, ds)
        return ds

    def constraint_forces(self, s: np.ndarray) -> np.ndarray:
        """M u̇ + h − Q_cmd − Q_damp at s with the current locks (nonzero only on locked DOFs)."""
        s = self._check(s)
        ds = np.empty_like(s)
        derivative(self.data, s, ds)
        forces = np.empty_like(s)
        holding_forces(self.data, s, ds, forces)
        return forces[:len(self.Q_cmd)].copy()
