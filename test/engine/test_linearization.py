"""`Simulation.linearize` and `Simulation.step_jacobians` — exact Jacobians by dual numbers through
the compiled core — against central differences of the core's own `double` right-hand side and
step (`core.Dynamics.rates`, `.step`), and, for steps that hold an impact, a rod coming to rest or
a release, of the engine's whole step (the compiled stepper's double run, events included), on
random robots with payloads, damping, locked joints and rods held at a stop, for every fixed-step
method and a sweep of step sizes."""
import numpy as np
import pytest

import robots
from differences import best_agreement
from mobile_manip_sim.engine.linearization import (
    effort_map,
    jacobians_along,
    moving_mask,
    reference_jacobian,
    step_jacobians_many,
)
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.scene.arm_controller import ArmController
from mobile_manip_sim.scene.coordinates import SLIDES_U
from mobile_manip_sim.scene.errors import SimulationError, UserError
from mobile_manip_sim.scene.loading import IntegratorSettings, load_scene, parse_scene

FIXED = ("euler", "semi_implicit_euler", "rk4")
# perturbations small enough to keep a step's events in it (central differences, extrapolated)
EVENT_STEPS = (1e-5, 3e-6, 1e-6)


def random_simulation(seed, n, method="rk4", dt=1e-3, effort_limits=None, stops=None):
    """A random robot of n links with a payload, joint and wheel damping, one locked joint (when
    n ≥ 2), random efforts and a random state; the rod of link 1 held at a stop (locked as the
    engine locks a resting rod) when seed is odd; `stops` the scene's stroke_limits."""
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
    if stops is not None:
        doc["effects"]["stroke_limits"] = stops
    doc["integrator"] = {"method": method, "dt": dt}
    sim = Simulation(parse_scene(doc))
    sim.set_efforts(wheels=rng.normal(size=2), joints=rng.normal(size=2 * n))
    q, u = robots.random_state(rng, sim.model)
    for k in sim.system.permanently_locked:
        u[k] = 0.0
    sim.set_state(q, u)
    if seed % 2 and n and stops is None:
        held = range(sim.nu)[SLIDES_U][0]
        sim.system.set_locked((held,))
    return sim


class CoreMaps:
    """The compiled core's own `double` right-hand side and step of x = (q, u) and τ (the
    instantiations for double of the templates the dual numbers differentiate): the efforts enter
    as the engine takes them, Q_cmd = B τ, with the simulation's damping and locks."""

    def __init__(self, sim):
        self.core, self.g = sim.dynamics.core, sim.dynamics.gravity
        self.damping, self.moving = sim.system.damping, moving_mask(sim)
        self.nx = sim.nq + sim.nu
        self.B = effort_map(sim.model)
        self.tau = np.concatenate([sim.wheel_efforts, sim.joint_efforts])
        self.s = sim.s[:self.nx + 3].copy()

    def _state(self, x):
        s = self.s.copy()
        s[:self.nx] = x
        return s

    def rate(self, x, tau):
        return self.core.rates(self._state(x), self.B @ tau, self.damping, self.moving,
                               self.g)[:self.nx]

    def step(self, x, tau, method, h):
        return self.core.step(method, self._state(x), h, self.B @ tau, self.damping, self.moving,
                              self.g)[:self.nx]


class EngineStep:
    """One whole step h of the engine from the state x with efforts τ (and, where a controller
    drives the arm, its held target r): the compiled stepper's double run
    (`Simulation.advance_to`), its events, impacts, rests and controller updates included, from
    the simulation's records as they are now, which every call puts back. x = (q, u), then with an
    arm controller its PID integrals z and, sampled, the arm efforts it holds; τ the efforts
    (the wheels' alone with an arm controller). Each call checks that the step held the same
    events as from the unperturbed state (the map differentiated is that branch)."""

    def __init__(self, sim, h):
        self.sim, self.h, self.nx = sim, h, sim.nq + sim.nu
        self.B = effort_map(sim.model)
        controlled = sim.arm_controller.active
        self.tau = np.concatenate([sim.wheel_efforts, [] if controlled else sim.joint_efforts])
        self.z = slice(self.nx + 3, self.nx + 3 + sim.nu - 2) if controlled else slice(0, 0)
        self.held = slice(2, sim.nu) if controlled and sim.sampled else slice(0, 0)
        stops, data = sim.stops, sim.system.data
        self.target = data.ref_coeffs[0, :, 0 if sim.arm_controller.mode == "position" else 1]
        self.arrays = (stops.resting, stops.watched, stops.count, stops.run, stops.failed,
                       data.counters, data.holding, data.free, data.Q_cmd, data.held, data.arm,
                       data.arm_ref, data.ref_coeffs, sim._clock)
        self.kept = [a.copy() for a in self.arrays]
        self.s, self.impacts, self.efforts = sim.s.copy(), len(sim.impacts), sim.wheel_efforts
        self.x, self.r = self._state(self.s), self.target.copy()
        self.end, self.events = self._run(self.x, self.tau, self.r)

    def _state(self, s):
        return np.concatenate([s[:self.nx], s[self.z], self.sim.system.data.held[self.held]])

    def _run(self, x, tau, r):
        sim, data = self.sim, self.sim.system.data
        sim.s = self.s.copy()
        sim.s[:self.nx], sim.s[self.z] = x[:self.nx], x[self.nx:self.nx + sim.s[self.z].size]
        data.held[self.held] = x[self.nx + sim.s[self.z].size:]
        full = np.zeros(sim.nu)
        full[:tau.size] = tau
        data.Q_cmd[:tau.size] = (self.B @ full)[:tau.size]
        self.target[:] = r
        sim.advance_to(sim.t + self.h)
        end = self._state(sim.s)
        events = ([(i.link, i.stop, i.resting) for i in sim.impacts[self.impacts:]],
                  sim.stops.resting.tolist(), sim.stops.watched.tolist())
        for array, kept in zip(self.arrays, self.kept, strict=True):
            array[...] = kept
        sim.s, sim.wheel_efforts = self.s.copy(), self.efforts
        del sim.impacts[self.impacts:], sim.impact_details[self.impacts:]
        sim._relock()
        return end, events

    def __call__(self, x, tau=None, r=None):
        end, events = self._run(x, self.tau if tau is None else tau, self.r if r is None else r)
        assert events == self.events, "a perturbation changed the step's events"
        return end


@pytest.mark.parametrize("n", [0, 1, 2, 3, 5])
@pytest.mark.parametrize("seed", [1, 2])
def test_linearize_agrees_with_central_differences_of_the_cores_right_hand_side(seed, n):
    sim = random_simulation(seed, n)
    maps = CoreMaps(sim)
    x = np.concatenate([sim.q, sim.u])
    F_x, F_tau = sim.linearize()
    assert best_agreement(lambda x: maps.rate(x, maps.tau), x, F_x) <= 1e-8
    assert best_agreement(lambda tau: maps.rate(x, tau), maps.tau, F_tau) <= 1e-8
    for k in sim.system.locked:   # held pseudo-velocities stay still: zero rows
        assert not F_x[sim.nq + k].any() and not F_tau[sim.nq + k].any()


@pytest.mark.parametrize("method", FIXED)
@pytest.mark.parametrize("dt", [1e-3, 1e-2])
@pytest.mark.parametrize("n", [0, 2, 4])
def test_step_jacobians_are_the_derivative_of_the_cores_step_map(method, dt, n):
    sim = random_simulation(7 + n, n, method=method, dt=dt)
    maps = CoreMaps(sim)
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


def test_jacobians_along_a_run_are_those_of_its_steps_and_flag_its_events():
    """Along the paper run (rk4, 2 ms, its end stops), every step's (A, B) is the step Jacobian
    at the state the step starts from, and the steps flagged are those in which a rod hit its stop
    or a resting rod left it, as a twin run sees them."""
    scene = load_scene()
    sim = Simulation(scene, integrator=IntegratorSettings(method="rk4", dt=0.002))
    twin = Simulation(scene, integrator=IntegratorSettings(method="rk4", dt=0.002))
    t, A, B, event = jacobians_along(sim, 1.5)
    assert t.size == 750 and A.shape == (750, 15, 15) and B.shape == (750, 15, 6)
    seen = []
    for k in range(t.size):
        impacts, resting = len(twin.impacts), twin.resting.copy()
        twin.advance_to(t[k] + 0.002)
        seen.append(len(twin.impacts) > impacts or not np.array_equal(twin.resting, resting))
    assert np.array_equal(event, seen) and event.sum() == 4   # 3 impacts, 1 release
    twin = Simulation(scene, integrator=IntegratorSettings(method="rk4", dt=0.002))
    for k in (0, 123, *np.flatnonzero(event), 749):
        twin.advance_to(t[k])
        A_k, B_k = twin.step_jacobians()
        assert np.array_equal(A[k], A_k) and np.array_equal(B[k], B_k)


def driven_into_a_stop(seed, n, method, dt, stops):
    """A random robot (`random_simulation`) whose rod 1 reaches its lower stop within the next
    step, at 2 m/s, about 0.4 of the step in (the other rods mid-stroke)."""
    sim = random_simulation(seed, n, method, dt, stops=stops)
    stroke = np.asarray(sim.model.stroke, dtype=float).reshape(-1, 2)
    q, u = sim.q.copy(), sim.u.copy()
    q[range(sim.nq)[6::2]] = stroke.mean(axis=1)
    q[6], u[3] = stroke[0, 0] + 0.8 * dt, -2.0
    sim.set_state(q, u)
    return sim


@pytest.mark.parametrize("method", FIXED)
@pytest.mark.parametrize(("n", "dt", "stops"), [
    (1, 1e-3, {"restitution": 0.5}),                    # a rebound
    (2, 5e-3, {"restitution": 0.0}),                    # the rod comes to rest at its stop
    (3, 2e-3, {"restitution": 0.7, "law": "reflect"}),  # the paper's law
])
def test_step_jacobians_through_an_impact_are_the_derivative_of_the_engines_step(method, n, dt,
                                                                                  stops):
    """A and B of a step in which a rod hits its stop (random robots, every fixed-step method)
    against central differences of the engine's own step — the stepper's double run, the impact
    located and applied — over perturbations that keep the step's events; the end state the dual
    numbers carry is the engine's bit for bit. The event-free step's A does not match (the
    saltation and the impact are what this checks)."""
    sim = driven_into_a_stop(11 + n, n, method, dt, stops)
    engine = EngineStep(sim, dt)
    assert engine.events[0], "the step holds an impact"
    A, B = sim.step_jacobians()
    assert best_agreement(engine, engine.x, A, EVENT_STEPS) <= 1e-8
    assert best_agreement(lambda tau: engine(engine.x, tau), engine.tau, B, EVENT_STEPS) <= 1e-8
    value, _, _, _ = sim._stepper.step_jacobians(sim.s, sim._clock, dt, engine.B)
    assert np.array_equal(value, engine.end)
    A_free, _ = CoreMaps(sim).core.jacobians(method, sim.s[:engine.nx + 3], dt, sim.system.Q_cmd,
                                             engine.B, sim.system.damping, moving_mask(sim),
                                             sim.dynamics.gravity)[1:]
    assert best_agreement(engine, engine.x, A_free, EVENT_STEPS) > 1e-3


def test_step_jacobians_through_a_release_are_the_derivative_of_the_engines_step():
    """The paper run's step at 1.132 s, in which its resting rod 2 is pulled off its stop: A
    against central differences of the engine's step along the directions that keep the rods at
    rest on their stops (a resting rod's l and l̇ perturbed leave its stop, or move into it: an
    impact, another branch of the map)."""
    sim = Simulation(load_scene(), integrator=IntegratorSettings(method="rk4", dt=0.002))
    sim.advance_to(1.132)
    engine = EngineStep(sim, 0.002)
    assert sim.resting.tolist() == [1, -1]
    assert engine.events == ([], [1, 0], [False, True])   # rod 2 left its stop, nothing hit
    A, _ = sim.step_jacobians()
    assert agreement_off_the_stops(engine, A) <= 1e-8


def agreement_off_the_stops(engine, A) -> float:
    """`best_agreement` of A with the engine's step along the directions that keep every resting
    rod on its stop: its own l and l̇ left out (moved, it leaves its stop or presses into it)."""
    sim = engine.sim
    on_stops = [j for k in np.flatnonzero(sim.resting) + 1 for j in (4 + 2 * k, sim.nq + 1 + 2 * k)]
    kept = [j for j in range(engine.x.size) if j not in on_stops]

    def along_kept(y):
        x = engine.x.copy()
        x[kept] = y
        return engine(x)
    return best_agreement(along_kept, engine.x[kept], A[:, kept], EVENT_STEPS)


def test_a_step_that_fails_is_said_in_one_line_and_leaves_the_run_as_it_was():
    """A step differentiated from a state where it goes non-finite: one SimulationError line; the
    run's time, state, rests and impacts untouched, and it runs on."""
    sim = Simulation(load_scene(), integrator=IntegratorSettings(method="rk4", dt=0.002))
    s = sim.s.copy()
    with pytest.raises(SimulationError, match=r"^t = 0 s: step_jacobians: the step from this "
                                              r"state failed \(the step did not complete "
                                              r"\(status 3\)\); try a smaller dt$"):
        sim.step_jacobians(u=np.full(sim.nu, 9e3), dt=10.0)
    assert np.array_equal(sim.s, s) and sim.t == 0.0 and not sim.resting.any() and not sim.impacts
    sim.advance_to(0.01)
    assert sim.t == 0.01


def controlled_simulation(mode, rate, method, dt, target=None):
    """The paper robot with its arm driven by the position or velocity controller (default gains,
    gravity feed-forward) at `rate` (0: continuous), wheel efforts given, a command at t = 0."""
    sim = Simulation(load_scene(), integrator=IntegratorSettings(method=method, dt=dt),
                     arm_controller=ArmController(mode), control_rate=rate)
    if mode == "position":
        sim.set_arm_positions(sim.q[5:] + 0.3 if target is None else target)
    else:
        sim.set_arm_velocities([0.5, 0.1, -0.3, 0.05])
    sim.set_efforts(wheels=[0.3, 0.1])
    return sim


@pytest.mark.parametrize(("mode", "rate", "method", "dt", "t"), [
    ("position", 0.0, "rk4", 1e-3, 0.1),                    # continuous
    ("velocity", 0.0, "semi_implicit_euler", 1e-3, 0.1),
    ("position", 1000.0, "rk4", 1e-3, 0.1),                 # sampled: an update every step
    ("position", 100.0, "euler", 1e-3, 0.105),              # between two updates
    ("velocity", 500.0, "euler", 2e-3, 0.2),
])
def test_closed_loop_step_jacobians_are_the_derivative_of_the_engines_step(mode, rate, method,
                                                                           dt, t):
    """With the arm controller in charge, A (x = (q, u, z), and the held efforts when sampled), B
    (the wheel efforts) and R (the held position or velocity target) against central differences
    of the engine's step, the controllers' update included where one is due. Facts beside: an
    update due at the step's start makes the held efforts depend on the target, between updates
    they do not (R's rows of them are zero, and of everything else too: the target acts through
    them alone)."""
    sim = controlled_simulation(mode, rate, method, dt)
    sim.advance_to(t)
    engine = EngineStep(sim, dt)
    A, B = sim.step_jacobians()
    R = reference_jacobian(sim)
    n_arm = sim.nu - 2
    assert A.shape == (engine.x.size,) * 2 == (sim.nq + sim.nu + n_arm * (2 if rate else 1),) * 2
    assert B.shape == (A.shape[0], 2) and R.shape == (A.shape[0], n_arm)
    assert best_agreement(engine, engine.x, A, EVENT_STEPS) <= 1e-8
    assert best_agreement(lambda tau: engine(engine.x, tau), engine.tau, B, EVENT_STEPS) <= 1e-8
    assert best_agreement(lambda r: engine(engine.x, r=r), engine.r, R, EVENT_STEPS) <= 1e-8
    update_due = rate > 0 and sim.next_update <= sim.t
    assert update_due == (rate > 0 and t != 0.105)
    assert (np.abs(R).max() > 0.1) == (rate == 0 or update_due)


@pytest.mark.parametrize("t", [0.398, 0.49])
def test_the_closed_loop_through_an_impact_is_the_derivative_of_the_engines_step(t):
    """The continuous position controller drives rod 1 onto its lower stop and rod 2 onto its
    upper one: the step at 0.398 s holds rod 1's impact (it comes to rest), the one at 0.49 s rod
    2's, whose impact frees the resting rod 1; A and R are differentiated through them (central
    differences of the engine's step, perturbations keeping the impact)."""
    sim = controlled_simulation("position", 0.0, "rk4", 1e-3, target=[0.3, 0.0, -0.2, 1.0])
    sim.advance_to(t)
    engine = EngineStep(sim, 1e-3)
    assert len(engine.events[0]) == 1
    A, _ = sim.step_jacobians()
    assert agreement_off_the_stops(engine, A) <= 1e-8
    R = reference_jacobian(sim)
    assert best_agreement(lambda r: engine(engine.x, r=r), engine.r, R, EVENT_STEPS) <= 1e-8


def test_what_the_closed_loop_cannot_be_differentiated_for_is_refused_in_one_line():
    """A trajectory has no single held target; a step that an update would cut; the continuous-time
    Jacobians and many states at once are of the robot driven by efforts."""
    sim = controlled_simulation("position", 100.0, "rk4", 3e-3)
    sim.advance_to(0.009)          # the next step, to 0.012 s, would hold the update at 0.01
    with pytest.raises(UserError, match=r"dt: the controllers' next update falls inside the step"):
        sim.step_jacobians()
    with pytest.raises(UserError, match="linearize is of the robot driven by efforts"):
        sim.linearize()
    with pytest.raises(UserError, match="step_jacobians_many is of the robot driven by efforts"):
        step_jacobians_many(sim, sim.q[None], sim.u[None])
    trajectory = Simulation(load_scene("config/arm_trajectory.yaml"),
                            integrator=IntegratorSettings(method="rk4", dt=1e-3))
    with pytest.raises(UserError, match="joint_trajectory mode: the derivative is with respect "
                                        "to the held target of position or velocity mode"):
        reference_jacobian(trajectory)
