"""MuJoCo's peer: the equivalent UNCONSTRAINED model of a `RobotModel`, as MJCF.

The same bodies as docs/model.md's robot, built as an ordinary MuJoCo tree:

- ``base``: slide x, slide y (world axes), hinge z at A; body mass M_pw at G = (d, 0, 0), yaw
  inertia I_pw about G (the roll and pitch components are I_pw too: planar motion never uses them).
- two wheels, hinges about base +y at (0, −b, 0) (right) and (0, +b, 0) (left), spin inertia I_w
  (a thin disc: I_w/2 about the two other axes). MuJoCo wants a mass on every moving body, so each
  wheel gets WHEEL_MASS_FRACTION of M_pw at its axle, taken back out of the base body with its
  first and second moments: the base + wheels keep mass M_pw, centre G and yaw inertia I_pw about
  G, which is all planar motion sees. Without wheel inertia the wheels are left out.
  With a fixed base (``base_pose`` = x, y, yaw) the base is welded there: no base joints, no wheels,
  and MuJoCo's robot is then exactly ours (v = ω = 0 leaves nothing to constrain).
- per arm link k one body with two joints, composed in order: a hinge about z of the joint frame
  (the body's frame: R0_k, at the mount for k = 1 and at the distal end of rod k−1 for k > 1),
  then a slide along the rotated x. The body's frame moves with the slide to η = l_k, the rod's
  distal end, so the rod occupies x ∈ [−L_k, 0] there (it slides through its joint) and the next
  link's body is placed at the origin. Inertial: μL at (−L/2, 0, 0), μL³/12 about y and z plus
  L·J; the payload, a point mass at the last rod's distal end, is folded into the last rod.

Contacts, constraints, joint limits, damping and armature are off; motors with gear 1 apply the
efforts (wheel torques, joint efforts). Nothing ties the wheels to the ground: MuJoCo's robot is
the unconstrained one whose mass matrix, projected with S(yaw) on our pseudo-velocities, is ours.
"""
from __future__ import annotations

import numpy as np

from ..scene.coordinates import ARM_Q, ARM_U, BASE_POSE, YAW, arm_size

try:
    import mujoco
except ImportError:  # the bench reports the MuJoCo section as skipped
    mujoco = None


WHEEL_MASS_FRACTION = 0.01


def available() -> bool:
    return mujoco is not None


def _num(value) -> str:
    return repr(float(value))


def _vec(values) -> str:
    return " ".join(_num(v) for v in values)


def _quat(R) -> str:
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(R, dtype=float).ravel())
    return _vec(quat)


def _combined(parts):
    """(mass, centre, inertia about the centre) of rigidly joined (mass, centre, inertia) parts."""
    mass = sum(m for m, _, _ in parts)
    centre = sum(m * np.asarray(c, dtype=float) for m, c, _ in parts) / mass
    inertia = np.zeros((3, 3))
    for m, c, I in parts:
        r = np.asarray(c, dtype=float) - centre
        inertia += np.asarray(I, dtype=float) + m * (r @ r * np.eye(3) - np.outer(r, r))
    return mass, centre, inertia


def _inertial(mass, centre, inertia) -> str:
    I = np.asarray(inertia, dtype=float)
    return (f'<inertial pos="{_vec(centre)}" mass="{_num(mass)}" '
            f'fullinertia="{_vec((I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]))}"/>')


def rod_inertial(length: float, mass_per_length: float, J, tip_mass: float = 0.0):
    """(mass, centre, inertia about the centre) of rod k in its body frame (distal end at 0)."""
    mass = mass_per_length * length
    bending = mass * length ** 2 / 12.0
    parts = [(mass, (-0.5 * length, 0.0, 0.0),
              np.diag([0.0, bending, bending]) + np.asarray(J) * length)]
    if tip_mass > 0.0:
        parts.append((tip_mass, (0.0, 0.0, 0.0), np.zeros((3, 3))))
    return _combined(parts)


def mjcf(robot_model, gravity: float = 0.0, tip_mass: float = 0.0, wheel_inertia: bool = True,
         integrator: str = "RK4", dt: float = 1e-3, energy: bool = False, base_pose=None) -> str:
    """The MJCF text of the equivalent unconstrained model (see the module docstring); `energy`
    turns on MuJoCo's per-step energy computation (off for timing)."""
    base, n = robot_model.base, robot_model.n_links
    I_w = base.wheel_inertia if wheel_inertia and base_pose is None else 0.0
    M, d, b = base.mass, base.com_offset, base.half_track
    m_w = WHEEL_MASS_FRACTION * M if I_w > 0.0 else 0.0
    body_mass = M - 2 * m_w
    body_x = M * d / body_mass
    # yaw inertia about A: I_pw + M d² = yaw + body_mass body_x² + 2 (m_w b² + I_w / 2)
    yaw = base.yaw_inertia + M * d ** 2 - body_mass * body_x ** 2 - 2 * m_w * b ** 2 - I_w
    if yaw <= 0.0:
        raise ValueError("the base's yaw inertia is too small for MuJoCo's wheel bodies")
    lines = ['<mujoco model="mobile_manipulator_unconstrained">',
             '  <compiler angle="radian" inertiafromgeom="false" autolimits="false"/>',
             f'  <option timestep="{_num(dt)}" integrator="{integrator}" '
             f'gravity="0 0 {_num(-gravity)}">',
             '    <flag contact="disable" constraint="disable" limit="disable" equality="disable"'
             ' frictionloss="disable" warmstart="disable"'
             f' energy="{"enable" if energy else "disable"}"/>',
             '  </option>',
             '  <worldbody>',
             '    <body name="base">' if base_pose is None else
             f'    <body name="base" pos="{_num(base_pose[0])} {_num(base_pose[1])} 0" '
             f'quat="{_vec((np.cos(base_pose[2] / 2), 0.0, 0.0, np.sin(base_pose[2] / 2)))}">']
    if base_pose is None:
        lines += ['      <joint name="x" type="slide" axis="1 0 0"/>',
                  '      <joint name="y" type="slide" axis="0 1 0"/>',
                  '      <joint name="yaw" type="hinge" axis="0 0 1"/>']
    lines += ['      ' + _inertial(body_mass, (body_x, 0.0, 0.0), np.diag([yaw, yaw, yaw]))]
    if I_w > 0.0:
        for name, side in (("right_wheel", -1.0), ("left_wheel", 1.0)):
            lines += [f'      <body name="{name}" pos="0 {_num(side * base.half_track)} 0">',
                      f'        <joint name="{name}_joint" type="hinge" axis="0 1 0"/>',
                      '        ' + _inertial(m_w, (0.0, 0.0, 0.0),
                                             np.diag([I_w / 2, I_w, I_w / 2])),
                      '      </body>']
    indent = "      "
    for k in range(n):
        pos = robot_model.mount if k == 0 else (0.0, 0.0, 0.0)
        inertial = rod_inertial(float(robot_model.length[k]), float(robot_model.mass_per_length[k]),
                                robot_model.inertia_per_length[k], tip_mass if k == n - 1 else 0.0)
        lines += [f'{indent}<body name="rod_{k + 1}" pos="{_vec(pos)}" '
                  f'quat="{_quat(robot_model.joint_rotation[k])}">',
                  f'{indent}  <joint name="arm_revolute_{k + 1}" type="hinge" axis="0 0 1"/>',
                  f'{indent}  <joint name="arm_prismatic_{k + 1}" type="slide" axis="1 0 0"/>',
                  f'{indent}  ' + _inertial(*inertial)]
        indent += "  "
    for _ in range(n):   # close the bodies, innermost first
        indent = indent[:-2]
        lines.append(f'{indent}</body>')
    lines += ['    </body>', '  </worldbody>', '  <actuator>']
    joints = (["right_wheel_joint", "left_wheel_joint"] if I_w > 0.0 else []) + \
        [f"arm_{kind}_{k + 1}" for k in range(n) for kind in ("revolute", "prismatic")]
    lines += [f'    <motor joint="{name}" gear="1"/>' for name in joints]
    lines += ['  </actuator>', '</mujoco>']
    return "\n".join(lines) + "\n"


class MujocoPeer:
    """The compiled MuJoCo model of a robot plus the map S(yaw) from our u to MuJoCo's qvel.

    qpos = (x, y, yaw, θ_R, θ_L, q_1, l_1, …) is our q (without the wheel angles when the wheels
    are left out, only the arm's with a fixed base); qvel = S(yaw) u with ẋ = v cos yaw,
    ẏ = v sin yaw, yaw rate ω, wheel rates (v ± bω)/r, then the joint rates.
    """

    def __init__(self, robot_model, gravity: float = 0.0, tip_mass: float = 0.0,
                 wheel_inertia: bool = True, integrator: str = "RK4", dt: float = 1e-3,
                 energy: bool = False, base_pose=None):
        self.robot_model = robot_model
        self.fixed_base = base_pose is not None
        self.wheels = wheel_inertia and robot_model.base.wheel_inertia > 0.0 and not self.fixed_base
        self.xml = mjcf(robot_model, gravity, tip_mass, wheel_inertia, integrator, dt, energy,
                        base_pose)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        n = robot_model.n_links
        self.arm = 0 if self.fixed_base else 5 if self.wheels else 3   # first arm index in qpos
        assert self.model.nv == self.arm + arm_size(n)

    def qpos(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        return (q[ARM_Q] if self.fixed_base else q if self.wheels
                else np.concatenate([q[BASE_POSE], q[ARM_Q]]))

    def S(self, q) -> np.ndarray:
        base, n = self.robot_model.base, self.robot_model.n_links
        r, b, yaw = base.wheel_radius, base.half_track, float(q[YAW])
        S = np.zeros((self.model.nv, self.robot_model.n_u))
        if not self.fixed_base:
            S[0, 0], S[1, 0], S[2, 1] = np.cos(yaw), np.sin(yaw), 1.0
        if self.wheels:
            S[3, 0], S[3, 1] = 1.0 / r, b / r
            S[4, 0], S[4, 1] = 1.0 / r, -b / r
        S[self.arm:, ARM_U] = np.eye(arm_size(n))
        return S

    def set_state(self, q, u) -> None:
        self.data.qpos[:] = self.qpos(q)
        self.data.qvel[:] = self.S(q) @ np.asarray(u, dtype=float)
        mujoco.mj_forward(self.model, self.data)

    def full_mass_matrix(self, q) -> np.ndarray:
        self.set_state(q, np.zeros(self.robot_model.n_u))
        M = np.zeros((self.model.nv, self.model.nv))
        mujoco.mj_fullM(self.model, self.data, M)
        return M

    def mass_matrix(self, q) -> np.ndarray:
        """Sᵀ M_full S: MuJoCo's mass matrix on our pseudo-velocities."""
        S = self.S(q)
        return S.T @ self.full_mass_matrix(q) @ S

    def energy(self, q, u) -> tuple[float, float]:
        """(kinetic, potential) in J as MuJoCo computes them."""
        self.set_state(q, u)
        mujoco.mj_energyPos(self.model, self.data)
        mujoco.mj_energyVel(self.model, self.data)
        return float(self.data.energy[1]), float(self.data.energy[0])

    def control(self, wheels, joints) -> np.ndarray:
        """The actuator vector for our efforts (wheel torques R, L; joint efforts τ_1, F_1, …)."""
        return np.concatenate([wheels if self.wheels else [], joints]).astype(float)


def for_scene(scene, integrator: str = "RK4", dt: float = 1e-3) -> MujocoPeer:
    """The peer of a scene's robot with its gravity, payload and wheel-inertia flags."""
    effects = scene.effects
    return MujocoPeer(scene.robot, effects.gravity, effects.payload or 0.0, effects.wheel_inertia,
                      integrator, dt,
                      base_pose=scene.initial_q[BASE_POSE] if effects.fixed_base else None)
