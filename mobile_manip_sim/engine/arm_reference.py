"""The arm's reference as a piecewise polynomial of the reference clock τ (s since the command).

Segment i starts at ``starts[i]`` (``starts[0] = 0``) and holds, per arm joint j, the
coefficients ``coeffs[i, j, 0:6]`` of a polynomial of degree ≤ 5 in the segment's local time
``t = τ − starts[i]``, and two constants added to its velocity and acceleration
(``coeffs[i, j, HELD_QD]``, ``coeffs[i, j, HELD_QDD]``: zero except where a trajectory's last
point is held); the last segment lasts for ever. So every command is one shape:

- a position set-point: one constant segment (q̇_ref = q̈_ref = 0);
- a velocity command: one linear segment from the position now, ``q_ref(τ) = q(0) + q̇_ref τ``;
- a trajectory (joint_trajectory_controller's spline interpolation): the arm's state at the
  command is the point at τ = 0 (its acceleration taken as zero), then one segment per point:
  positions only → linear (velocity piecewise constant), with velocities → cubic Hermite, with
  accelerations too → quintic; after the last point the reference IS the last point, as jtc
  samples it: its position, and its velocity and acceleration as given (zero when not given;
  a node goal's last velocity is zero, jtc's rule), not the derivatives of a constant. A
  first point at ``time_from_start = 0`` starts the trajectory at that point (no segment from
  the state now). Inside a segment the reference is a polynomial of τ, hence of simulated time:
  the integrators see a smooth right-hand side, and re-simulation is bit for bit.

The arm's revolute joints are continuous (no angle stops; ``continuous`` in the URDF), and as
joint_trajectory_controller does for continuous joints, a trajectory's start state is moved by
whole turns towards the first point (`wrapped_start`, jtc's ``wraparound_joint``) and position
errors are the shortest angle (`shortest_angle`, angles::shortest_angular_distance): a
trajectory from 3.0 rad to −3.0 rad turns +0.28 rad, not −6.

The compiled core evaluates it (core/include/mms/arm_control.hpp, at every right-hand side, or
at each update when sampled; `Simulation.arm_reference` reads it); the builders here are numpy.
"""
from __future__ import annotations

import math

import numpy as np

from ..core import vocabulary

# the layout the core evaluates (core/include/mms/arm_control.hpp `reference`)
N_COEFFS = vocabulary["REF_COEFFS"]
DEGREE = N_COEFFS - 1
# coeffs[i, j, ...] after the polynomial's: constants added to q̇_ref and q̈_ref (a held point)
HELD_QD, HELD_QDD = vocabulary["HELD_QD"], vocabulary["HELD_QDD"]
WIDTH = vocabulary["REF_WIDTH"]
TURN = 2.0 * math.pi
# jtc's wraparound_joint: a start exactly half a turn from the first point (within this, rad)
# keeps the direction of the plain difference
HALF_TURN_TOLERANCE = 1e-9
# rows of the evaluated reference (`Simulation.arm_reference`)
Q_REF, QD_REF, QDD_REF = 0, 1, 2


def is_continuous(j):
    """Arm joint j (0 … n_arm − 1: q_1, l_1, q_2, …) is a revolute joint, continuous: an angle
    and the same angle ± 2π are one pose."""
    return j % 2 == 0


def shortest_angle(start, end):
    """angles::shortest_angular_distance(start, end), rad: end − start moved by whole turns
    into (−π, π]. Inside that range it is the plain difference, bit for bit."""
    d = end - start
    if -math.pi < d <= math.pi:
        return d
    r = np.fmod(d + math.pi, 2.0 * math.pi)   # angles::normalize_angle (C fmod)
    return r + math.pi if r <= 0.0 else r - math.pi


def position_errors(desired, actual) -> np.ndarray:
    """desired − actual per arm joint (n_arm), the shortest angle on the continuous ones: the
    error jtc's tolerances and PID read (``compute_error_for_joint``)."""
    desired, actual = np.asarray(desired, dtype=float), np.asarray(actual, dtype=float)
    error = desired - actual
    for j in range(error.size):
        if is_continuous(j):
            error[j] = shortest_angle(float(actual[j]), float(desired[j]))
    return error


def wrapped_start(q0, first) -> np.ndarray:
    """jtc's ``wraparound_joint``: the start state q0 with each continuous joint moved by whole
    turns to within half a turn of the first point (at exactly half a turn, within
    HALF_TURN_TOLERANCE, towards the first point's side of q0); joints that need no whole
    turn keep their value bit for bit."""
    q = np.array(q0, dtype=float)
    for j in range(q.size):
        if not is_continuous(j):
            continue
        dist = shortest_angle(float(q[j]), float(first[j]))
        if abs(abs(dist) - math.pi) < HALF_TURN_TOLERANCE:
            dist = abs(dist) if first[j] > q[j] else -abs(dist)
        moved = first[j] - dist
        if round((q[j] - moved) / TURN) != 0:
            q[j] = moved
    return q


def hold(q) -> tuple[np.ndarray, np.ndarray]:
    """(starts, coeffs) of a set-point: q_ref = q for ever."""
    q = np.asarray(q, dtype=float)
    coeffs = np.zeros((1, q.size, WIDTH))
    coeffs[0, :, 0] = q
    return np.zeros(1), coeffs


def ramp(q0, qd) -> tuple[np.ndarray, np.ndarray]:
    """(starts, coeffs) of a velocity command: q_ref(τ) = q0 + q̇_ref τ for ever."""
    starts, coeffs = hold(q0)
    coeffs[0, :, 1] = qd
    return starts, coeffs


def linear(p0, p1, h) -> np.ndarray:
    """Coefficients (…, n_arm, 6) from p0 to p1 in h seconds at constant velocity (p0, p1:
    (…, n_arm); h: (…, 1): any number of segments at once)."""
    c = np.zeros(p0.shape + (WIDTH,))
    c[..., 0], c[..., 1] = p0, (p1 - p0) / h
    return c


def cubic(p0, v0, p1, v1, h) -> np.ndarray:
    """Cubic Hermite: positions and velocities at both ends."""
    c = np.zeros(p0.shape + (WIDTH,))
    c[..., 0], c[..., 1] = p0, v0
    c[..., 2] = (3.0 * (p1 - p0) - (2.0 * v0 + v1) * h) / h ** 2
    c[..., 3] = (2.0 * (p0 - p1) + (v0 + v1) * h) / h ** 3
    return c


def quintic(p0, v0, a0, p1, v1, a1, h) -> np.ndarray:
    """Quintic: positions, velocities and accelerations at both ends."""
    c = np.zeros(p0.shape + (WIDTH,))
    c[..., 0], c[..., 1], c[..., 2] = p0, v0, 0.5 * a0
    c[..., 3] = (20.0 * (p1 - p0) - (8.0 * v1 + 12.0 * v0) * h
                 - (3.0 * a0 - a1) * h * h) / (2.0 * h ** 3)
    c[..., 4] = (30.0 * (p0 - p1) + (14.0 * v1 + 16.0 * v0) * h
                 + (3.0 * a0 - 2.0 * a1) * h * h) / (2.0 * h ** 4)
    c[..., 5] = (12.0 * (p1 - p0) - 6.0 * (v1 + v0) * h - (a0 - a1) * h * h) / (2.0 * h ** 5)
    return c


def trajectory(q0, qd0, times, positions, velocities=None, accelerations=None):
    """(starts, coeffs) of a trajectory from the state (q0, q̇0) now (module doc), q0 moved by
    whole turns towards the first point (`wrapped_start`). `times` (m,) strictly increasing,
    ≥ 0; positions (m, n_arm); velocities, accelerations (m, n_arm) or None (accelerations
    need velocities). Checked by the caller."""
    times = np.asarray(times, dtype=float)
    P = np.asarray(positions, dtype=float)
    V = None if velocities is None else np.asarray(velocities, dtype=float)
    A = None if accelerations is None else np.asarray(accelerations, dtype=float)
    first = 1 if times[0] == 0.0 else 0   # 1: the trajectory starts at its first point
    knots_t = np.concatenate(([0.0], times[first:]))
    start = P[0] if first else wrapped_start(q0, P[0])
    KP = np.concatenate((start[None, :], P[first:]))
    if V is not None:
        v0 = V[0] if first else np.asarray(qd0, dtype=float)
        KV = np.concatenate((v0[None, :], V[first:]))
    if A is not None:
        a0 = A[0] if first else np.zeros_like(start)
        KA = np.concatenate((a0[None, :], A[first:]))
    # every segment at once (a 100,000-point trajectory took a second segment by segment)
    h = np.diff(knots_t)[:, None]
    if V is None:
        pieces = linear(KP[:-1], KP[1:], h)
    elif A is None:
        pieces = cubic(KP[:-1], KV[:-1], KP[1:], KV[1:], h)
    else:
        pieces = quintic(KP[:-1], KV[:-1], KA[:-1], KP[1:], KV[1:], KA[1:], h)
    segments = np.concatenate((pieces, np.zeros((1,) + pieces.shape[1:])))
    held = segments[-1]   # the last point as jtc samples it after its time
    held[:, 0] = KP[-1]
    held[:, HELD_QD] = 0.0 if V is None else V[-1]
    held[:, HELD_QDD] = 0.0 if A is None else A[-1]
    return knots_t, segments
