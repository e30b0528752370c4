"""The O(n) articulated-body forward dynamics and the composite-rigid-body mass matrix, checked
against the slower formulations they replace, on random robots of 0–32 links.

Tolerances of solves scale with κ(M)·ε, as Drake's forward-dynamics tests do: an answer cannot
be more accurate than the conditioning of M allows, whichever algorithm computes it.
"""
import numpy as np
import pytest

import robots
from mobile_manip_sim.dynamics import Dynamics
from mobile_manip_sim.scene.coordinates import SLIDES_U, rod

LINK_COUNTS = [0, 1, 2, 3, 4, 5, 8, 12, 16, 20, 24, 32]
EPS = np.finfo(float).eps


def random_robot(seed, n):
    """A random robot of n links (`robots.random_robot`), a random gravity and payload, and a
    random state with the extensions up to 10 % past the stops, reproducible from seed."""
    rng = np.random.default_rng(seed)
    model = robots.random_robot(rng, n)
    dyn = Dynamics(model, gravity=rng.uniform(0.0, 12.0),
                   tip_mass=0.0 if seed % 3 == 0 else rng.uniform(0.1, 3.0))
    q, u = robots.random_state(rng, model, beyond=0.1)
    return rng, model, dyn, q, u, rng.normal(size=model.n_u)


def by_columns(dyn, q):
    """M column by column: column j is the inverse dynamics at rest without gravity of the unit
    acceleration u̇ = e_j."""
    nu = dyn.model.n_u
    return np.column_stack([dyn.inverse_dynamics(q, np.zeros(nu), np.eye(nu)[j], gravity=0.0)
                            for j in range(nu)])


@pytest.mark.parametrize("n", LINK_COUNTS)
def test_composite_mass_matrix_equals_column_by_column_inverse_dynamics(n):
    for seed in range(3):
        _, _, dyn, q, _, _ = random_robot(1000 * n + seed, n)
        M, M_ref = dyn.mass_matrix(q), by_columns(dyn, q)
        assert np.abs(M - M_ref).max() <= 1e-12 * np.abs(M_ref).max(), np.abs(M - M_ref).max()
        assert np.array_equal(M, M.T)


@pytest.mark.parametrize("n", LINK_COUNTS)
def test_articulated_forward_dynamics_equals_mass_matrix_solve(n):
    """u̇ = M⁻¹ (Q − h), with M and h from the Gibbs–Appell passes, to κ(M)·ε."""
    for seed in range(4):
        rng, _, dyn, q, u, _ = random_robot(3000 * n + seed, n)
        Q = rng.normal(size=dyn.model.n_u) * 10.0
        M = dyn.mass_matrix(q)
        ud_ref = np.linalg.solve(M, Q - dyn.bias(q, u))
        ud = dyn.forward_dynamics(q, u, Q)
        tol = 10.0 * np.linalg.cond(M) * EPS * max(1.0, np.abs(ud_ref).max())
        assert np.abs(ud - ud_ref).max() <= tol, (np.abs(ud - ud_ref).max(), tol)


@pytest.mark.parametrize("n", [0, 1, 2, 5, 16, 32])
def test_articulated_forward_dynamics_inverts_inverse_dynamics(n):
    for seed in range(4):
        _, _, dyn, q, u, ud = random_robot(4000 * n + seed, n)
        Q = dyn.inverse_dynamics(q, u, ud)
        tol = 10.0 * np.linalg.cond(dyn.mass_matrix(q)) * EPS * max(1.0, np.abs(ud).max())
        assert np.abs(dyn.forward_dynamics(q, u, Q) - ud).max() <= tol


@pytest.mark.parametrize("n", [0, 1, 2, 4, 9])
def test_locked_pseudo_velocities_get_zero_acceleration_and_the_reduced_solve(n):
    """A locked DOF (resting rod, locked joint, fixed base) drops out: u̇_f = M_ff⁻¹ (Q − h)_f."""
    for seed in range(6):
        rng, _, dyn, q, u, _ = random_robot(5000 * n + seed, n)
        nu = dyn.model.n_u
        locked = sorted(set(rng.choice(nu, size=rng.integers(1, nu + 1), replace=False).tolist()))
        if seed == 0:
            locked = [0, 1]  # a fixed base
        free = [k for k in range(nu) if k not in locked]
        u[locked] = 0.0
        Q = rng.normal(size=nu)
        M, h = dyn.mass_matrix(q), dyn.bias(q, u)
        ud_ref = np.zeros(nu)
        if free:
            ud_ref[free] = np.linalg.solve(M[np.ix_(free, free)], (Q - h)[free])
        moving = np.zeros(nu)
        moving[free] = 1.0
        ud = dyn.forward_dynamics(q, u, Q, moving)
        slide_force = dyn.core.slide_forces()
        assert np.all(ud[locked] == 0.0)
        kappa = np.linalg.cond(M[np.ix_(free, free)]) if free else 1.0
        tol = 10.0 * kappa * EPS * max(1.0, np.abs(ud_ref).max())
        assert np.abs(ud - ud_ref).max() <= tol
        # The force each locked slide transmits, read off the same pass, is the generalized
        # force M u̇ + h of its l̇_k (what its stop must supply beyond Q).
        slides = [j for j in locked if j in range(nu)[SLIDES_U]]
        transmitted = M @ ud_ref + h
        for j in slides:
            scale = 1.0 + np.abs(M[j]).max() * np.abs(ud_ref).max() + abs(h[j])
            assert (abs(slide_force[rod(j)] - transmitted[j])
                    <= 1e3 * kappa * EPS * scale)


def test_cholesky_and_articulated_paths_agree_on_the_paper_robot():
    from mobile_manip_sim.scene.loading import load_scene
    dyn = Dynamics(load_scene().robot, gravity=10.0, tip_mass=0.2)
    rng = np.random.default_rng(11)
    for _ in range(20):
        q, u = robots.random_state(rng, dyn.model)
        Q = rng.normal(size=dyn.model.n_u)
        np.testing.assert_allclose(dyn.forward_dynamics(q, u, Q),
                                   dyn.forward_dynamics_by_cholesky(q, u, Q),
                                   rtol=1e-11, atol=1e-12)
