"""A rod that starts at rest exactly on its stop, pressed into it, is held there from the first
instant for every method (docs/model.md, "Resting, leaving, and no Zeno"), and leaves at the
instant its stop would pull; a rod on its stop moving away, or pulled away, is not held.

The case is the one measured before the hold existed: a random 3-link robot without gravity,
stops with e = 1 and no rest speed, rod 1 at its lower stop at rest under −2.2 N. Left free, rk4
at 1 ms hit that stop 11,744 times in the first 0.5 s (rebounds of round-off size a few µs
apart, just outside the Zeno guard's 1 µs evidence). The other rods are driven, so the robot
moves and the holding force changes while it stays a push.
"""
import numpy as np
import pytest

import robots
from mobile_manip_sim.engine import layout
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.scene.loading import parse_scene
from mobile_manip_sim.scene.methods import METHODS

PRESS = -2.2   # N along rod 1: into its lower stop


def pressed_scene(method, *, force=PRESS, ld_1=0.0):
    rng = np.random.default_rng(39)
    doc = robots.random_robot_document(rng, 3, gravity=0.0)
    links = doc["robot"]["arm"]["links"]
    joints = doc["initial"]["joints"]
    joints[1] = links[0]["stroke"][0]   # rod 1 exactly at its lower stop
    velocity = [0.0] * len(doc["initial"]["velocity"])
    velocity[layout.u_slide(1)] = ld_1
    doc["initial"]["velocity"] = velocity
    doc["efforts"] = {"wheels": [0.0, 0.0], "joints": [0.3, force, -0.2, 0.0, 0.1, 0.0]}
    doc["effects"]["stroke_limits"] = {"restitution": 1.0, "rest_speed": 0.0}
    doc["integrator"] = ({"method": method, "dt": 1e-3} if METHODS[method].fixed_step
                         else {"method": method, "rtol": 1e-9, "atol": 1e-11})
    return Simulation(parse_scene(doc))


def l_1(sim):
    return sim.q[layout.q_slide(1)]


def energy_tolerance(sim):
    """J: the first-order methods' energy drift over the run is of order dt (2e-4 J measured)."""
    order_one = sim.settings.method in ("euler", "semi_implicit_euler")
    return (1e-3 if order_one else 1e-7) * max(1.0, sim.total_energy())


@pytest.mark.parametrize("method", list(METHODS))
def test_a_rod_pressed_into_its_stop_at_rest_is_held_from_the_start(method):
    sim = pressed_scene(method)
    lower = sim.stroke[0, 0]
    assert sim.resting[0] == -1   # held at t = 0, before any step
    for t in np.arange(1, 51) / 100:
        sim.advance_to(t)
        assert l_1(sim) == lower and sim.u[layout.u_slide(1)] == 0.0 and sim.resting[0] == -1
    assert len(sim.impacts) == 0 and sim.holds == 0
    assert abs(sim.energy_error()) < energy_tolerance(sim)
    # the press reverses: the stop would pull, so the rod leaves at that instant, and moves out
    efforts = np.array(sim.joint_efforts)
    efforts[1] = -PRESS
    sim.set_efforts(joints=efforts)
    assert sim.resting[0] == 0
    sim.advance_to(0.6)
    assert l_1(sim) > lower and sim.u[layout.u_slide(1)] > 0.0
    assert not [hit for hit in sim.impacts if hit.link == 1]   # (rod 3 meets its stop at 0.549 s)
    assert abs(sim.energy_error()) < energy_tolerance(sim)


@pytest.mark.parametrize("method", ["rk4", "dop853"])
def test_a_rod_on_its_stop_pulled_away_is_not_held(method):
    sim = pressed_scene(method, force=-PRESS)
    assert sim.resting[0] == 0
    sim.advance_to(0.1)
    assert l_1(sim) > sim.stroke[0, 0] and len(sim.impacts) == 0


@pytest.mark.parametrize("method", ["rk4", "dop853"])
def test_a_rod_on_its_stop_moving_away_is_not_held(method):
    """Moving away at 0.05 m/s against the press: it leaves, turns and comes back to its stop
    (an impact of the law, e = 1: a rebound, not a hold)."""
    sim = pressed_scene(method, ld_1=0.05)
    assert sim.resting[0] == 0
    sim.advance_to(0.01)
    assert l_1(sim) > sim.stroke[0, 0]
    sim.advance_to(0.2)
    assert len(sim.impacts) >= 1 and sim.impacts[0].link == 1 and sim.holds == 0
