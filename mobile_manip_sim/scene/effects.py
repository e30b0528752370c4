"""What a scene turns on, as the simulator runs it: the one place that turns a scene's `Effects`
into settings — dynamics options, damping coefficients, locked pseudo-velocities, effort limits,
the end-stop law. The engine, the plots, the URDF export and the tests all ask `settings(scene)`;
none reads `scene.effects` to re-derive them.

Each effect sets exactly one setting (`SETTING_OF_EFFECT`), and an effect that is off leaves its
setting absent (0.0, False, None or ()) — so the engine adds no stage for it (MuJoCo's
``disableflags``: skipped, not multiplied by zero). It sits at the scene layer (numpy only).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .coordinates import ARM_U, arm_size
from .loading import Scene, StrokeLimits
from .model import Base

# scene effect → the setting it sets (several effects may share one setting)
SETTING_OF_EFFECT = {
    "gravity": "gravity",
    "payload": "tip_mass",
    "wheel_inertia": "wheel_inertia",
    "joint_damping": "rate_damping",
    "wheel_damping": "rate_damping",
    "locked_joints": "locked",
    "fixed_base": "locked",
    "effort_limits": "effort_limits",
    "stroke_limits": "stop_law",
}


@dataclass(frozen=True)
class EffectSettings:
    """The settings of one scene's effects (fields absent when their effects are off)."""

    gravity: float = 0.0                     # g, m/s² along −z (dynamics option)
    tip_mass: float = 0.0                    # kg, point payload at the tip of rod n (dynamics
                                             # option)
    wheel_inertia: bool = False              # the wheels' spin inertia I_w counts (dynamics option)
    rate_damping: np.ndarray | None = None   # (2 + 2n,) viscous coefficients c on the joint rates
                                             # (θ̇_R, θ̇_L, q̇_1, l̇_1, …): effort −c·rate,
                                             # N·m·s/rad or N·s/m
    locked: tuple = ()                       # indices into u held at zero (locked joints,
                                             # fixed base)
    effort_limits: np.ndarray | None = None  # (2 + 2n,) bounds on |(τ_R, τ_L, τ_1, F_1, …)|,
                                             # N·m or N;
                                             # inf where the scene sets none
    stop_law: StrokeLimits | None = None     # the end stops' law; None: stops not watched

    def dynamics_options(self) -> dict:
        """Keyword arguments of `dynamics.Dynamics` for these settings."""
        return {"gravity": self.gravity, "tip_mass": self.tip_mass,
                "wheel_inertia": self.wheel_inertia}

    def generalized_damping(self, base: Base) -> np.ndarray | None:
        """(n_u,) diagonal viscous coefficients on u = (v, ω, q̇_1, l̇_1, …), or None (no
        damping stage). Both wheels share one coefficient c: wheel torques −c θ̇ with
        θ̇_R/L = (v ± bω)/r, projected, give Q_v = −2c v/r², Q_ω = −2c b² ω/r²."""
        if self.rate_damping is None:
            return None
        c = np.array(self.rate_damping, dtype=float)
        c_wheel = float(self.rate_damping[0])
        c[0] = 2.0 * c_wheel / base.wheel_radius ** 2
        c[1] = 2.0 * c_wheel * base.half_track ** 2 / base.wheel_radius ** 2
        return c

    def saturate(self, efforts, first: int = 0) -> np.ndarray:
        """Efforts (from entry `first` of (τ_R, τ_L, τ_1, F_1, …) on) clipped to the limits."""
        efforts = np.asarray(efforts, dtype=float)
        if self.effort_limits is None:
            return efforts
        limits = self.effort_limits[first:first + efforts.size]
        return np.clip(efforts, -limits, limits)


def settings(scene: Scene) -> EffectSettings:
    """The engine settings of `scene`'s effects (module doc)."""
    effects, robot = scene.effects, scene.robot
    n_arm = arm_size(robot.n_links)
    rate_damping = None
    if effects.wheel_damping or effects.joint_damping is not None:
        rate_damping = np.zeros(2 + n_arm)
        if effects.wheel_damping:
            rate_damping[:2] = effects.wheel_damping
        if effects.joint_damping is not None:
            rate_damping[ARM_U] = effects.joint_damping
    arm_names = robot.joint_names()[ARM_U]
    locked = [2 + arm_names.index(name) for name in effects.locked_joints]
    if effects.fixed_base:
        locked += [0, 1]
    effort_limits = None
    groups = effects.effort_limits or {}
    if any(groups.get(group) is not None for group in ("wheels", "joints")):
        effort_limits = np.full(2 + n_arm, np.inf)
        for group, where in (("wheels", slice(0, 2)), ("joints", slice(2, None))):
            if groups.get(group) is not None:
                effort_limits[where] = groups[group]
    return EffectSettings(gravity=effects.gravity, tip_mass=effects.payload or 0.0,
                          wheel_inertia=effects.wheel_inertia, rate_damping=rate_damping,
                          locked=tuple(sorted(locked)), effort_limits=effort_limits,
                          stop_law=effects.stroke_limits)
