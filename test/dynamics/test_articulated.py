"""The O(n) articulated-body forward dynamics and the composite-rigid-body mass matrix, checked
against the slower formulations they replace, on random robots of 0–32 links.

Tolerances of solves scale with κ(M)·ε, as Drake's forward-dynamics tests do: an answer cannot
be more accurate than the conditioning of M allows, whichever algorithm computes it.
"""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

import robots
from mobile_manip_sim.dynamics import Dynamics, articulated, kernels
from mobile_manip_sim.scene.coordinates import SLIDES_U, rod

HELPERS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "helpers")
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
    nu = dyn.model.n_u
    M = np.empty((nu, nu))
    kernels.frames(dyn.model_record, q, dyn.ws)
    kernels.mass_matrix_by_columns(dyn.model_record, q, dyn.ws, np.zeros(nu), np.zeros(nu),
                                   np.zeros(nu), M)
    return M


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
        padded = np.full(nu, -1, dtype=np.int64)
        padded[:len(free)] = free
        ud = np.full(nu, np.nan)
        articulated.forward_dynamics(dyn.model_record, q, u, Q, dyn.gravity, padded, dyn.ws, ud)
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
            assert (abs(dyn.ws.slide_force[rod(j)] - transmitted[j])
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


def test_pure_python_and_compiled_kernels_agree():
    """The same source run as plain Python (MOBILE_MANIP_SIM_NO_JIT=1) and compiled gives the same
    numbers: mass matrix, bias, energies, the forward dynamics and the articulated pass with a
    locked DOF, on random robots of 0, 1, 2 and 7 links."""
    script = (
        "import json, sys, numpy as np\n"
        f"sys.path[:0] = {[os.path.dirname(__file__), HELPERS]!r}\n"
        "from test_articulated import random_robot\n"
        "from mobile_manip_sim.dynamics import articulated, jit, vec3\n"
        "out = {'compiled': jit.ENABLED, 'kind': type(vec3.add).__name__, 'values': []}\n"
        "for n in (0, 1, 2, 7):\n"
        "    rng, model, dyn, q, u, _ = random_robot(77 + n, n)\n"
        "    Q = rng.normal(size=model.n_u)\n"
        "    free = np.arange(model.n_u); free[1] = -1 if model.n_u > 2 else 1\n"
        "    ud = np.empty(model.n_u)\n"
        "    articulated.forward_dynamics(dyn.model_record, q, u, Q, dyn.gravity, free, dyn.ws,\n"
        "                                 ud)\n"
        "    out['values'] += [dyn.mass_matrix(q).tolist(), dyn.bias(q, u).tolist(),\n"
        "                      list(dyn.energy(q, u)), dyn.forward_dynamics(q, u, Q).tolist(),\n"
        "                      ud.tolist()]\n"
        "print(json.dumps(out))\n")
    results = []
    for no_jit in ("1", "0"):
        env = dict(os.environ, MOBILE_MANIP_SIM_NO_JIT=no_jit)
        completed = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                                   text=True, check=True)
        results.append(json.loads(completed.stdout))
    python, compiled = results
    assert python["compiled"] is False and python["kind"] == "function"          # really Python …
    assert compiled["compiled"] is True and compiled["kind"] == "CPUDispatcher"  # … really numba
    for python_value, compiled_value in zip(python["values"], compiled["values"], strict=True):
        np.testing.assert_allclose(np.array(python_value), np.array(compiled_value),
                                   rtol=1e-12, atol=1e-12)
