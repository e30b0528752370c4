"""The arm reference (`engine/arm_reference.py`): joint_trajectory_controller's interpolation as
piecewise polynomials of the reference clock — each kind passes through what the points give
(positions; velocities; accelerations), is continuous where it should be, starts at the state
of the arm at the command and holds the last point afterwards."""
import numpy as np
import pytest

from mobile_manip_sim.engine import arm_reference
from mobile_manip_sim.engine.arm_reference import Q_REF, QD_REF, QDD_REF

RNG = np.random.default_rng(18)
N_ARM = 4
TIMES = np.array([0.4, 1.0, 1.3])
P = RNG.normal(0.0, 0.5, (3, N_ARM))
V = RNG.normal(0.0, 1.0, (3, N_ARM))
A = RNG.normal(0.0, 3.0, (3, N_ARM))
Q0, QD0 = RNG.normal(0.0, 0.5, N_ARM), RNG.normal(0.0, 1.0, N_ARM)


def evaluate(starts, coeffs, tau):
    out = np.zeros((3, coeffs.shape[1]))
    for hint in (0, starts.size - 1, starts.size // 2):   # the result does not depend on it
        arm_reference.reference(starts, coeffs, starts.size, float(tau), out, hint)
        if hint == 0:
            first = out.copy()
        assert np.array_equal(out, first)
    return out


def knots(times):
    return np.concatenate([[0.0], times])


@pytest.mark.parametrize("kind", ["linear", "cubic", "quintic"])
def test_each_kind_passes_through_its_points_and_starts_at_the_state_now(kind):
    V_, A_ = (None, None) if kind == "linear" else (V, None) if kind == "cubic" else (V, A)
    starts, coeffs = arm_reference.trajectory(Q0, QD0, TIMES, P, V_, A_)
    assert np.array_equal(starts, knots(TIMES))     # one segment per point, then the hold
    start = evaluate(starts, coeffs, 0.0)
    assert np.allclose(start[Q_REF], Q0, atol=1e-14)
    if kind != "linear":
        assert np.allclose(start[QD_REF], QD0, atol=1e-12)
    if kind == "quintic":
        assert np.allclose(start[QDD_REF], 0.0, atol=1e-10)   # the state's acceleration: zero
    for i, t in enumerate(TIMES[:-1]):
        at = evaluate(starts, coeffs, t)             # the next segment, at its start
        just_before = evaluate(starts, coeffs, np.nextafter(t, 0.0))
        assert np.allclose(at[Q_REF], P[i], atol=1e-12)
        assert np.allclose(just_before[Q_REF], P[i], atol=1e-9)     # continuous position
        if kind != "linear":
            assert np.allclose(at[QD_REF], V[i], atol=1e-10)
            assert np.allclose(just_before[QD_REF], V[i], atol=1e-8)   # continuous velocity
        if kind == "quintic":
            assert np.allclose(at[QDD_REF], A[i], atol=1e-8)
            assert np.allclose(just_before[QDD_REF], A[i], atol=1e-6)  # continuous acceleration


def test_linear_moves_at_constant_velocity_between_points():
    starts, coeffs = arm_reference.trajectory(Q0, QD0, TIMES, P)
    for t in (0.5, 0.7, 0.95):   # inside the segment from point 0 (0.4 s) to point 1 (1.0 s)
        ref = evaluate(starts, coeffs, t)
        assert np.allclose(ref[QD_REF], (P[1] - P[0]) / 0.6, atol=1e-12)
        assert np.allclose(ref[Q_REF], P[0] + (t - 0.4) * (P[1] - P[0]) / 0.6, atol=1e-12)
        assert np.array_equal(ref[QDD_REF], np.zeros(N_ARM))


def test_the_last_point_is_held():
    starts, coeffs = arm_reference.trajectory(Q0, QD0, TIMES, P, V, A)
    for t in (TIMES[-1], 2.0, 1e5):
        ref = evaluate(starts, coeffs, t)
        assert np.array_equal(ref[Q_REF], P[-1])
        assert np.array_equal(ref[QD_REF], np.zeros(N_ARM))
        assert np.array_equal(ref[QDD_REF], np.zeros(N_ARM))


def test_a_first_point_at_time_zero_starts_the_trajectory_there():
    times = np.array([0.0, 0.5])
    starts, coeffs = arm_reference.trajectory(Q0, QD0, times, P[:2], V[:2])
    assert np.array_equal(starts, times)   # no segment from the state now
    assert np.allclose(evaluate(starts, coeffs, 0.0)[Q_REF], P[0], atol=1e-14)
    assert np.allclose(evaluate(starts, coeffs, 0.0)[QD_REF], V[0], atol=1e-12)


def test_hold_and_ramp():
    starts, coeffs = arm_reference.hold(P[0])
    assert np.array_equal(evaluate(starts, coeffs, 3.0), np.array([P[0], np.zeros(N_ARM),
                                                                   np.zeros(N_ARM)]))
    starts, coeffs = arm_reference.ramp(Q0, V[0])
    ref = evaluate(starts, coeffs, 2.5)
    assert np.allclose(ref[Q_REF], Q0 + 2.5 * V[0], atol=1e-14)
    assert np.array_equal(ref[QD_REF], V[0])


def test_the_polynomials_match_numerical_derivatives():
    """q̇_ref and q̈_ref are the derivatives of q_ref (central differences inside a segment)."""
    starts, coeffs = arm_reference.trajectory(Q0, QD0, TIMES, P, V, A)
    h = 1e-5
    for t in (0.2, 0.61, 1.17):
        minus, mid, plus = (evaluate(starts, coeffs, t + d) for d in (-h, 0.0, h))
        assert np.allclose((plus[Q_REF] - minus[Q_REF]) / (2 * h), mid[QD_REF], rtol=1e-6,
                           atol=1e-6)
        assert np.allclose((plus[QD_REF] - minus[QD_REF]) / (2 * h), mid[QDD_REF], rtol=1e-5,
                           atol=1e-5)
