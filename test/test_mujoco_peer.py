"""MuJoCo's peer (bench/mujoco_peer.py) is the same robot: its mass matrix, projected with S(yaw)
on our pseudo-velocities, is `Dynamics.mass_matrix`, and its kinetic and potential energies are ours,
at random states of the paper robot and of random 1–6-link robots."""
import numpy as np
import pytest

from mobile_manip_sim.bench.scenes import random_robot_document
from mobile_manip_sim.dynamics import Dynamics
from mobile_manip_sim.scene import load_scene, parse_scene

mujoco_peer = pytest.importorskip("mobile_manip_sim.bench.mujoco_peer")
pytest.importorskip("mujoco")


def _robots():
    yield "paper", load_scene().robot, 10.0, 0.0, True
    yield "paper, payload, no wheel inertia", load_scene().robot, 9.81, 0.7, False
    for n in range(1, 7):
        yield f"random {n} links", parse_scene(random_robot_document(n, seed=40 + n, physical=True), "r").robot, 10.0, 0.3, True


def _random_state(robot, rng):
    q = rng.normal(size=robot.n_q)
    q[6::2] = rng.uniform(0.0, 1.0, robot.n_links) * np.array(robot.length)
    return q, rng.normal(size=robot.n_u)


@pytest.mark.parametrize("label, robot, gravity, tip_mass, wheel_inertia", list(_robots()),
                         ids=lambda v: v if isinstance(v, str) else "")
def test_mass_matrix_and_energies_are_ours(label, robot, gravity, tip_mass, wheel_inertia):
    dyn = Dynamics(robot, gravity=gravity, tip_mass=tip_mass, wheel_inertia=wheel_inertia)
    peer = mujoco_peer.MujocoPeer(robot, gravity, tip_mass, wheel_inertia)
    rng = np.random.default_rng(len(label))
    potential_offset = None
    for _ in range(10):
        q, u = _random_state(robot, rng)
        M = dyn.mass_matrix(q)
        M_mj = peer.mass_matrix(q)
        assert np.abs(M_mj - M).max() <= 1e-12 * np.abs(M).max(), label
        T, V = dyn.energy(q, u)
        T_mj, V_mj = peer.energy(q, u)
        assert abs(T_mj - T) <= 1e-12 * max(T, 1.0)
        # potential energies agree up to one constant (each has its own zero)
        offset = V_mj - V
        potential_offset = offset if potential_offset is None else potential_offset
        assert abs(offset - potential_offset) <= 1e-11 * max(abs(V), 1.0)


def test_a_changed_inertia_is_seen():
    """The comparison is sharp: a rod mass 1e-9 off shows."""
    scene = load_scene()
    doc = scene.document
    doc["robot"]["arm"]["links"][1]["mass_per_length"] *= 1.0 + 1e-9
    other = parse_scene(doc, "perturbed").robot
    q, _ = _random_state(scene.robot, np.random.default_rng(3))
    M = Dynamics(scene.robot).mass_matrix(q)
    M_mj = mujoco_peer.MujocoPeer(other, 0.0).mass_matrix(q)
    assert np.abs(M_mj - M).max() > 1e-10 * np.abs(M).max()


def test_qpos_is_our_configuration_and_qvel_is_S_u():
    robot = load_scene().robot
    peer = mujoco_peer.MujocoPeer(robot, 10.0)
    q, u = _random_state(robot, np.random.default_rng(5))
    peer.set_state(q, u)
    # the last rod's distal end from MuJoCo's kinematics against ours
    tip = peer.data.xpos[peer.model.nbody - 1]
    assert np.allclose(tip, Dynamics(robot).tip_position(q), atol=1e-12)
    v, omega = u[0], u[1]
    assert np.allclose(peer.data.qvel[:3], [v * np.cos(q[2]), v * np.sin(q[2]), omega])
