"""MuJoCo's peer (bench/mujoco_peer.py) is the same robot: its mass matrix, projected with S(yaw)
on our pseudo-velocities, is `Dynamics.mass_matrix`, and its kinetic and potential energies are
ours, at random states of the paper robot and of random 1–6-link robots."""
import numpy as np
import pytest

from mobile_manip_sim.bench.scenes import random_robot_document
from mobile_manip_sim.dynamics import Dynamics
from mobile_manip_sim.scene.coordinates import ARM_U, BASE_POSE, OMEGA, YAW, V
from mobile_manip_sim.scene.loading import load_scene, parse_scene
from robots import random_state

mujoco_peer = pytest.importorskip("mobile_manip_sim.bench.mujoco_peer")
pytest.importorskip("mujoco")


def _robots():
    yield "paper", load_scene().robot, 10.0, 0.0, True
    yield "paper, payload, no wheel inertia", load_scene().robot, 9.81, 0.7, False
    for n in range(1, 7):
        robot = parse_scene(random_robot_document(n, seed=40 + n, physical=True), "r").robot
        yield f"random {n} links", robot, 10.0, 0.3, True


@pytest.mark.parametrize("label, robot, gravity, tip_mass, wheel_inertia", list(_robots()),
                         ids=lambda v: v if isinstance(v, str) else "")
def test_mass_matrix_and_energies_are_ours(label, robot, gravity, tip_mass, wheel_inertia):
    dyn = Dynamics(robot, gravity=gravity, tip_mass=tip_mass, wheel_inertia=wheel_inertia)
    peer = mujoco_peer.MujocoPeer(robot, gravity, tip_mass, wheel_inertia)
    rng = np.random.default_rng(len(label))
    potential_offset = None
    for _ in range(10):
        q, u = random_state(rng, robot)
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
    q, _ = random_state(np.random.default_rng(3), scene.robot)
    M = Dynamics(scene.robot).mass_matrix(q)
    M_mj = mujoco_peer.MujocoPeer(other, 0.0).mass_matrix(q)
    assert np.abs(M_mj - M).max() > 1e-10 * np.abs(M).max()


def test_qpos_is_our_configuration_and_qvel_is_S_u():
    robot = load_scene().robot
    peer = mujoco_peer.MujocoPeer(robot, 10.0)
    q, u = random_state(np.random.default_rng(5), robot)
    peer.set_state(q, u)
    # the last rod's distal end from MuJoCo's kinematics against ours
    tip = peer.data.xpos[peer.model.nbody - 1]
    assert np.allclose(tip, Dynamics(robot).tip_position(q), atol=1e-12)
    v, omega = u[V], u[OMEGA]
    assert np.allclose(peer.data.qvel[:3], [v * np.cos(q[YAW]), v * np.sin(q[YAW]), omega])


def test_fixed_base_peer_is_the_arm_block():
    """Base welded at its pose: MuJoCo's mass matrix is our arm block and the tip is ours."""
    robot = parse_scene(random_robot_document(4, seed=9, physical=True), "r").robot
    rng = np.random.default_rng(11)
    q, u = random_state(rng, robot)
    peer = mujoco_peer.MujocoPeer(robot, 10.0, base_pose=q[BASE_POSE])
    dyn = Dynamics(robot, gravity=10.0)
    M = dyn.mass_matrix(q)[ARM_U, ARM_U]
    assert np.abs(peer.mass_matrix(q)[ARM_U, ARM_U] - M).max() <= 1e-12 * np.abs(M).max()
    peer.set_state(q, u)
    assert np.allclose(peer.data.xpos[peer.model.nbody - 1], dyn.tip_position(q), atol=1e-12)


def test_fixed_base_trajectory_is_ours():
    """Same ODE, same method, same step: MuJoCo's RK4 on a fixed-base 3-link arm under gravity
    follows our rk4 to round-off, and both converge to our DOP853 reference."""
    from mobile_manip_sim.bench import versus_mujoco
    from mobile_manip_sim.bench.runs import simulate
    from mobile_manip_sim.scene.loading import make_integrator
    scene = versus_mujoco.random_arm_scene(n_links=3, seed=7, duration=0.3)
    _, mj = versus_mujoco.trajectory(scene, "RK4", 1e-3)
    ours = simulate(scene, make_integrator(scene.integrator, "rk4", dt=1e-3)).samples
    reference = simulate(scene, make_integrator(scene.integrator, "dop853", rtol=1e-12,
                                                atol=1e-13)).samples
    assert mj.shape == ours.shape
    assert np.abs(mj - ours).max() <= 1e-10
    assert 1e-12 < np.abs(mj - reference).max() <= 1e-7   # rk4 at 1 ms is not exact
    assert np.abs(mj[-1] - mj[0]).max() > 0.1               # and the arm did move
