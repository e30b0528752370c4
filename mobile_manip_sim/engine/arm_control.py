"""The arm controller inside the simulated system, as ros2_control's controllers drive an arm:
the settings' defaults for a robot (`for_robot`: the record itself, `scene.arm_controller.
ArmController`, is the scene layer's), the feed-forward's model (`feedforward_masses`,
`feedforward_model`) and the compiled control law that `system.applied_forces` runs at every
right-hand-side evaluation.

The law, per arm joint j (revolute τ_j in N·m, prismatic F_j in N), with the reference of
`arm_reference.py` evaluated at the reference clock τ (a state component, τ̇ = 1):

    e = q_ref − q,   ė = q̇_ref − q̇,   ż = e
    (e the shortest angle on the revolute joints, which are continuous: jtc's error)
    τ_j = sat(ff_j + kp e + kd ė + ki z)     within the scene's effort limits

The derivative acts on q̇_ref − q̇ (for a set-point q̇_ref = 0: on the measurement, so a step
of the set-point does not kick). Anti-windup: z stops integrating while the output is saturated
in the direction of the error. Feedforward ff:

- ``none``;
- ``gravity``: G(q), the project's inverse dynamics `kernels.gibbs_appell` at u = 0, u̇ = 0,
  in its reduced form (`dynamics.reduced.gravity_efforts`: with ω = α = 0 every point
  accelerates by g ẑ);
- ``computed_torque``: the inverse dynamics of the arm following q̈_ref, ``M u̇* + h(q, u) −
  Q_damp`` at the actual (q, u), with u̇* = (v̇*, ω̇*, q̈_ref) and the base's acceleration
  (v̇*, ω̇*) solved exactly rather than assumed zero: the base rows of the same equations, with
  the wheel forces and damping acting now, ``M_bb u̇_b* = Q_b − M_ba q̈_ref − h_b`` (3
  inverse-dynamics passes: one with q̈_ref, two unit base accelerations for M_bb and M_ab:
  `dynamics.reduced.base_acceleration`).
  A locked or resting arm joint is taken at u̇ = 0, a fixed base at u̇_b = 0.

Both model-based feed-forwards compute with `feedforward_model`: the plant's model record itself,
or with a model error (`scene.arm_controller.ModelError`) a record whose masses, inertias and
payload differ (held in ``system.ff_masses``), so computed torque no longer cancels the plant
exactly.

The controller's states z (n_arm) and τ follow W in s (`layout.arm_integrals`,
`layout.reference_clock`) and exist only when the arm is not in effort mode; in effort mode the
stage is never entered and s, every run and every bag are what they were without it.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..dynamics import indices, kernels
from ..dynamics.articulated import set_moving
from ..dynamics.jit import jit, jit_inline
from ..dynamics.records import BaseParameters, Model
from ..dynamics.reduced import base_acceleration, gravity_efforts
from ..scene.arm_controller import (
    DEFAULT_FEEDFORWARD,
    GAINS,
    ArmController,
    Feedforward,
    ModelError,
)
from ..scene.coordinates import ARM_U, OMEGA, V, arm_size
from ..scene.errors import UserError
from . import layout
from .arm_reference import (
    Q_REF,
    QD_REF,
    QDD_REF,
    is_continuous_jit,
    reference,
    shortest_angle_jit,
)

# system.arm[...] entries (ARM_SEGMENT: the reference segment of the last evaluation, a search hint)
ARM_ON, ARM_FEEDFORWARD, ARM_SEGMENTS, ARM_SEGMENT = range(4)
N_ARM_SETTINGS = 4
# the feed-forward kinds (system.arm[ARM_FEEDFORWARD])
FEEDFORWARD_NONE, FEEDFORWARD_GRAVITY, FEEDFORWARD_COMPUTED_TORQUE = (
    int(kind) for kind in Feedforward)
# system.arm_gains rows
GAIN_KP, GAIN_KI, GAIN_KD = range(3)
# system.arm_ref rows: the reference (arm_reference.Q_REF, QD_REF, QDD_REF), then
LAST_FF, LAST_TAU = 3, 4   # the feedforward and the applied efforts of the last evaluation
# system.arm_scratch rows (n_u each)
SCRATCH_UD, SCRATCH_QA, SCRATCH_COL_V, SCRATCH_COL_W, SCRATCH_ZERO = range(5)
# system.ff_masses entries (`feedforward_masses`), then μ (n) and J (n, 3, 3) flattened from FF_MU
FF_MASS, FF_YAW_INERTIA, FF_WHEEL_INERTIA, FF_TIP_MASS, FF_MU = range(5)

# Default gains (`default_controller`): each joint alone, with its diagonal inertia M_jj at the
# robot's reference pose (every q_k = 0, every rod at mid-stroke), is a critically damped PD of
# natural frequency ω_n — kp = M_jj ω_n², kd = 2 M_jj ω_n — plus a slow integral, ki = ε M_jj ω_n³
# (its zero at −ε ω_n: a small ε keeps the overshoot of a step near 1 %; the gravity
# feedforward leaves the integral only the residue), rounded to 2 significant digits.
# Paper robot: kp (170, 800, 34, 400), ki (17, 80, 3.4, 40), kd (17, 80, 3.4, 40).
DEFAULT_BANDWIDTH = 20.0        # ω_n, rad/s
DEFAULT_INTEGRAL_RATIO = 0.005  # ε


def for_robot(controller: ArmController, robot) -> ArmController:
    """`controller` with every gain given per joint (the robot's defaults filled in, one number
    repeated); a UserError if a list does not have one value per arm joint. Effort mode keeps
    no gains and no model error."""
    if not controller.active:
        return replace(controller, kp=(), ki=(), kd=(), model_error=ModelError())
    n_arm = arm_size(robot.n_links)
    defaults = default_gains(robot)
    gains = {}
    for row, name in enumerate(GAINS):
        value = getattr(controller, name)
        if len(value) == 0:
            value = tuple(defaults[row])
        elif len(value) == 1:
            value = value * n_arm
        if len(value) != n_arm:
            raise UserError(f"arm_gains.{name}", f"expected one number or {n_arm} (one per "
                                                 f"arm joint), got {len(value)}")
        gains[name] = value
    return replace(controller, **gains)


def default_controller(robot, mode: str = "position",
                       feedforward: str = DEFAULT_FEEDFORWARD) -> ArmController:
    """The documented defaults for `robot` (module constants; docs/controllers.md)."""
    return for_robot(ArmController(mode, feedforward=feedforward), robot)


def scene_arm_controller(section) -> ArmController:
    """The arm controller of a scene's ``controller:`` section (`scene.controller`); effort
    mode when there is none."""
    return ArmController() if section is None else section.arm_controller


def feedforward_masses(model, error: ModelError) -> np.ndarray:
    """``system.ff_masses``, the inertial parameters the feed-forward computes with: empty when
    `error` is exact (the plant's model record itself), else the plant's masses, inertias and
    payload changed by `error` (FF_MASS, FF_YAW_INERTIA, FF_WHEEL_INERTIA, FF_TIP_MASS, then μ
    and J flattened); `feedforward_model` makes the record, with the plant's geometry.

    One float array rather than a second `Model` record: every compiled call that takes the
    system's record (four right-hand sides per rk4 step, the event checks) is handed each of
    its arrays' descriptors one word at a time, so a record of records costs on every
    evaluation, even in effort mode where the feed-forward never runs."""
    if error.exact:
        return np.zeros(0)
    mass, inertia = 1.0 + error.mass, 1.0 + error.inertia
    base = model.base
    tip_mass = model.tip_mass if error.payload is None else float(error.payload)
    head = np.zeros(FF_MU)
    head[FF_MASS], head[FF_YAW_INERTIA] = base.mass * mass, base.yaw_inertia * inertia
    head[FF_WHEEL_INERTIA], head[FF_TIP_MASS] = base.wheel_inertia * inertia, tip_mass
    return np.concatenate((head, (model.mu * mass).ravel(), (model.J * inertia).ravel()))


@jit_inline
def feedforward_model(system):
    """The dynamics' model record (`dynamics.records.Model`) the feed-forward computes with:
    ``system.model`` itself, or with a model error one whose masses, inertias and payload are
    ``system.ff_masses``' (`feedforward_masses`); the geometry is the plant's."""
    f, model = system.ff_masses, system.model
    if f.shape[0] == 0:
        return model
    n, b = model.L.shape[0], model.base
    base = BaseParameters(f[FF_MASS], f[FF_YAW_INERTIA], b.com_offset, b.wheel_radius,
                          b.half_track, f[FF_WHEEL_INERTIA])
    return Model(base, model.mount, model.R0, model.L, f[FF_MU:FF_MU + n],
                 f[FF_MU + n:FF_MU + 10 * n].reshape((n, 3, 3)), f[FF_TIP_MASS])


def default_gains(robot) -> np.ndarray:
    """(3, n_arm) kp, ki, kd: the rule of DEFAULT_BANDWIDTH's comment."""
    from ..dynamics import Dynamics
    q = np.zeros(robot.n_q)
    q[6::2] = np.mean(np.asarray(robot.stroke).reshape(-1, 2), axis=1)
    inertia = np.diag(Dynamics(robot).mass_matrix(q))[ARM_U]
    w = DEFAULT_BANDWIDTH
    return np.array([round_2(inertia * w ** 2), round_2(DEFAULT_INTEGRAL_RATIO * inertia * w ** 3),
                     round_2(2.0 * inertia * w)])


def round_2(values) -> np.ndarray:
    """Each value rounded to two significant digits."""
    values = np.asarray(values, dtype=float)
    out = np.zeros_like(values)
    for i, v in enumerate(values):
        out[i] = float(f"{v:.2g}") if v > 0 else 0.0
    return out


def arm_settings(control: ArmController, effort_limits) -> tuple:
    """The compiled records' arrays for `control` (resolved, `for_robot`): settings (ARM_ON,
    ARM_FEEDFORWARD, ARM_SEGMENTS, ARM_SEGMENT), gains (3, n_arm) and effort limits (n_arm; inf
    where none)."""
    n_arm = len(control.kp)
    settings = np.zeros(N_ARM_SETTINGS)
    settings[ARM_ON] = 1.0 if control.active else 0.0
    settings[ARM_FEEDFORWARD] = control.feedforward_id
    gains = np.array([control.kp, control.ki, control.kd], dtype=float).reshape(3, n_arm)
    limits = np.full(n_arm, np.inf) if effort_limits is None else np.array(effort_limits[ARM_U])
    return settings, gains, limits


@jit_inline
def feedforward(system, s, ff):
    """The feedforward efforts (module doc) into ff (n_arm). Needs `kernels.frames` of s."""
    kind = system.arm[ARM_FEEDFORWARD]
    n_arm = ff.shape[0]
    if kind == FEEDFORWARD_NONE or (kind == FEEDFORWARD_GRAVITY and system.gravity == 0.0):
        for j in range(n_arm):
            ff[j] = 0.0
        return
    model, ws, scratch = feedforward_model(system), system.ws, system.arm_scratch
    damping = system.damping
    nq, nu = layout.sizes(system)
    q, u = s[:nq], s[nq:nq + nu]
    ud, Q_id = scratch[SCRATCH_UD], scratch[SCRATCH_QA]
    if kind == FEEDFORWARD_GRAVITY:
        gravity_efforts(model, q, system.gravity, ws, ff)
        return
    set_moving(system.free, ws.moving)
    ud[0], ud[1] = 0.0, 0.0
    for j in range(n_arm):
        ud[indices.arm_u(j)] = system.arm_ref[QDD_REF, j] * ws.moving[indices.arm_u(j)]
    kernels.gibbs_appell(model, q, u, ud, system.gravity, ws, Q_id)
    Qb0, Qb1 = system.Q[V], system.Q[OMEGA]
    if damping.shape[0] > 0:
        Qb0 -= damping[0] * u[0]
        Qb1 -= damping[1] * u[1]
    vd, omd = base_acceleration(model, ws, q, Qb0, Qb1, Q_id, scratch[SCRATCH_UD],
                                scratch[SCRATCH_ZERO], scratch[SCRATCH_COL_V],
                                scratch[SCRATCH_COL_W])
    for j in range(n_arm):
        ff[j] = Q_id[indices.arm_u(j)]
        if vd != 0.0 or omd != 0.0:
            i = indices.arm_u(j)
            ff[j] += scratch[SCRATCH_COL_V, i] * vd + scratch[SCRATCH_COL_W, i] * omd
        if damping.shape[0] > 0:
            ff[j] += damping[indices.arm_u(j)] * u[indices.arm_u(j)]


@jit
def arm_efforts(system, s, ds):
    """The arm's efforts into system.Q[2:] (and system.arm_ref[LAST_TAU]), ż and τ̇ into ds (module
    doc). Needs `kernels.frames` of s and the base's applied forces in system.Q[0:2].

    Compiled on its own, not inlined into the right-hand side: inlined, its code (the reference,
    the PID, the feed-forward's inverse dynamics) made every right-hand side slower, the runs
    without a controller too (measured on a two-core AMD EPYC: the paper scene's rk4 run some
    15 % slower, the computed-torque run 18 %). Even out of line, the call hands it the whole
    system record word by word, and its mere presence cost every evaluation some 35 ns: the
    right-hand side of an effort-mode run is compiled without it (`system.EffortSystemData`)."""
    nq, nu = layout.sizes(system)
    i_z, i_clock = layout.arm_integrals(nq, nu), layout.reference_clock(nq, nu)
    ref, gains, limits = system.arm_ref, system.arm_gains, system.arm_limits
    arm = system.arm
    arm[ARM_SEGMENT] = reference(system.ref_starts, system.ref_coeffs, int(arm[ARM_SEGMENTS]),
                                 s[i_clock], ref, int(arm[ARM_SEGMENT]))
    feedforward(system, s, ref[LAST_FF])
    for j in range(indices.arm_width(nu)):
        q_j = s[layout.arm_q(j)]
        e = (shortest_angle_jit(q_j, ref[Q_REF, j]) if is_continuous_jit(j)
             else ref[Q_REF, j] - q_j)
        ed = ref[QD_REF, j] - s[layout.arm_u(nq, j)]
        raw = (ref[LAST_FF, j] + gains[GAIN_KP, j] * e + gains[GAIN_KD, j] * ed
               + gains[GAIN_KI, j] * s[i_z + j])
        limit = limits[j]
        tau = min(max(raw, -limit), limit)
        system.Q[indices.arm_u(j)] = tau
        ref[LAST_TAU, j] = tau
        ds[i_z + j] = 0.0 if (raw > limit and e > 0.0) or (raw < -limit and e < 0.0) else e
    ds[i_clock] = 1.0


@jit_inline
def held_arm_efforts(system, s, ds):
    """Sampled (`sampling.py`): the efforts of the last update, held, into system.Q[2:]; the
    integrals z change only at updates (ż = 0), the reference clock runs (τ̇ = 1)."""
    nq, nu = layout.sizes(system)
    i_z, i_clock = layout.arm_integrals(nq, nu), layout.reference_clock(nq, nu)
    for j in range(indices.arm_width(nu)):
        system.Q[indices.arm_u(j)] = system.held[indices.arm_u(j)]
        ds[i_z + j] = 0.0
    ds[i_clock] = 1.0
