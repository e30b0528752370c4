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
