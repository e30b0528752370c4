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
    # saturated, the base takes some 6 s to reach its speed (0.905 m/s at 5 s, radau and bdf
    # alike to 6e-7), never beyond it by more than the loop's overshoot
    assert sim.u[V] == pytest.approx(1.0 if t_end == 20.0 else 0.9046, abs=0.01)
    if method not in ("euler", "semi_implicit_euler"):   # theirs drifts by O(dt): 1.25 J and
        # 0.05 J over 20 s; SciPy's bdf 8e-6 J over 5 s
        tolerance = 1e-4 if method == "bdf" else 1e-6
        assert abs(sim.energy_error()) < tolerance * max(1.0, abs(sim.work))


def held_wheel_pi(sim, t_end, rate):
    """A closed loop written here: at each update instant m/rate control_toolbox's PI with
    conditional integration on each wheel's speed, the torques held until the next; between,
    SciPy's DOP853 on the plant's equations (the engine's right-hand side in torque mode: the
    same equations, integrated and controlled independently). Returns the state at t_end."""
    r, b = sim.model.base.wheel_radius, sim.model.base.half_track
    limits = [float(w) for w in sim.effects.effort_limits[:2]]
    targets = np.array([(1.0 + b * 0.0) / r, (1.0 - b * 0.0) / r])
    s = sim.s.copy()
    z = np.zeros(2)
    torques = np.array(sim.wheel_efforts, dtype=float)   # held until the first update after t=0
    period = 1.0 / rate
    plant = Simulation(sim.scene, sim.settings, control_rate=0.0)
    m = 1
    t = 0.0
    while t < t_end - 1e-12:
        t_next = min(m / rate, t_end)
        plant.set_efforts(wheels=torques)
        solution = integrate.solve_ivp(lambda _t, y: plant.system.derivative(y), (t, t_next), s,
                                       method="DOP853", rtol=1e-12, atol=1e-14)
        s = solution.y[:, -1]
        t = t_next
        if t_next == m / rate:   # the update: command from z as it stands, then z += T e
            speeds = np.array([(s[sim.nq + V] + b * s[sim.nq + OMEGA]) / r,
                               (s[sim.nq + V] - b * s[sim.nq + OMEGA]) / r])
            for w in range(2):
                error = targets[w] - speeds[w]
                raw = KP * error + KI * z[w]
                torques[w] = min(max(raw, -limits[w]), limits[w])
                if not (raw != torques[w] and error * raw > 0.0):
                    z[w] += period * error
            m += 1
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
    """The instants where the values change are update instants, and they do change."""
    changed = np.flatnonzero(np.any(np.diff(values, axis=0) != 0.0, axis=1)) + 1
    at = times[changed] / period
    assert changed.size > 0
    assert np.all(np.abs(at - np.round(at)) < 1e-6), times[changed][:5]
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
    """The base alone from rest, no arm, cmd_vel 1 m/s at t = 0 with the loop at 100 Hz. The
    wheels keep their commanded torque (0) until the loop's first update at T = 10 ms. There
    each wheel's error is e₁ = v*/r − 0, the command kp e₁ (z = 0), then z = T e₁; from rest
    under that constant torque the base reaches v(2T) = T · 2τ₁/r / M_vv, and the second command
    is kp (v*/r − v(2T)/r) + ki T e₁."""
    plain = simulation(base_only_doc(), "rk4", dt=1e-3)
    sim = Simulation(plain.scene, plain.settings, control_rate=100.0)
    sim.set_base_velocity(1.0, 0.0)
    r = sim.model.base.wheel_radius
    T = 0.01
    sim.advance_to(T - 1e-3)
    assert np.array_equal(sim.wheel_torques(), [0.0, 0.0]) and sim.u[V] == 0.0
    sim.advance_to(T)
    e1 = 1.0 / r
    assert sim.wheel_torques() == pytest.approx([KP * e1, KP * e1], rel=1e-14)
    M_vv = sim.dynamics.mass_matrix(sim.q)[V, V]
    sim.advance_to(2 * T)
    v = T * 2.0 * KP * e1 / r / M_vv   # rk4 is exact for a constant acceleration
    assert sim.u[V] == pytest.approx(v, rel=1e-12)
    tau2 = KP * (1.0 / r - v / r) + KI * T * e1
    assert sim.wheel_torques() == pytest.approx([tau2, tau2], rel=1e-12)


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
    sim.advance_to(0.51)
    assert sim.wheel_torques()[0] > before[0] + 1.0


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
