"""The arm controller inside the simulated system, as ros2_control's controllers drive an arm:
the settings' defaults for a robot (`for_robot`: the record itself, `scene.arm_controller.
ArmController`, is the scene layer's), the feed-forward's model (`feedforward_masses`) and the
arrays the compiled control law reads (`arm_settings`; the law is core/include/mms/
arm_control.hpp, run at every right-hand-side evaluation, or at each update when sampled).

The law, per arm joint j (revolute τ_j in N·m, prismatic F_j in N), with the reference of
`arm_reference.py` evaluated at the reference clock τ (a state component, τ̇ = 1):

    e = q_ref − q,   ė = q̇_ref − q̇,   ż = e
    (e the shortest angle on the revolute joints, which are continuous: jtc's error)
    τ_j = sat(ff_j + kp e + kd ė + ki z)     within the scene's effort limits

The derivative acts on q̇_ref − q̇ (for a set-point q̇_ref = 0: on the measurement, so a step
of the set-point does not kick). Anti-windup: z stops integrating while the output is saturated
in the direction of the error. Feedforward ff:

- ``none``;
- ``gravity``: G(q), the project's inverse dynamics at u = 0, u̇ = 0, in its reduced form (with
  ω = α = 0 every point accelerates by g ẑ);
- ``computed_torque``: the inverse dynamics of the arm following q̈_ref, ``M u̇* + h(q, u) −
  Q_damp`` at the actual (q, u), with u̇* = (v̇*, ω̇*, q̈_ref) and the base's acceleration
  (v̇*, ω̇*) solved exactly rather than assumed zero: the base rows of the same equations, with
  the wheel forces and damping acting now, ``M_bb u̇_b* = Q_b − M_ba q̈_ref − h_b`` (3
  inverse-dynamics passes: one with q̈_ref, two unit base accelerations for M_bb and M_ab).
  A locked or resting arm joint is taken at u̇ = 0, a fixed base at u̇_b = 0.

Both model-based feed-forwards compute with the plant's model itself, or with a model error
(`scene.arm_controller.ModelError`) a model whose masses, inertias and payload differ (held in
``system.ff_masses``), so computed torque no longer cancels the plant exactly.

The controller's states z (n_arm) and τ follow W in s (`layout.arm_integrals`,
`layout.reference_clock`) and exist only when the arm is not in effort mode; in effort mode the
stage is never entered and s, every run and every bag are what they were without it.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..scene.arm_controller import (
    DEFAULT_FEEDFORWARD,
    GAINS,
    ArmController,
    Feedforward,
    ModelError,
)
from ..scene.coordinates import ARM_U, arm_size
from ..scene.errors import UserError

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


def feedforward_masses(dynamics, error: ModelError) -> np.ndarray:
    """``system.ff_masses``, the inertial parameters the feed-forward computes with: empty when
    `error` is exact (the plant's own model), else the plant's (`dynamics`: its robot, payload
    and wheel inertia) masses, inertias and payload changed by `error` (FF_MASS, FF_YAW_INERTIA,
    FF_WHEEL_INERTIA, FF_TIP_MASS, then μ and J flattened); the core makes the model from them,
    with the plant's geometry."""
    if error.exact:
        return np.zeros(0)
    mass, inertia = 1.0 + error.mass, 1.0 + error.inertia
    robot = dynamics.model
    base = robot.base
    wheel_inertia = base.wheel_inertia if dynamics.wheel_inertia else 0.0
    tip_mass = dynamics.tip_mass if error.payload is None else float(error.payload)
    head = np.zeros(FF_MU)
    head[FF_MASS], head[FF_YAW_INERTIA] = base.mass * mass, base.yaw_inertia * inertia
    head[FF_WHEEL_INERTIA], head[FF_TIP_MASS] = wheel_inertia * inertia, tip_mass
    return np.concatenate((head, (np.asarray(robot.mass_per_length, dtype=float) * mass).ravel(),
                           (np.asarray(robot.inertia_per_length, dtype=float) * inertia).ravel()))


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

