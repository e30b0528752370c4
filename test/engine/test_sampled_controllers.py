"""Sampled controllers (engine/sampling.py, docs/controllers.md "The control rate"): the wheel-speed
loop and the arm controller update at the control rate, as ros2_control's controller manager runs
its controllers at its update_rate, and the efforts are held between updates.

Checked against facts that do not come from the engine's controller code: the held efforts read
at every step are constant between update instants; the first updates equal control_toolbox's
PI (``Pid::compute_command``: the command from the integral as it stands, then
i_term += dt · i_gain · error unless saturated in the error's direction) computed by hand; and a
whole sampled run equals a closed loop written here — the PI at the update instants, SciPy's
DOP853 between them on the plant's equations with the efforts held.
"""
import copy
import math

import numpy as np
import pytest
from scipy import integrate

from engine_cases import base_only_doc, paper_doc, simulation
from mobile_manip_sim.engine.simulation import DEFAULT_WHEEL_SPEED_GAINS, Simulation
from mobile_manip_sim.scene.arm_controller import ArmController
from mobile_manip_sim.scene.controller import DEFAULT_CONTROL_RATE
from mobile_manip_sim.scene.coordinates import OMEGA, V
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.loading import parse_scene
from mobile_manip_sim.scene.methods import METHODS

KP, KI = DEFAULT_WHEEL_SPEED_GAINS


def stall_doc(method, rate):
    """The stall case measured on main c493bf3: the paper scene, wheel effort limits 0.3 N·m,
    its arm efforts as given (dop853, rk45 and radau stopped at t = 1.52 s there, continuous)."""
    doc = paper_doc()
    doc["effects"]["effort_limits"] = {"wheels": [0.3, 0.3]}
    doc["controller"] = {"rate": rate}
    doc["integrator"] = ({"method": method, "dt": 1e-3} if METHODS[method].fixed_step
                         else {"method": method, "rtol": 1e-10, "atol": 1e-12})
    return doc


@pytest.mark.parametrize("method", list(METHODS))
def test_the_stall_case_runs_through_with_every_method_sampled(method):
    """cmd_vel 1 m/s on the saturating wheels, arm efforts as given: 20 s (SciPy's radau and
    bdf, stepped from Python, 5 s), the energy balanced."""
    sim = Simulation(parse_scene(stall_doc(method, DEFAULT_CONTROL_RATE)))
    sim.set_base_velocity(1.0, 0.0)
    t_end = 5.0 if METHODS[method].stepper.startswith("scipy") else 20.0
    for k in range(1, int(t_end * 10) + 1):
        sim.advance_to(k / 10)
    assert sim.t == t_end
    # saturated, the base takes some 6 s to reach its speed (0.923 m/s at 5 s: dop853 and rk4
    # alike to 1e-10, bdf to 8e-7), never beyond it by more than the loop's overshoot
    assert sim.u[V] == pytest.approx(1.0 if t_end == 20.0 else 0.9232, abs=0.01)
    if method not in ("euler", "semi_implicit_euler"):   # theirs drifts by O(dt): 1.25 J and
        # 0.05 J over 20 s; SciPy's bdf 8e-6 J over 5 s
        tolerance = 1e-4 if method == "bdf" else 1e-6
        assert abs(sim.energy_error()) < tolerance * max(1.0, abs(sim.work))


@pytest.mark.parametrize("method", list(METHODS))
def test_the_stall_case_runs_through_with_every_method_continuous(method):
    """controller.rate 0: the continuous loop's back-calculation anti-windup puts no switch in
    the right-hand side (conditional integration did: dop853, rk45 and radau stopped at
    t = 1.52 s, "5000 steps advanced it only 3.7e-06 s"). 20 s with every method (dop853 in
    1543 steps), the energy balanced."""
    sim = Simulation(parse_scene(stall_doc(method, 0.0)))
    assert not sim.sampled
    sim.set_base_velocity(1.0, 0.0)
    for k in range(1, 201):
        sim.advance_to(k / 10)
    assert sim.t == 20.0
    assert sim.u[V] == pytest.approx(1.0, abs=0.01)
    if method not in ("euler", "semi_implicit_euler"):   # theirs drifts by O(dt)
        tolerance = 1e-4 if method == "bdf" else 1e-6
        assert abs(sim.energy_error()) < tolerance * max(1.0, abs(sim.work))


def test_the_continuous_loop_back_calculates_only_when_saturated():
    """control_toolbox's BACK_CALCULATION with its default tracking time constant T_t = kp/ki
    for a PI: ki ė = ki e + (τ − raw)/T_t, i.e. ė = e + (τ − raw)/kp, read from the right-hand
    side at a saturated state and at an unsaturated one (there ė is the error, exactly: the
    correction must not fire)."""
    doc = base_only_doc(effects={"effort_limits": {"wheels": [0.3, 0.3]}})
    doc["controller"] = {"rate": 0}
    sim = simulation(doc, "rk4", dt=1e-3)
    r, b = sim.model.base.wheel_radius, sim.model.base.half_track
    e = sim.nq + sim.nu
    for v, z, saturated in ((0.2, 0.01, True), (0.99, 0.001, False)):
        sim.set_state(sim.q, [v, 0.0])
        sim.set_base_velocity(1.0, 0.0)   # a fresh loop (integrals 0), set to z here
        sim.s[e:e + 2] = z
        error = (1.0 + b * 0.0) / r - (v + b * 0.0) / r   # θ̇* − θ̇, as the loop forms it
        raw = KP * error + KI * z
        tau = min(raw, 0.3)
        assert (raw > 0.3) == saturated
        rates = sim.system.derivative(sim.s)[e:e + 2]
        expected = error + (tau - raw) / KP if saturated else error
        assert rates.tolist() == pytest.approx([expected, expected], rel=1e-14)
        if not saturated:
            assert rates.tolist() == [error, error]
        assert sim.wheel_torques().tolist() == pytest.approx([tau, tau], rel=1e-14)
        sim.set_efforts(wheels=[0.0, 0.0])   # off, so that the next cmd_vel starts the loop


def held_wheel_pi(sim, t_end, rate):
    """A closed loop written here: at each update instant m/rate (m = 0, 1, …: the command
    given at t = 0 is taken there) control_toolbox's PI with conditional integration on each
    wheel's speed, the torques held until the next; between, SciPy's DOP853 on the plant's
    equations (the engine's right-hand side in torque mode: the same equations, integrated and
    controlled independently). Returns the state at t_end."""
    r, b = sim.model.base.wheel_radius, sim.model.base.half_track
    limits = [float(w) for w in sim.effects.effort_limits[:2]]
    targets = np.array([(1.0 + b * 0.0) / r, (1.0 - b * 0.0) / r])
    s = sim.s.copy()
    z = np.zeros(2)
    torques = np.zeros(2)
    period = 1.0 / rate
    plant = Simulation(sim.scene, sim.settings, control_rate=0.0)
    m = 0
    t = 0.0
    while True:
        if t == m / rate:   # the update: command from z as it stands, then z += T e
            speeds = np.array([(s[sim.nq + V] + b * s[sim.nq + OMEGA]) / r,
                               (s[sim.nq + V] - b * s[sim.nq + OMEGA]) / r])
            for w in range(2):
                error = targets[w] - speeds[w]
                raw = KP * error + KI * z[w]
                torques[w] = min(max(raw, -limits[w]), limits[w])
                if not (raw != torques[w] and error * raw > 0.0):
                    z[w] += period * error
            m += 1
        t_next = min(m / rate, t_end)
        plant.set_efforts(wheels=torques)
        solution = integrate.solve_ivp(lambda _t, y: plant.system.derivative(y), (t, t_next), s,
                                       method="DOP853", rtol=1e-12, atol=1e-14)
        s = solution.y[:, -1]
        t = t_next
        if t >= t_end:
            return s


@pytest.mark.parametrize("rate", [100.0, 1000.0])
def test_a_sampled_run_equals_an_independent_closed_loop(rate):
    """The stall case's base without its stops (the arm's efforts as given, no impacts to
    model), 0.5 s: dop853 with the wheel loop at `rate` against `held_wheel_pi`."""
    doc = stall_doc("dop853", rate)
    doc["effects"].pop("stroke_limits")
    sim = Simulation(parse_scene(doc))
    sim.set_base_velocity(1.0, 0.0)
    reference = held_wheel_pi(sim, 0.5, rate)
    sim.advance_to(0.5)
    n = sim.nq + sim.nu
    scale = np.maximum(1.0, np.abs(reference[:n]))
    assert np.max(np.abs(sim.s[:n] - reference[:n]) / scale) < 1e-9


def stepwise(sim, t_end, dt, read):
    """`read()` after every step of dt up to t_end: (times, values)."""
    times = np.arange(1, int(round(t_end / dt)) + 1) * dt
    values = []
    for t in times:
        sim.advance_to(t)
        values.append(np.array(read(), dtype=float))
    return times, np.array(values)


def changes_only_at_updates(times, values, period):
    """The values change only across an update instant, and they do change: where the value
    read at times[i] differs from that at times[i-1], an update instant lies in
    [times[i-1], times[i]] (the update at times[i-1] itself is the first act of the call to
    times[i]; the reads are a quarter of a period apart, so most such intervals hold none)."""
    changed = np.flatnonzero(np.any(np.diff(values, axis=0) != 0.0, axis=1)) + 1
    first, last = times[changed - 1] / period, times[changed] / period
    assert changed.size > 0
    assert np.all(np.floor(last + 1e-6) >= first - 1e-6), times[changed][:5]
    return changed.size


@pytest.mark.parametrize("method", ["rk4", "dop853"])
def test_the_wheel_torques_are_held_between_updates(method):
    """Read at every step of 0.25 ms (a quarter of the update period): the torques change only
    at update instants — at nearly all of them while the loop acts."""
    doc = stall_doc(method, 1000.0)
    doc["effects"].pop("effort_limits")   # unsaturated: the torques move at every update
    if method == "rk4":
        doc["integrator"]["dt"] = 2.5e-4
    sim = Simulation(parse_scene(doc))
    sim.set_base_velocity(0.3, 0.0)
    times, torques = stepwise(sim, 0.3, 2.5e-4, sim.wheel_torques)
    assert changes_only_at_updates(times, torques, 1e-3) > 250


@pytest.mark.parametrize("mode", ["position", "joint_trajectory"])
def test_the_arm_efforts_are_held_between_updates(mode):
    doc = paper_doc()
    doc["controller"] = {"arm_controller": mode, "rate": 200}
    doc["efforts"] = {"wheels": [0.1, 0.2]}
    doc["integrator"] = {"method": "rk4", "dt": 5e-4}
    sim = Simulation(parse_scene(doc))
    if mode == "joint_trajectory":
        q0 = sim.q[5:].copy()
        sim.set_arm_trajectory([0.5], [q0 + [0.2, 0.1, -0.2, 0.1]])
    times, efforts = stepwise(sim, 0.6, 5e-4, sim.joint_efforts_applied)
    assert changes_only_at_updates(times, efforts, 5e-3) > 100
    assert abs(sim.energy_error()) < 1e-8 * max(1.0, abs(sim.work))


def test_the_first_updates_are_control_toolboxs_pi_by_hand():
    """The base alone from rest, no arm, cmd_vel 1 m/s at t = 0 with the loop at 100 Hz: the
    command is given at an update instant, so the loop's first update, at t = 0, takes it. There
    each wheel's error is e₀ = v*/r − 0, the command kp e₀ (z = 0), then z = T e₀; from rest
    under that constant torque the base reaches v(T) = T · 2τ₀/r / M_vv, and the second command,
    at T, is kp (v*/r − v(T)/r) + ki T e₀. A call that ends at T leaves the update at T to the
    next call: until then the torques read are the first update's."""
    plain = simulation(base_only_doc(), "rk4", dt=1e-3)
    sim = Simulation(plain.scene, plain.settings, control_rate=100.0)
    sim.set_base_velocity(1.0, 0.0)
    r = sim.model.base.wheel_radius
    T = 0.01
    assert np.array_equal(sim.wheel_torques(), [0.0, 0.0])   # the update at 0 is to come
    sim.advance_to(1e-3)
    e0 = 1.0 / r
    assert sim.wheel_torques() == pytest.approx([KP * e0, KP * e0], rel=1e-14)
    M_vv = sim.dynamics.mass_matrix(sim.q)[V, V]
    sim.advance_to(T)
    v = T * 2.0 * KP * e0 / r / M_vv   # rk4 is exact for a constant acceleration
    assert sim.u[V] == pytest.approx(v, rel=1e-12)
    assert sim.wheel_torques() == pytest.approx([KP * e0, KP * e0], rel=1e-14)
    sim.advance_to(T + 1e-3)
    tau1 = KP * (1.0 / r - v / r) + KI * T * e0
    assert sim.wheel_torques() == pytest.approx([tau1, tau1], rel=1e-12)


def test_a_saturated_update_freezes_the_integral_as_control_toolbox_does():
    """Limits 0.3 N·m: the first update saturates in the error's direction, so z stays 0 and the
    second command is the limit again; the integral moves once the wheel leaves saturation."""
    doc = base_only_doc(effects={"effort_limits": {"wheels": [0.3, 0.3]}})
    doc["controller"] = {"rate": 100}
    sim = simulation(doc, "rk4", dt=1e-3)
    sim.set_base_velocity(1.0, 0.0)
    e = slice(sim.nq + sim.nu, sim.nq + sim.nu + 2)
    sim.advance_to(0.02)
    assert np.array_equal(sim.wheel_torques(), [0.3, 0.3]) and np.array_equal(sim.s[e], [0, 0])
    while sim.wheel_torques()[0] == 0.3:
        sim.advance_to(sim.t + 0.01)
    assert sim.s[e][0] != 0.0


def test_a_command_is_taken_at_the_next_update():
    """ros2_control's controllers read their commands in update(): a cmd_vel between two updates
    changes the torques at the next update instant, not before."""
    doc = base_only_doc()
    doc["controller"] = {"rate": 100}
    sim = simulation(doc, "rk4", dt=1e-3)
    sim.set_base_velocity(0.5, 0.0)
    sim.advance_to(0.503)
    before = sim.wheel_torques()
    sim.set_base_velocity(1.0, 0.0)
    sim.advance_to(0.509)
    assert np.array_equal(sim.wheel_torques(), before)
    sim.advance_to(0.51)   # the update at 0.51 s is the next call's first act
    assert np.array_equal(sim.wheel_torques(), before)
    sim.advance_to(0.511)
    assert sim.wheel_torques()[0] > before[0] + 1.0


@pytest.mark.parametrize("method", ["rk4", "dop853", "radau"])
def test_a_command_at_an_update_instant_is_taken_at_that_update(method):
    """A call that ends at an update instant leaves the update to the next call, which applies
    it after the commands given between the calls (as ros2_control's controllers read their
    commands in update()): a cmd_vel given at t = 0.5 s, an instant of the 100 Hz loop, sets
    the torques held from 0.5 s on — those of the new target at the state of 0.5 s."""
    doc = base_only_doc()
    doc["controller"] = {"rate": 100}
    sim = simulation(doc, method, **({"dt": 1e-3} if method == "rk4" else {}))
    sim.set_base_velocity(0.5, 0.0)
    sim.advance_to(0.5)
    r, b = sim.model.base.wheel_radius, sim.model.base.half_track
    v, omega = sim.u[V], sim.u[OMEGA]
    z = sim.s[sim.nq + sim.nu:sim.nq + sim.nu + 2].copy()
    sim.set_base_velocity(1.0, 0.0)
    sim.advance_to(0.505)
    expected = [KP * (1.0 / r - (v + b * omega) / r) + KI * z[0],
                KP * (1.0 / r - (v - b * omega) / r) + KI * z[1]]
    assert sim.wheel_torques() == pytest.approx(expected, rel=1e-14, abs=1e-14)


def test_ending_calls_at_update_instants_changes_nothing():
    """The update at the end of a call is applied by the next: a run advanced in calls that end
    at update instants (and between them) is bit for bit the run advanced in one call."""
    runs = []
    for targets in ([0.3], np.arange(1, 61) * 0.005, np.arange(1, 301) * 0.001):
        doc = base_only_doc(effects={"effort_limits": {"wheels": [0.3, 0.3]}})
        doc["controller"] = {"rate": 200}
        sim = simulation(doc, "dop853")
        sim.set_base_velocity(1.0, 0.0)
        for t in targets:
            sim.advance_to(float(t))
        runs.append(sim.s.copy())
    assert np.array_equal(runs[0], runs[1]) and np.array_equal(runs[0], runs[2])


def test_a_command_at_an_update_instant_is_the_scenes_command_shifted():
    """The node's way and the headless scene's agree: the paper robot held in place by its
    joint_trajectory controller (default rate) until t_a = 0.2 s, an update instant, then given
    a trajectory, is at t_a + s where the same scene with that trajectory in its controller
    section (given at t = 0) is at s — up to the rounding of the hold before t_a (1e-9)."""
    text = paper_doc()
    text["efforts"] = {"wheels": [0.0, 0.0]}
    text["integrator"] = {"method": "rk4", "dt": 1e-3}
    points = [(0.5, [0.5, 0.4, -0.1, 0.6]), (1.0, [0.6, 0.45, 0.2, 0.55])]
    headless_doc = copy.deepcopy(text)
    headless_doc["controller"] = {"arm_controller": "joint_trajectory", "trajectory": {
        "points": [{"time_from_start": t, "positions": p} for t, p in points]}}
    text["controller"] = {"arm_controller": "joint_trajectory"}
    headless, node = Simulation(parse_scene(headless_doc)), Simulation(parse_scene(text))
    assert node.control_rate == DEFAULT_CONTROL_RATE
    t_a = 0.2
    node.advance_to(t_a)
    node.set_arm_trajectory([t for t, _ in points], [p for _, p in points])
    largest = 0.0
    for k in range(1, 121):
        headless.advance_to(k * 0.01)
        node.advance_to(t_a + k * 0.01)
        largest = max(largest, np.max(np.abs(headless.q[3:] - node.q[3:])))
    assert largest < 1e-9


def test_rate_zero_keeps_the_continuous_loop():
    """controller.rate 0: the torques follow the speed at every evaluation (they change at
    every step) and equal the loop's law at the state."""
    doc = base_only_doc()
    doc["controller"] = {"rate": 0}
    sim = simulation(doc, "rk4", dt=1e-3)
    assert not sim.sampled
    sim.set_base_velocity(1.0, 0.0)
    times, torques = stepwise(sim, 0.05, 1e-3, sim.wheel_torques)
    assert np.all(np.diff(torques[:, 0]) != 0.0)


def test_an_effort_mode_run_is_not_cut_at_update_instants():
    """No controller drives: the default rate changes nothing, not even the adaptive steps."""
    runs = []
    for rate in (0.0, DEFAULT_CONTROL_RATE):
        doc = paper_doc()
        doc["controller"] = {"rate": rate}
        sim = Simulation(parse_scene(doc))
        sim.advance_to(1.0)
        runs.append((sim.s.copy(), sim.steps))
    assert np.array_equal(runs[0][0], runs[1][0]) and runs[0][1] == runs[1][1]


@pytest.mark.parametrize("rate", [-1.0, math.inf, "fast", 2e6])
def test_a_bad_rate_is_a_one_line_error(rate):
    doc = paper_doc()
    doc["controller"] = {"rate": rate}
    with pytest.raises(UserError, match=r"^controller\.rate: ") as error:
        Simulation(parse_scene(doc))
    assert "\n" not in str(error.value)
    with pytest.raises(UserError, match=r"^controller\.rate: "):
        Simulation(parse_scene(paper_doc()), control_rate=rate)


def test_the_arm_controller_record_is_the_same_at_any_rate():
    """The rate is the controller manager's, not the arm controller's: an ArmController given
    to Simulation runs at the scene's rate."""
    doc = copy.deepcopy(paper_doc())
    doc["controller"] = {"rate": 250}
    sim = Simulation(parse_scene(doc), arm_controller=ArmController("position"))
    assert sim.control_rate == 250.0 and sim.system.data.rate == 250.0


def test_the_sampled_reference_is_jtcs_sample_at_each_update_instant():
    """joint_trajectory at 100 Hz: the reference the held efforts come from is the trajectory
    sampled at the update instant t_m, as JTC samples it at each of the controller manager's
    updates — not at a step's stages, not one update late. Between two position-only points JTC
    interpolates linearly, so q_ref(t_m) = P0 + (t_m − 0.2)/0.4 (P1 − P0) and q̇_ref = (P1 −
    P0)/0.4, checked at every update inside that segment with rk4 steps of 3 ms around them."""
    doc = paper_doc()
    doc["controller"] = {"arm_controller": "joint_trajectory", "rate": 100}
    doc["efforts"] = {"wheels": [0.1, 0.2]}
    doc["integrator"] = {"method": "rk4", "dt": 3e-3}
    sim = Simulation(parse_scene(doc))
    q0 = sim.q[5:].copy()
    P = np.array([q0 + [0.2, 0.05, -0.2, 0.05], q0 + [0.4, 0.1, -0.4, 0.1]])
    sim.set_arm_trajectory([0.2, 0.6], P)
    for m in range(21, 60):   # the updates strictly inside (0.2 s, 0.6 s)
        t_m = m / 100
        sim.advance_to(t_m + 0.004)
        held = sim.system.arm_ref
        assert np.allclose(held[0], P[0] + (t_m - 0.2) / 0.4 * (P[1] - P[0]), rtol=0,
                           atol=1e-12), (t_m, held[0])
        assert np.allclose(held[1], (P[1] - P[0]) / 0.4, rtol=0, atol=1e-12), (t_m, held[1])
