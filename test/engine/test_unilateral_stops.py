"""Several stops at once (docs/model.md; core/include/mms/stops.hpp `solve_contacts`): each
stop only pushes, restitution on the stop being hit, 0 on resting ones, a resting rod that its
stop would have to pull leaves it, and energy never rises in an impact."""
import itertools
from importlib import resources

import numpy as np
import pytest

from mobile_manip_sim.core import solve_contacts
from mobile_manip_sim.engine import layout
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.scene.loading import make_integrator, parse_scene, scene_from_text

L_1 = layout.q_slide(1)   # l_1 in q


def embedded(name):
    return scene_from_text(resources.files("mobile_manip_sim").joinpath("config", name).read_text(),
                           name)


@pytest.mark.parametrize("method", ["rk4", "dop853"])
def test_two_rods_the_resting_one_leaves_as_the_unilateral_law_says(method):
    """The scene's header derives the numbers: M = [[2, 1], [1, 1]] along (l̇1, l̇2), contacts
    rod 1 upper (σ = −1, e = 0) and rod 2 lower (σ = +1, e = 0.5): W = [[1, 1], [1, 2]],
    q = (0, −1.5); rod 2 active alone: P2 = 0.75, w1 = 0.75 > 0, so rod 1 leaves at 0.75 m/s."""
    scene = embedded("two_rod_unilateral.yaml")
    sim = Simulation(scene, make_integrator(scene.integrator, method))
    assert sim.resting[0] == 1   # rod 1 at rest on its upper stop, pressed: held from t = 0
    while not any(i.link == 2 for i in sim.impacts):
        sim.advance_to(sim.t + 0.001)
    first_hit = next(i for i, impact in enumerate(sim.impacts) if impact.link == 2)
    impact, detail = sim.impacts[first_hit], sim.impact_details[first_hit]
    assert first_hit == 0   # rod 1 never hit its stop: it rested there (docs/model.md)
    j1, j2 = 3, 5
    assert detail.u_before[j1] == 0.0 and detail.u_before[j2] == pytest.approx(-1.0, abs=1e-12)
    assert detail.u_after[j1] == pytest.approx(-0.75, abs=1e-12)     # rod 1 leaves its stop
    assert detail.u_after[j2] == pytest.approx(0.5, abs=1e-12)       # −e l̇2⁻
    assert impact.energy_lost == pytest.approx(0.1875, abs=1e-12)
    # total momentum along the rods: m1 l̇1 + m2 (l̇1 + l̇2), no stop pulled on rod 1
    momentum = lambda u: 1.0 * u[j1] + 1.0 * (u[j1] + u[j2])
    assert momentum(detail.u_after) == pytest.approx(momentum(detail.u_before), abs=1e-12)
    sim.advance_to(sim.t + 0.001)
    assert sim.resting[0] == 0 and sim.q[L_1] < 1.0                    # really off its stop


def brute_force_lcp(W, q):
    """Every active set, the one that satisfies P ≥ 0, w ≥ 0 (unique for W positive definite)."""
    m = len(q)
    for size in range(m + 1):
        for active in itertools.combinations(range(m), size):
            P = np.zeros(m)
            if active:
                idx = list(active)
                P[idx] = np.linalg.solve(W[np.ix_(idx, idx)], -q[idx])
            w = W @ P + q
            if np.all(P >= -1e-12) and np.all(w >= -1e-12):
                return P
    raise AssertionError("no solution")


@pytest.mark.parametrize("seed", range(40))
def test_the_pivoting_solve_is_the_exact_complementarity_solution(seed):
    rng = np.random.default_rng(seed)
    m = int(rng.integers(1, 8))
    A = rng.normal(size=(m, m))
    W = A @ A.T + 0.1 * np.eye(m)
    q = rng.normal(size=m)
    P, w = solve_contacts(W, q)
    assert np.all(P >= 0.0) and np.all(w >= -1e-12) and abs(P @ w) < 1e-12
    assert np.allclose(P, brute_force_lcp(W, q), atol=1e-10)


def random_three_rod_scene(seed):
    rng = np.random.default_rng(seed)
    doc = embedded("hard_impacts.yaml").document
    doc["name"] = f"three_rods_{seed}"
    link = dict(doc["robot"]["arm"]["links"][1])
    doc["robot"]["arm"]["links"] = [
        {**link, "length": 1.0, "mass_per_length": float(rng.uniform(0.5, 2.0)),
         "joint_rpy": [float(a) for a in rng.uniform(-1.5, 1.5, 3)],
         "stroke": [float(rng.uniform(0.1, 0.4)), float(rng.uniform(0.6, 0.9))]} for _ in range(3)]
    doc["initial"]["joints"] = [float(x)
                                for x in np.ravel([[rng.uniform(-1, 1), 0.5] for _ in range(3)])]
    doc["initial"]["velocity"] = [0.0, 0.0, *map(float, rng.normal(0.0, 1.5, 6))]
    doc["efforts"] = {"wheels": [0.3, -0.1], "joints": [float(x) for x in rng.normal(0.0, 3.0, 6)]}
    doc["effects"]["stroke_limits"] = {"restitution": float(rng.uniform(0.0, 0.9)),
                                       "law": "impulse", "rest_speed": 0.01}
    doc["integrator"] = {"method": "rk4", "dt": 0.002}
    return parse_scene(doc)


def test_in_random_multi_rod_scenes_no_stop_ever_pulls():
    """Every impact, settling ones (slower than the rest speed) included: impulses P ≥ 0 on each
    contact (the rods hit and those resting, every rod at a stop in the impact's state), no
    contact left moving into its stop, energy not increased, and M (u⁺ − u⁻) = E P: the momentum
    of every free direction that is not a contact is kept. Only an impact held at an
    accumulation point (the Zeno guard) may hold a contact bilaterally, by at most the momentum
    of the tail it cuts off. Between impacts, at the end of every step, the stop of every
    resting rod pushes (its holding force changed sign inside a step: it was released there)."""
    pulled_under_the_old_law = checked = slow = 0
    for seed in range(12):
        sim = Simulation(random_three_rod_scene(seed))
        for t in np.arange(1, 1001) * 0.002:
            sim.advance_to(t)
            forces = sim.system.constraint_forces(sim.s)
            for k in np.flatnonzero(sim.resting) + 1:
                assert -sim.resting[k - 1] * forces[layout.u_slide(k)] >= -1e-9, (seed, t, k)
        permanent = set(sim.system.permanently_locked)
        for impact, d in zip(sim.impacts, sim.impact_details, strict=True):
            at_stop = {layout.u_slide(r): (1.0 if d.q[layout.q_slide(r)] == sim.stroke[r - 1, 0]
                                           else -1.0)
                       for r in range(1, 4) if d.q[layout.q_slide(r)] in sim.stroke[r - 1]}
            assert layout.u_slide(impact.link) in at_stop
            M = sim.dynamics.mass_matrix(d.q)
            impulse = M @ (d.u_after - d.u_before)
            others = [j for j in range(sim.nu) if j not in at_stop and j not in permanent]
            assert np.abs(impulse[others]).max(initial=0.0) < 1e-9 * (1 + np.abs(M).max())
            tol = 1e-4 if d.held else 1e-9
            for j, sigma in at_stop.items():
                assert sigma * impulse[j] >= -tol, (seed, impact)       # the stop pushes
                assert sigma * d.u_after[j] >= -1e-9, (seed, impact)    # none left moving in
            assert impact.energy_lost >= -1e-12
            checked += 1
            slow += abs(impact.ld_before) < 0.01
            resting_before = [j for j in at_stop if j not in d.free and j not in permanent]
            pulled_under_the_old_law += any(d.u_after[j] != 0.0 for j in resting_before)
    # the scenes do exercise the law, settling impacts included
    assert checked > 30 and pulled_under_the_old_law > 0 and slow > 5
