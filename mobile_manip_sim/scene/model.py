"""The immutable robot model: what docs/model.md calls the parameters, in SI units.

A `RobotModel` is built once from a scene (see `scene.py`) and shared by every simulation of
that scene; per-simulation scratch space lives in the compiled core (`Dynamics.core`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .coordinates import q_size, u_size


def _frozen(values, shape) -> np.ndarray:
    array = np.array(values, dtype=float).reshape(shape)
    array.setflags(write=False)
    return array


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """URDF convention: R = Rz(yaw) · Ry(pitch) · Rx(roll)."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


@dataclass(frozen=True)
class Base:
    """Differential-drive base (docs/model.md table): M_pw, I_pw, d, r, b, I_w."""

    mass: float            # M_pw, kg: base + wheels
    yaw_inertia: float     # I_pw, kg·m²: about the vertical through G
    com_offset: float      # d, m: from A forward to G
    wheel_radius: float    # r, m
    half_track: float      # b, m: from A to each wheel centre
    wheel_inertia: float   # I_w, kg·m²: spin inertia of one wheel about its axle


@dataclass(frozen=True)
class RobotModel:
    """Base plus a serial arm of `n_links` revolute–prismatic pairs.

    Per-link arrays are indexed by link (0-based here, 1-based in docs/model.md):
    ``joint_rotation[i]`` is R0_i (3×3, parent joint frame → joint frame before q_i),
    ``length[i]`` is L_i (m), ``mass_per_length[i]`` μ_i (kg/m),
    ``inertia_per_length[i]`` J_i (3×3 kg·m, link frame), ``stroke[i]`` the [min, max] of l_i (m).
    ``mount`` is m, the first joint's position in base_link (m).
    """

    base: Base
    mount: np.ndarray
    joint_rotation: np.ndarray
    length: np.ndarray
    mass_per_length: np.ndarray
    inertia_per_length: np.ndarray
    stroke: np.ndarray
    joint_rpy: np.ndarray = field(default=None)

    @staticmethod
    def build(base: Base, mount, links: list[dict]) -> "RobotModel":
        """Links as dicts with length, mass_per_length, inertia_per_length (3×3), joint_rpy,
        stroke."""
        n = len(links)
        rpy = np.array([link["joint_rpy"] for link in links], dtype=float).reshape(n, 3)
        return RobotModel(
            base=base,
            mount=_frozen(mount, (3,)),
            joint_rotation=_frozen([rpy_matrix(*angles) for angles in rpy], (n, 3, 3)),
            length=_frozen([link["length"] for link in links], (n,)),
            mass_per_length=_frozen([link["mass_per_length"] for link in links], (n,)),
            inertia_per_length=_frozen([link["inertia_per_length"] for link in links], (n, 3, 3)),
            stroke=_frozen([link["stroke"] for link in links], (n, 2)),
            joint_rpy=_frozen(rpy, (n, 3)),
        )

    @property
    def n_links(self) -> int:
        return len(self.length)

    @property
    def n_q(self) -> int:
        """Configuration size: x, y, yaw, θ_R, θ_L, then q_i, l_i per link."""
        return q_size(self.n_links)

    @property
    def n_u(self) -> int:
        """Pseudo-velocity size: v, ω, then q̇_i, l̇_i per link."""
        return u_size(self.n_links)

    def joint_names(self) -> list[str]:
        """Names used in /joint_states and the URDF: wheels, then per link revolute, prismatic."""
        names = ["right_wheel_joint", "left_wheel_joint"]
        for i in range(1, self.n_links + 1):
            names += [f"arm_revolute_{i}", f"arm_prismatic_{i}"]
        return names
