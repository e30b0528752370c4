"""The arm reference (`engine/arm_reference.py`): joint_trajectory_controller's interpolation as
piecewise polynomials of the reference clock — each kind passes through what the points give
(positions; velocities; accelerations), is continuous where it should be, starts at the state
of the arm at the command and holds the last point afterwards."""
import numpy as np
import pytest

from mobile_manip_sim import core
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
    """The core's evaluation (the one the controller runs), from any search hint alike."""
    first = core.arm_reference(starts, coeffs, float(tau), 0)
    for hint in (starts.size - 1, starts.size // 2):   # the result does not depend on it
        assert np.array_equal(core.arm_reference(starts, coeffs, float(tau), hint), first)
    return first


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


def test_the_last_point_is_held_as_jtc_samples_it():
    """After the last point jtc's `Trajectory::sample` returns that point itself, and on
    success repeats it (`set_success_trajectory_point`, "no matter if it has nonzero velocity
    or acceleration"): its position, its velocity and its acceleration as given — zero where
    the points give none — not the derivatives of a constant."""
    for V_, A_ in ((V, A), (V, None), (None, None)):
        starts, coeffs = arm_reference.trajectory(Q0, QD0, TIMES, P, V_, A_)
        for t in (TIMES[-1], 2.0, 1e5):
            ref = evaluate(starts, coeffs, t)
            assert np.array_equal(ref[Q_REF], P[-1])
            assert np.array_equal(ref[QD_REF], np.zeros(N_ARM) if V_ is None else V[-1])
            assert np.array_equal(ref[QDD_REF], np.zeros(N_ARM) if A_ is None else A[-1])


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


# --- continuous joints: the revolute ones (arm indices 0, 2, …), as jtc treats them -----------

TURN = 2.0 * np.pi


def test_the_shortest_angle_is_the_difference_moved_by_whole_turns_into_minus_pi_pi():
    """Against an independent formula (the argument of e^{i d}) on angles up to 1e4 rad; inside
    (−π, π] it is the plain difference bit for bit; −π maps to +π as angles::normalize_angle."""
    rng = np.random.default_rng(26)
    for start, end in rng.uniform(-1e4, 1e4, (2000, 2)):
        d = arm_reference.shortest_angle(start, end)
        assert -np.pi < d <= np.pi
        assert d == pytest.approx(np.angle(np.exp(1j * (end - start))), abs=1e-9)
        assert (end - start - d) / TURN == pytest.approx(round((end - start - d) / TURN),
                                                         abs=1e-9)
    for start, end in rng.uniform(-1.5, 1.5, (200, 2)):
        assert arm_reference.shortest_angle(start, end) == end - start
    assert arm_reference.shortest_angle(0.0, -np.pi) == np.pi
    assert arm_reference.shortest_angle(0.0, np.pi) == np.pi
    assert arm_reference.shortest_angle(3.0, -3.0) == pytest.approx(TURN - 6.0, abs=1e-15)


def test_a_trajectory_from_3_to_minus_3_rad_starts_a_turn_lower_and_goes_the_short_way():
    """jtc's `wraparound_joint`: the start state moves by whole turns towards the first point,
    so the reference of the revolute joints turns +0.283 rad (2π − 6), not −6; the prismatic
    joints are never wrapped (7 m away stays 7 m away)."""
    q0 = np.array([3.0, 0.3, 0.4 + 2 * TURN, 0.3])
    first = np.array([-3.0, 7.3, 0.5, 0.3])
    for V_ in (None, np.zeros((1, N_ARM))):
        starts, coeffs = arm_reference.trajectory(q0, np.zeros(N_ARM), [1.0], first[None, :], V_)
        start, end = evaluate(starts, coeffs, 0.0), evaluate(starts, coeffs, 1.0)
        assert start[Q_REF][0] == pytest.approx(3.0 - TURN, abs=1e-14)
        assert start[Q_REF][2] == pytest.approx(0.4, abs=1e-12)        # two turns down
        assert start[Q_REF][1] == 0.3 and start[Q_REF][3] == 0.3
        assert np.array_equal(end[Q_REF], first)
        turned = end[Q_REF] - start[Q_REF]
        assert turned[0] == pytest.approx(TURN - 6.0, abs=1e-14)       # +0.283 rad
        path = np.array([evaluate(starts, coeffs, t)[Q_REF][0] for t in np.linspace(0, 1, 21)])
        assert np.all(np.diff(path) >= 0.0)                             # never the long way


@pytest.mark.parametrize("q0, first, expected", [
    (0.0, np.pi, 0.0),              # exactly half a turn: the plain difference's way (jtc)
    (0.0, -np.pi, 0.0),
    (0.0, np.pi + 1e-10, 0.0),      # within jtc's 1e-9 of half a turn: still not moved
    (0.0, np.pi + 1e-6, TURN),      # beyond it: a turn up, then −π + 1e-6 to go
    (-10.0, 3.0, -10.0 + 2 * TURN),
    (1e4, 0.5, None),               # far away: moved to within half a turn of the point
])
def test_the_start_moves_by_whole_turns_as_jtc_wraparound_joint(q0, first, expected):
    moved = arm_reference.wrapped_start(np.array([q0, 0.0]), np.array([first, 0.0]))[0]
    if expected is None:
        assert abs(moved - first) <= np.pi and round((q0 - moved) / TURN) != 0
    else:
        assert moved == pytest.approx(expected, abs=1e-9)
    assert abs(first - moved) <= np.pi + 1e-9


def test_a_start_within_half_a_turn_is_kept_bit_for_bit():
    rng = np.random.default_rng(5)
    for _ in range(200):
        q0, first = rng.uniform(-20.0, 20.0, N_ARM), rng.uniform(-20.0, 20.0, N_ARM)
        first[0::2] = q0[0::2] + rng.uniform(-3.1, 3.1, 2)
        assert np.array_equal(arm_reference.wrapped_start(q0, first), q0)
