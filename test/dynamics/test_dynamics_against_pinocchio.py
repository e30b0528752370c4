"""docs/model.md fact: an independent formulation gives the same M and h.

The Gibbs–Appell core (`mobile_manip_sim.dynamics`) is compared with the robot built as an
ordinary multibody in Pinocchio (`pinocchio_reference.py`): M = Sᵀ M_full S, h = Sᵀ h_full(q, S u),
on random robots (0–6 links and 10, random joint rpy, masses, lengths, cross-section inertias, base
parameters, payloads) in random states.
"""
import numpy as np
import pytest

from mobile_manip_sim.dynamics import Dynamics
from pinocchio_reference import build_projected_model
from robots import random_configuration, random_robot, random_state

SEEDS = list(range(60))
TOL = 1e-9


def random_case(seed, n=None):
    """A random robot (n links, default seed % 7), gravity, payload and state (the extensions up to
    10 % past the stops), from `seed`."""
    rng = np.random.default_rng(seed)
    n = seed % 7 if n is None else n  # every link count 0–6 appears
    model = random_robot(rng, n)
    gravity = rng.uniform(5.0, 12.0)
    tip_mass = 0.0 if seed % 3 == 0 else rng.uniform(0.1, 3.0)
    wheel_inertia = seed % 5 != 4
    q, u = random_state(rng, model, beyond=0.1)
    ud = rng.normal(size=model.n_u)
    dyn = Dynamics(model, gravity=gravity, tip_mass=tip_mass, wheel_inertia=wheel_inertia)
    ref = build_projected_model(model, gravity, tip_mass=tip_mass, wheel_inertia=wheel_inertia)
    return rng, model, dyn, ref, q, u, ud


# every link count 0–6 over SEEDS, and three 10-link robots
@pytest.mark.parametrize("seed, n",
                         [(seed, None) for seed in SEEDS] + [(2000 + s, 10) for s in range(3)])
def test_mass_matrix_equals_projected_pinocchio_crba(seed, n):
    _, _, dyn, ref, q, _, _ = random_case(seed, n)
    M, M_ref = dyn.mass_matrix(q), ref.mass_matrix(q)
    assert np.max(np.abs(M - M_ref)) <= 1e-12 * np.max(np.abs(M_ref)), (M - M_ref)


@pytest.mark.parametrize("seed, gravity", [(seed, True) for seed in SEEDS]
                         + [(seed, False) for seed in SEEDS[::4]])
def test_bias_equals_projected_pinocchio_rnea(seed, gravity):
    _, model, dyn, ref, q, u, _ = random_case(seed)
    if not gravity:
        ref = build_projected_model(model, 0.0, tip_mass=dyn.tip_mass,
                                    wheel_inertia=dyn.wheel_inertia)
    h, h_ref = dyn.bias(q, u, gravity=None if gravity else 0.0), ref.bias(q, u)
    assert np.max(np.abs(h - h_ref)) <= TOL * max(np.max(np.abs(h_ref)), 1.0), (h - h_ref)


@pytest.mark.parametrize("seed", SEEDS[::3])
def test_inverse_dynamics_equals_projected_pinocchio_rnea(seed):
    _, _, dyn, ref, q, u, ud = random_case(seed)
    Q, Q_ref = dyn.inverse_dynamics(q, u, ud), ref.inverse_dynamics(q, u, ud)
    assert np.max(np.abs(Q - Q_ref)) <= TOL * max(np.max(np.abs(Q_ref)), 1.0), (Q - Q_ref)


@pytest.mark.parametrize("seed", SEEDS)
def test_tip_position_equals_pinocchio_last_rod_frame_origin(seed):
    _, _, dyn, ref, q, _, _ = random_case(seed)
    tip, tip_ref = dyn.joint_origins(q)[-1], ref.tip_position(q)
    assert np.allclose(tip, tip_ref, rtol=0.0, atol=1e-12), (tip, tip_ref)


@pytest.mark.parametrize("seed", SEEDS)
def test_kinetic_energy_equals_pinocchio_kinetic_energy(seed):
    _, _, dyn, ref, q, u, _ = random_case(seed)
    T, _ = dyn.energy(q, u)
    T_ref = ref.kinetic_energy(q, u)
    assert abs(T - T_ref) <= TOL * max(abs(T_ref), 1.0), (T, T_ref)


@pytest.mark.parametrize("seed", SEEDS)
def test_potential_energy_equals_pinocchio_potential_up_to_a_constant(seed):
    rng, model, dyn, ref, q, u, _ = random_case(seed)
    q2 = random_configuration(rng, model)   # the base moves in the plane too: V must not see it
    _, V1 = dyn.energy(q, u)
    _, V2 = dyn.energy(q2, u)
    dV_ref = ref.potential_energy(q2) - ref.potential_energy(q)
    scale = max(abs(ref.potential_energy(q)), abs(ref.potential_energy(q2)), 1.0)
    assert abs((V2 - V1) - dV_ref) <= TOL * scale, (V2 - V1, dV_ref)


@pytest.mark.parametrize("seed", SEEDS[::5] + [2000])
def test_exact_jacobians_equal_projected_pinocchio_rnea_derivatives(seed):
    """The core's dual-number Jacobians of u̇ against Pinocchio's analytic RNEA derivatives of the
    ordinary multibody, projected: with u̇ solving Sᵀ rnea(q, S u, S u̇) = Q,
    ∂u̇/∂u = −M⁻¹ Sᵀ ∂τ/∂v S, ∂u̇/∂q_k = −M⁻¹ Sᵀ ∂τ/∂q_k (a joint of the arm or a wheel: the same
    coordinate in both), ∂u̇/∂Q = M⁻¹; the base's pose enters neither (both zero)."""
    import pinocchio as pin
    rng, model, dyn, ref, q, u, _ = random_case(seed, 10 if seed == 2000 else None)
    nq, nu = model.n_q, model.n_u
    Q = rng.normal(size=nu)
    M, h = ref.mass_matrix(q), ref.bias(q, u)
    ud = np.linalg.solve(M, Q - h)   # Pinocchio's own u̇
    S = ref.S
    dtau_dq, dtau_dv, _ = pin.computeRNEADerivatives(ref.model, ref.data,
                                                     ref.full_configuration(q), S @ u, S @ ud)
    s = np.concatenate([q, u, np.zeros(3)])
    rates, d_dx, d_dQ = dyn.core.jacobians("", s, 0.0, Q, np.eye(nu), np.zeros(0), np.ones(nu),
                                           dyn.gravity)
    scale = max(1.0, np.abs(d_dx).max(), np.abs(d_dQ).max())
    assert np.abs(rates[nq:] - ud).max() <= 1e-10 * max(1.0, np.abs(ud).max())
    joints = list(range(3, nq))   # wheels, then the arm: q[3:] are Pinocchio's v[3:] too
    expected = {"u": -np.linalg.solve(M, S.T @ dtau_dv @ S),
                "joints": -np.linalg.solve(M, S.T @ dtau_dq[:, joints]),
                "Q": np.linalg.inv(M)}
    ours = {"u": d_dx[nq:, nq:], "joints": d_dx[nq:, joints], "Q": d_dQ[nq:]}
    for name, value in expected.items():
        assert np.abs(ours[name] - value).max() <= 1e-10 * scale, name
    assert np.abs(d_dx[nq:, :3]).max() <= 1e-12 * scale   # x, y, yaw: the dynamics do not see them
