"""The wheel-speed PI loop (`Simulation.set_base_velocity`): it reaches the commanded base
velocity, keeps within its torque limit, and its work enters the energy balance like any effort."""
import copy

import numpy as np
import pytest

from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.scene.coordinates import OMEGA, V
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.loading import load_scene, parse_scene

ARM_JOINTS = ["arm_revolute_1", "arm_prismatic_1", "arm_revolute_2", "arm_prismatic_2"]


def paper(method="rk4", locked=True, **effects):
    doc = copy.deepcopy(load_scene().document)
    if locked:
        doc["effects"]["locked_joints"] = ARM_JOINTS
    doc["effects"].update(effects)
    doc["controller"] = {"rate": 0}   # the continuous loop (sampled: test_sampled_controllers)
    doc["integrator"] = {"method": method, "dt": 1e-3} if method == "rk4" else {"method": method}
    return Simulation(parse_scene(doc))


def run(sim, duration, rate=100):
    for k in range(1, int(round(duration * rate)) + 1):
        sim.advance_to(k / rate)


@pytest.mark.parametrize("method", ["rk4", "dop853"])
def test_the_base_reaches_the_commanded_velocity(method):
    sim = paper(method)
    sim.set_base_velocity(0.3, 0.5)
    run(sim, 3.0)
    assert sim.u[V] == pytest.approx(0.3, abs=1e-3)
    assert sim.u[OMEGA] == pytest.approx(0.5, abs=1e-3)


def test_wheel_torques_stay_within_the_limit_and_the_work_is_counted():
    sim = paper(effort_limits={"wheels": [0.05, 0.05]})
    sim.set_base_velocity(1.0, 0.0)
    peak = 0.0
    for k in range(1, 201):
        sim.advance_to(k / 100)
        peak = max(peak, float(np.max(np.abs(sim.wheel_torques()))))
    assert peak == pytest.approx(0.05, rel=1e-12)     # saturated, never beyond
    assert 0.0 < sim.u[0] < 1.0                        # still accelerating under the limit
    assert sim.work > 0.0
    assert abs(sim.energy_error()) < 1e-9 * sim.work


def test_effort_commands_turn_the_loop_off():
    sim = paper()
    sim.set_base_velocity(0.3, 0.0)
    run(sim, 1.0)
    sim.set_efforts(wheels=[0.0, 0.0])
    assert not sim.velocity_mode
    v = sim.u[0]
    run_from = sim.t
    for k in range(1, 51):
        sim.advance_to(run_from + k / 100)
    assert sim.u[0] == pytest.approx(v, abs=1e-9)     # no torque, no friction: it coasts
    assert np.array_equal(sim.wheel_torques(), [0.0, 0.0])


def test_bad_gains_are_one_line_errors():
    sim = paper()
    with pytest.raises(UserError, match="wheel_speed.kp"):
        sim.set_wheel_speed_gains(float("nan"), 1.0)
    with pytest.raises(UserError, match="cmd_vel"):
        sim.set_base_velocity(float("inf"), 0.0)


def test_holding_forces_are_what_the_mass_matrix_says():
    """The force a locked pseudo-velocity needs (`System.constraint_forces`, one inverse-dynamics
    pass) equals (M u̇ + h − Q) from the composite-rigid-body mass matrix and the bias, with u̇
    from the articulated pass zero on the locked DOFs; zero on the free ones."""
    sim = paper(locked=False, gravity=10.0)
    rng = np.random.default_rng(3)
    sim.system.set_locked((3, 5))            # both rods held, as at their stops
    for _ in range(5):
        q = np.array(sim.q) + rng.normal(0.0, 0.3, sim.nq)
        u = rng.normal(0.0, 1.0, sim.nu)
        u[[3, 5]] = 0.0
        s = sim.system.state(q, u)
        ud = sim.system.derivative(s)[sim.nq:sim.nq + sim.nu]
        assert ud[3] == 0.0 and ud[5] == 0.0
        M, h = sim.dynamics.mass_matrix(q), sim.dynamics.bias(q, u)
        expected = M @ ud + h - sim.system.Q_cmd
        forces = sim.system.constraint_forces(s)
        scale = 1.0 + np.abs(expected).max()
        assert np.allclose(forces, expected, atol=1e-10 * scale)
        assert np.abs(forces[[0, 1, 2, 4]]).max() < 1e-10 * scale   # free DOFs need no force
        assert np.abs(forces[[3, 5]]).min() > 1e-3                   # the held ones do


def step_response(limits, duration=4.0, rate=100):
    """A 1 m/s cmd_vel step from rest (arm locked, rk4 1 ms): v and (τ_R, τ_L) at each sample."""
    sim = paper(**({} if limits is None else {"effort_limits": {"wheels": limits}}))
    sim.set_base_velocity(1.0, 0.0)
    v, torques = [], []
    for k in range(1, int(round(duration * rate)) + 1):
        sim.advance_to(k / rate)
        v.append(sim.u[V])
        torques.append(sim.wheel_torques())
    return sim, np.array(v), np.array(torques)


# What saturation may add to the unsaturated step's overshoot: 1 % of the step. With the
# integral frozen while a wheel is saturated the loop leaves saturation with the integral it
# had (zero, from rest) and the error kp·e = limit, a smaller step than the unsaturated one.
OVERSHOOT_MARGIN = 0.01   # m/s


def test_a_saturated_step_overshoots_no_more_than_an_unsaturated_one_and_settles():
    """Anti-windup: with 0.3 N·m limits the wheels saturate for most of the rise; an integral
    that kept integrating would carry the base far past 1 m/s (to 1.92 m/s, settling after
    8 s). It overshoots no more than the unlimited loop (+ OVERSHOOT_MARGIN) and settles."""
    _, free, _ = step_response(None)
    sim, limited, torques = step_response([0.3, 0.3])
    assert np.abs(torques).max() == pytest.approx(0.3, rel=1e-12)    # it did saturate
    assert np.abs(torques).max() <= 0.3
    assert free.max() > 1.0                                          # the PI loop overshoots
    assert limited.max() - 1.0 <= free.max() - 1.0 + OVERSHOOT_MARGIN
    assert np.all(np.abs(limited[200:] - 1.0) < 0.02)                # within 2 % from 2 s on
    assert limited[-1] == pytest.approx(1.0, abs=1e-4)
    assert abs(sim.energy_error()) < 1e-9 * sim.work                 # the work still balances


def test_unequal_wheel_limits_give_unequal_torques():
    """Each wheel within its own limit: [1.0, 0.1] N·m gives τ_R = 1.0 and τ_L = 0.1 while
    both saturate (not both 0.1), and a torque_limit of the loop lowers only the larger."""
    sim, v, torques = step_response([1.0, 0.1], duration=0.5)
    assert torques[0].tolist() == [1.0, 0.1]                        # both saturated at 10 ms
    assert np.abs(torques[:, 0]).max() == 1.0 and np.abs(torques[:, 1]).max() == 0.1
    assert sim.u[OMEGA] != 0.0       # unequal torques turn the base, as a real drive would
    sim = paper(effort_limits={"wheels": [1.0, 0.1]})
    sim.set_wheel_speed_gains(2.0, 20.0, torque_limit=0.5)
    sim.set_base_velocity(1.0, 0.0)
    sim.advance_to(0.01)
    assert sim.wheel_torques().tolist() == [0.5, 0.1]


@pytest.mark.parametrize("limit", [None, 0.05])
def test_the_wheel_torques_said_are_those_the_right_hand_side_applies(limit):
    """`wheel_torques` under velocity commands (free and saturated) against the right-hand side:
    the accelerations now are M⁻¹(Q − h) with the wheels' Q made from the torques said."""
    sim = paper(locked=False, **({} if limit is None else {"effort_limits": {"wheels": limit}}))
    sim.set_base_velocity(0.8, -0.6)
    r, b = sim.model.base.wheel_radius, sim.model.base.half_track
    for k in range(1, 6):
        sim.advance_to(0.05 * k)
        tau_R, tau_L = sim.wheel_torques()
        Q = sim.system.Q_cmd.copy()
        Q[V], Q[OMEGA] = (tau_R + tau_L) / r, b * (tau_R - tau_L) / r
        if sim.system.damping.size:
            Q -= sim.system.damping * sim.u
        expected = sim.dynamics.forward_dynamics(sim.q, sim.u, Q)
        assert np.allclose(sim.acceleration(), expected, rtol=1e-12, atol=1e-12), k
        if limit is not None:
            assert max(abs(tau_R), abs(tau_L)) <= limit
