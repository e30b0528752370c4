"""coordinates.py, the owner of the q and u indices: its sizes, slices and index functions
describe one layout (each index of q and u once), which agrees with the facts written elsewhere on
it: `RobotModel.joint_names` (the /joint_states and URDF order) and the configuration rate."""
import numpy as np
import pytest

from mobile_manip_sim.dynamics import Dynamics
from mobile_manip_sim.scene.coordinates import (
    ARM_Q,
    ARM_U,
    BASE_POSE,
    JOINTS,
    OMEGA,
    SLIDES_Q,
    SLIDES_U,
    TURNS_Q,
    TURNS_U,
    WHEELS,
    YAW,
    V,
    X,
    Y,
    q_joint,
    q_slide,
    q_turn,
    rod,
    u_slide,
    u_turn,
)
from robots import random_robot, random_state


@pytest.mark.parametrize("n", [0, 1, 2, 5])
def test_the_indices_cover_q_and_u_once_in_the_model_s_sizes_and_joint_order(n):
    robot = random_robot(np.random.default_rng(n), n)
    q, u = np.arange(robot.n_q), np.arange(robot.n_u)
    rods = range(1, n + 1)
    assert list(q[TURNS_Q]) == [q_turn(k) for k in rods]
    assert list(q[SLIDES_Q]) == [q_slide(k) for k in rods]
    assert list(u[TURNS_U]) == [u_turn(k) for k in rods]
    assert list(u[SLIDES_U]) == [u_slide(k) for k in rods]
    # every index of q once: the base pose, the wheels, then the arm's pairs
    assert sorted([X, Y, YAW, *q[WHEELS], *q[TURNS_Q], *q[SLIDES_Q]]) == list(q)
    assert list(q[BASE_POSE]) == [X, Y, YAW] and len(q[ARM_Q]) == 2 * n
    assert sorted([V, OMEGA, *u[TURNS_U], *u[SLIDES_U]]) == list(u) and len(u[ARM_U]) == 2 * n
    # /joint_states order is q from JOINTS on, and the arm's joints are indexed as u
    names = robot.joint_names()
    assert len(q[JOINTS]) == len(names) == robot.n_u
    for k in rods:
        assert names[u_turn(k)] == f"arm_revolute_{k}" and names[u_slide(k)] == f"arm_prismatic_{k}"
        assert q_joint(u_turn(k)) == q_turn(k) and q_joint(u_slide(k)) == q_slide(k)
        assert rod(u_turn(k)) == rod(u_slide(k)) == k


def test_the_configuration_rate_moves_each_coordinate_by_its_own_rate():
    """q̇ of an arm coordinate is its entry of u, and the base pose moves with (v, ω) alone."""
    robot = random_robot(np.random.default_rng(7), 3)
    dynamics = Dynamics(robot)
    q, u = random_state(np.random.default_rng(8), robot)
    qdot = dynamics.configuration_rate(q, u)
    assert np.array_equal(qdot[ARM_Q], u[ARM_U])
    assert qdot[YAW] == u[OMEGA]
    assert qdot[X] == pytest.approx(u[V] * np.cos(q[YAW]), rel=1e-15)
    assert qdot[Y] == pytest.approx(u[V] * np.sin(q[YAW]), rel=1e-15)

