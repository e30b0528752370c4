"""`Simulation.set_state(q, u)`: a state set by hand is the state a scene starting there would
have (bit for bit), the energy balance stays the integration's, rods held at a stop are free
again, and every bad value is one line naming ``state.q[i]`` or ``state.u[i]``."""
import copy

import numpy as np
import pytest

from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.loading import load_scene, parse_scene

Q = [0.1, -0.2, 0.3, 0.0, 0.0, 0.4, 0.6, -0.3, 0.2]
U = [0.2, -0.1, 0.5, 0.1, -0.3, 0.05]


def scene(method="rk4", **initial):
    doc = copy.deepcopy(load_scene().document)
    doc["integrator"] = ({"method": "rk4", "dt": 1e-3} if method == "rk4"
                         else {"method": method, "rtol": 1e-10, "atol": 1e-12})
    doc["initial"].update(initial)
    return parse_scene(doc)


@pytest.mark.parametrize("method", ["rk4", "dop853"])
def test_a_state_set_at_t_0_runs_as_a_scene_that_starts_there(method):
    by_hand = Simulation(scene(method))
    by_hand.set_state(Q, U)
    started = Simulation(scene(method, pose=Q[:3], wheels=Q[3:5], joints=Q[5:], velocity=U))
    assert np.array_equal(by_hand.s, started.s)
    for t in (0.1, 0.5):
        by_hand.advance_to(t)
        started.advance_to(t)
        assert np.array_equal(by_hand.s, started.s)
    assert by_hand.energy_error() == pytest.approx(started.energy_error(), abs=1e-12)


def test_mid_run_the_energy_balance_is_rebased_and_time_commands_and_impacts_are_kept():
    sim = Simulation(scene())
    sim.advance_to(0.5)
    t, impacts, work = sim.t, len(sim.impacts), sim.work
    sim.set_state(Q, U)
    assert sim.t == t and len(sim.impacts) == impacts and sim.work == work
    assert np.array_equal(sim.q, Q) and np.array_equal(sim.u, U)
    assert abs(sim.energy_error()) < 1e-9
    sim.advance_to(1.0)
    assert abs(sim.energy_error()) < 1e-6   # rk4 at 1 kHz over 0.5 s (impacts booked)


def test_a_rod_resting_at_its_stop_is_free_again_where_the_state_puts_it():
    """Zero efforts: rod 2 of the paper robot comes to rest at its upper stop by 0.55 s
    (restitution 0). Set back to mid-stroke at rest, it is free and falls back from there."""
    sim = Simulation(scene())
    sim.set_efforts([0.0, 0.0], [0.0] * 4)
    sim.advance_to(0.55)
    assert sim.resting.tolist() == [0, 1] and sim.q[8] == 1.0
    q = sim.q.copy()
    q[8] = 0.5
    sim.set_state(q, np.zeros(6))
    assert not sim.resting.any()
    sim.advance_to(0.6)
    assert 0.5 < sim.q[8] < 1.0 and sim.u[5] > 0.0   # sliding out again, not held


@pytest.mark.parametrize("q, u, key, problem", [
    (Q[:-1], U, "state.q", "expected 9 values, got shape (8,)"),
    (Q, U + [0.0], "state.u", "expected 6 values, got shape (7,)"),
    ([Q], U, "state.q", "expected 9 values, got shape (1, 9)"),
    (Q[:2] + [float("nan")] + Q[3:], U, "state.q[2]", "must be finite"),
    (Q, U[:1] + [float("inf")] + U[2:], "state.u[1]", "must be finite"),
    (Q, U[:1] + [1e9] + U[2:], "state.u[1]", "within ±10000"),
    (Q[:6] + [1.5] + Q[7:], U, "state.q[6]", r"arm_prismatic_1: 1.5 m is outside the stroke"),
    ("up", U, "state.q", "expected 9 numbers, got up"),
    ({"x": 1}, U, "state.q", "expected 9"),
])
def test_a_bad_state_is_one_line_naming_the_entry(q, u, key, problem):
    sim = Simulation(scene())
    before = sim.s.copy()
    with pytest.raises(UserError, match=problem.replace("(", r"\(").replace(")", r"\)")
                       if "outside" not in problem else problem) as error:
        sim.set_state(q, u)
    assert error.value.key == key and "\n" not in str(error.value)
    assert np.array_equal(sim.s, before)   # nothing changed


def test_a_locked_joint_cannot_be_given_a_velocity():
    doc = copy.deepcopy(load_scene().document)
    doc["effects"]["fixed_base"] = True
    sim = Simulation(parse_scene(doc))
    with pytest.raises(UserError, match=r"state.u\[0\]: the base's v is locked by the scene"):
        sim.set_state(Q, U)
    sim.set_state(Q, [0.0, 0.0] + U[2:])
    assert np.array_equal(sim.u, [0.0, 0.0] + U[2:])
