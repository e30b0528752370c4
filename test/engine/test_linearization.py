"""`Simulation.linearize` and `Simulation.step_jacobians` — exact Jacobians by dual numbers through
the compiled core — against central differences of the engine's own right-hand side and of the
core's double step (the map the dual instance differentiates), on random robots with payloads,
damping, locked joints and rods held at a stop, for every fixed-step method and a sweep of step
sizes."""
import numpy as np
import pytest

import robots
from differences import best_agreement
from mobile_manip_sim.engine.linearization import effort_map, moving_mask
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.scene.coordinates import SLIDES_U
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.loading import IntegratorSettings, load_scene, parse_scene

FIXED = ("euler", "semi_implicit_euler", "rk4")


def random_simulation(seed, n, method="rk4", dt=1e-3, effort_limits=None):
    """A random robot of n links with a payload, joint and wheel damping, one locked joint (when
    n ≥ 2), random efforts and a random state; the rod of link 1 held at a stop (locked as the
    engine locks a resting rod) when seed is odd."""
    rng = np.random.default_rng(seed)
    doc = robots.random_robot_document(rng, n)
    names = [f"arm_{kind}_{k}" for k in range(1, n + 1) for kind in ("revolute", "prismatic")]
    doc["effects"]["wheel_damping"] = float(rng.uniform(0.0, 0.3))
    if n:
        doc["effects"].update({"payload": float(rng.uniform(0.1, 2.0)),
                               "joint_damping": rng.uniform(0.0, 0.5, 2 * n).tolist()})
    if n >= 2:
        doc["effects"]["locked_joints"] = [names[2]]
    if effort_limits is not None:
        doc["effects"]["effort_limits"] = effort_limits
    doc["integrator"] = {"method": method, "dt": dt}
    sim = Simulation(parse_scene(doc))
    sim.set_efforts(wheels=rng.normal(size=2), joints=rng.normal(size=2 * n))
    q, u = robots.random_state(rng, sim.model)
    for k in sim.system.permanently_locked:
        u[k] = 0.0
    sim.set_state(q, u)
    if seed % 2 and n:
        held = range(sim.nu)[SLIDES_U][0]
        sim.system.set_locked((held,))
    return sim


class EngineMaps:
    """The engine's own right-hand side and step of x = (q, u) and τ, through its compiled
    kernels: the efforts enter as the engine takes them, Q_cmd = B τ."""

    def __init__(self, sim):
        self.sim, self.nq, self.nu = sim, sim.nq, sim.nu
        self.B = effort_map(sim.model)
        self.tau = np.concatenate([sim.wheel_efforts, sim.joint_efforts])
        self.s = sim.s.copy()

    def _state(self, x, tau):
        s = self.s.copy()
        s[:self.nq + self.nu] = x
        self.sim.system.Q_cmd[:] = self.B @ tau
        return s

    def rate(self, x, tau):
        Q_cmd = self.sim.system.Q_cmd.copy()
        rate = self.sim.system.derivative(self._state(x, tau))[:self.nq + self.nu]
        self.sim.system.Q_cmd[:] = Q_cmd   # the simulation's efforts as they were
        return rate

    def step(self, x, tau, method, h):
        """One step of the core's double instance (the map the dual one differentiates)."""
        sim = self.sim
        s = self.s.copy()
        s[:self.nq + self.nu] = x
        out = sim.dynamics.core.step(method, s, h, self.B @ tau, sim.system.damping,
                                     moving_mask(sim), sim.dynamics.gravity)
        return out[:self.nq + self.nu]


@pytest.mark.parametrize("n", [0, 1, 2, 3, 5])
@pytest.mark.parametrize("seed", [1, 2])
def test_linearize_agrees_with_central_differences_of_the_engines_right_hand_side(seed, n):
    sim = random_simulation(seed, n)
    maps = EngineMaps(sim)
    x = np.concatenate([sim.q, sim.u])
    F_x, F_tau = sim.linearize()
    assert best_agreement(lambda x: maps.rate(x, maps.tau), x, F_x) <= 1e-8
    assert best_agreement(lambda tau: maps.rate(x, tau), maps.tau, F_tau) <= 1e-8
    for k in sim.system.locked:   # held pseudo-velocities stay still: zero rows
        assert not F_x[sim.nq + k].any() and not F_tau[sim.nq + k].any()


@pytest.mark.parametrize("method", FIXED)
@pytest.mark.parametrize("dt", [1e-3, 1e-2])
@pytest.mark.parametrize("n", [0, 2, 4])
def test_step_jacobians_are_the_derivative_of_the_engines_step_map(method, dt, n):
    sim = random_simulation(7 + n, n, method=method, dt=dt)
    maps = EngineMaps(sim)
    x = np.concatenate([sim.q, sim.u])
    A, B = sim.step_jacobians()
    assert best_agreement(lambda x: maps.step(x, maps.tau, method, dt), x, A) <= 1e-8
    assert best_agreement(lambda tau: maps.step(x, tau, method, dt), maps.tau, B) <= 1e-8
    # a step of another length, asked for explicitly
    A2, _ = sim.step_jacobians(dt=2 * dt)
    assert best_agreement(lambda x: maps.step(x, maps.tau, method, 2 * dt), x, A2) <= 1e-8


def test_an_effort_held_at_its_limit_has_no_influence_and_one_inside_it_has():
    limits = {"wheels": 0.05, "joints": [100.0, 100.0, 100.0, 100.0]}
    sim = random_simulation(4, 2, effort_limits=limits)
    sim.set_efforts(wheels=[1.0, 0.01], joints=[0.5, -0.5, 0.2, 0.1])
    _, F_tau = sim.linearize()
    assert not F_tau[:, 0].any()                       # τ_R clamped at 0.05
    acting = [k for k in range(1, sim.nu) if k not in sim.system.locked]   # not a locked joint's
    assert len(acting) == sim.nu - 2 and np.abs(F_tau[:, acting]).max(axis=0).min() > 0


def test_the_paper_scene_linearizes_at_its_start_into_the_documented_shapes():
    sim = Simulation(load_scene(), integrator=IntegratorSettings(method="rk4", dt=1e-3))
    F_x, F_tau = sim.linearize()
    A, B = sim.step_jacobians()
    assert F_x.shape == A.shape == (15, 15) and F_tau.shape == B.shape == (15, 6)
    assert np.isfinite(A).all() and np.isfinite(B).all()


def test_what_is_not_differentiated_is_refused_in_one_line():
    sim = Simulation(load_scene())   # dop853: adaptive
    with pytest.raises(UserError, match="step_jacobians differentiates the steps of euler"):
        sim.step_jacobians()
    sim.set_base_velocity(0.5, 0.0)
    with pytest.raises(UserError, match="velocity commands"):
        sim.linearize()
    with pytest.raises(UserError, match=r"q\[0\]"):
        Simulation(load_scene()).linearize(q=[np.nan] + 8 * [0.0])


def test_many_states_at_once_equal_each_state_alone():
    """`step_jacobians_many` (one compiled loop) gives, state by state, what `step_jacobians`
    gives at that state, with efforts per state (one of them clamped by its limit)."""
    from mobile_manip_sim.engine.linearization import step_jacobians_many
    limits = {"wheels": 0.5, "joints": [3.0, 3.0, 3.0, 3.0]}
    sim = random_simulation(9, 2, effort_limits=limits)
    rng = np.random.default_rng(9)
    states = [robots.random_state(rng, sim.model) for _ in range(5)]
    q, u = np.array([s[0] for s in states]), np.array([s[1] for s in states])
    u[:, list(sim.system.permanently_locked)] = 0.0
    efforts = rng.normal(size=(5, sim.nu))
    efforts[:, 0] = 0.1
    efforts[2, 0] = 7.0                          # beyond its limit: a zero column there
    A, B = step_jacobians_many(sim, q, u, efforts)
    assert A.shape == (5, sim.nq + sim.nu, sim.nq + sim.nu) and B.shape == (5, A.shape[1], sim.nu)
    for i in range(5):
        sim.set_efforts(wheels=efforts[i, :2], joints=efforts[i, 2:])
        A_i, B_i = sim.step_jacobians(q[i], u[i])
        assert np.array_equal(A[i], A_i) and np.array_equal(B[i], B_i)
    assert not B[2, :, 0].any() and B[1, :, 0].any()


def test_jacobians_along_a_run_are_those_of_its_steps_and_flag_the_impacts():
    """Along the paper run (rk4, 2 ms, its end stops), every step's (A, B) is the step Jacobian
    at the state the step starts from, and the steps that hold an impact are the ones flagged."""
    from mobile_manip_sim.engine.linearization import jacobians_along
    scene = load_scene()
    sim = Simulation(scene, integrator=IntegratorSettings(method="rk4", dt=0.002))
    twin = Simulation(scene, integrator=IntegratorSettings(method="rk4", dt=0.002))
    t, A, B, event = jacobians_along(sim, 1.5)
    assert t.size == 750 and A.shape == (750, 15, 15) and B.shape == (750, 15, 6)
    assert event.sum() == len(sim.impacts) > 0
    for k in (0, 123, int(np.flatnonzero(event)[0]), 749):
        twin.advance_to(t[k])
        A_k, B_k = twin.step_jacobians()
        assert np.array_equal(A[k], A_k) and np.array_equal(B[k], B_k)
