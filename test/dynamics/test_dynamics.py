"""Facts of docs/model.md that the dynamics core must satisfy, checked on random robots."""
import numpy as np
import pytest

from mobile_manip_sim.dynamics import Dynamics, constraint_residuals
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.scene.coordinates import V
from mobile_manip_sim.scene.loading import load_scene, parse_scene
from robots import random_robot_document, random_state

SEEDS = range(12)


@pytest.mark.parametrize("seed", SEEDS)
def test_mass_matrix_is_symmetric_positive_definite(seed):
    rng = np.random.default_rng(seed)
    scene = parse_scene(random_robot_document(rng, seed % 6))
    dyn = Dynamics(scene.robot, gravity=10.0)
    q, _ = random_state(rng, scene.robot)
    M = dyn.mass_matrix(q)
    np.testing.assert_allclose(M, M.T, rtol=0, atol=1e-13 * np.abs(M).max())
    assert np.linalg.eigvalsh(M).min() > 0


@pytest.mark.parametrize("seed", SEEDS)
def test_inverse_and_forward_dynamics_invert_each_other(seed):
    rng = np.random.default_rng(100 + seed)
    scene = parse_scene(random_robot_document(rng, seed % 6))
    dyn = Dynamics(scene.robot, gravity=9.81)
    q, u = random_state(rng, scene.robot)
    ud = rng.normal(size=scene.robot.n_u)
    Q = dyn.inverse_dynamics(q, u, ud)
    ud_back = dyn.forward_dynamics(q, u, Q)
    kappa = np.linalg.cond(dyn.mass_matrix(q))
    np.testing.assert_allclose(ud_back, ud, rtol=0, atol=kappa * 1e-14 * max(1.0, np.abs(ud).max()))


@pytest.mark.parametrize("seed", SEEDS)
def test_kinetic_energy_is_half_u_M_u(seed):
    """T from the velocities of every rod point equals ½ uᵀ M u with M from the recursion."""
    rng = np.random.default_rng(200 + seed)
    scene = parse_scene(random_robot_document(rng, seed % 6))
    dyn = Dynamics(scene.robot, gravity=0.0, tip_mass=rng.uniform(0, 1))
    q, u = random_state(rng, scene.robot)
    T, _ = dyn.energy(q, u)
    assert T == pytest.approx(0.5 * u @ dyn.mass_matrix(q) @ u, rel=1e-12)


@pytest.mark.parametrize("seed", SEEDS)
def test_energy_rate_equals_power_of_generalized_forces(seed):
    """d(T + V)/dt = Q·u along the motion u̇ = f(q, u, Q), at random states and efforts."""
    rng = np.random.default_rng(300 + seed)
    scene = parse_scene(random_robot_document(rng, seed % 6))
    dyn = Dynamics(scene.robot, gravity=10.0, tip_mass=0.3)
    q, u = random_state(rng, scene.robot)
    Q = rng.normal(size=scene.robot.n_u)
    qd, ud = dyn.configuration_rate(q, u), dyn.forward_dynamics(q, u, Q)
    eps = 1e-6
    E_plus = sum(dyn.energy(q + eps * qd, u + eps * ud))
    E_minus = sum(dyn.energy(q - eps * qd, u - eps * ud))
    rate = (E_plus - E_minus) / (2 * eps)
    assert rate == pytest.approx(Q @ u, rel=1e-6, abs=1e-7 * (1 + abs(E_plus)))


@pytest.mark.parametrize("seed", SEEDS)
def test_gravity_as_root_acceleration_equals_gravity_from_the_potential(seed):
    """h(q, 0) with gravity on is ∂V/∂u: the potential's rate along each pseudo-velocity."""
    rng = np.random.default_rng(400 + seed)
    scene = parse_scene(random_robot_document(rng, seed % 6))
    dyn = Dynamics(scene.robot, gravity=9.81, tip_mass=0.5)
    q, _ = random_state(rng, scene.robot)
    zero = np.zeros(scene.robot.n_u)
    G_trick = dyn.bias(q, zero)
    eps = 1e-6
    G_potential = []
    for k in range(scene.robot.n_u):
        qd = dyn.configuration_rate(q, np.eye(scene.robot.n_u)[k])
        V_plus, V_minus = dyn.energy(q + eps * qd, zero)[1], dyn.energy(q - eps * qd, zero)[1]
        G_potential.append((V_plus - V_minus) / (2 * eps))
    np.testing.assert_allclose(G_trick, G_potential, rtol=0,
                               atol=1e-7 * (1 + np.abs(G_trick).max()))


@pytest.mark.parametrize("gravity", [0.0, 10.0])
def test_energy_is_conserved_without_efforts(gravity):
    """Zero efforts, no dissipation, a tight DOP853: T + V stays put to 1e-9 relative over 5 s."""
    doc = random_robot_document(np.random.default_rng(7), 2, gravity=gravity)
    doc["integrator"] = {"method": "dop853", "rtol": 1e-12, "atol": 1e-12}
    sim = Simulation(parse_scene(doc))
    E0 = sim.total_energy()
    for k in range(1, 51):
        sim.advance_to(0.1 * k)
        assert sim.total_energy() == pytest.approx(E0, rel=1e-9)
    assert np.abs(sim.u).max() > 0.1  # it really moved


def test_constraint_residuals_stay_at_round_off_along_the_paper_run():
    sim = Simulation(load_scene())
    worst = 0.0
    for k in range(1, 151):
        sim.advance_to(0.01 * k)
        worst = max(worst, *map(abs, constraint_residuals(sim.model, sim.q, sim.qdot())))
    assert sim.u[V] != 0.0 and worst < 1e-14
