"""The frame tree (frames.py) is the robot the dynamics integrates and the URDF describes: every
link frame composed from the tree's transforms equals Pinocchio's forward kinematics on the
URDF the node publishes (prefixed, as with frame_prefix), and the core's own position pass
(`Dynamics.joint_origins`, `link_rotations`), for the paper robot and a random 5-link arm."""
import numpy as np
import pinocchio as pin
import pytest

from mobile_manip_sim.ros.frames import FOOTPRINT, FrameTree, rpy_quaternion
from mobile_manip_sim.ros.urdf import robot_description
from mobile_manip_sim.scene.coordinates import JOINTS, YAW, X, Y
from mobile_manip_sim.scene.model import rpy_matrix
from robots import random_configuration
from test_urdf import SCENES, core_dynamics

TOL = 1e-9
PREFIX = "robot1/"
FIVE_LINKS = "random_5"       # seed 5 of test_urdf.random_scene: five links, random rpy, payload
CASES = ["paper", FIVE_LINKS]


def matrix(transform) -> pin.SE3:
    x, y, z, w = transform.rotation
    return pin.SE3(pin.Quaternion(w, x, y, z).matrix(), np.array(transform.translation))


def world_frames(tree: FrameTree, q, odom="odom") -> dict:
    """Frame → SE3 in odom, composed from the root down the tree's transforms."""
    base = tree.base_transform(q, odom)
    poses = {base.child: matrix(base)}
    values = {joint.name: joint for joint in tree.joints}
    transforms = tree.static_transforms() + tree.moving_transforms(q)
    by_child = {t.child: t for t in transforms}
    for joint in tree.joints:       # parents come before children
        t = by_child[tree.frame(joint.child)]
        poses[t.child] = poses[t.parent] * matrix(t)
    assert set(values) == {j.name for j in tree.joints}
    return poses


def pinocchio_frames(scene, q_full_of, q):
    model = pin.buildModelFromXML(robot_description(scene, prefix=PREFIX), pin.JointModelPlanar())
    data = model.createData()
    pin.framesForwardKinematics(model, data, q_full_of(model, q))
    return model, data


def full_configuration(model, robot, q):
    """Pinocchio's configuration of the URDF model (planar root, then joints by name)."""
    q_full = np.zeros(model.nq)
    root = model.joints[1]
    q_full[root.idx_q:root.idx_q + 4] = q[X], q[Y], np.cos(q[YAW]), np.sin(q[YAW])
    for name, value in zip(robot.joint_names(), q[JOINTS], strict=True):
        joint = model.joints[model.getJointId(name)]
        if joint.nq == 2:
            q_full[joint.idx_q:joint.idx_q + 2] = np.cos(value), np.sin(value)
        else:
            q_full[joint.idx_q] = value
    return q_full


@pytest.mark.parametrize("name", CASES)
def test_every_link_frame_equals_pinocchio_on_the_published_urdf(name):
    scene = SCENES[name]
    robot = scene.robot
    assert robot.n_links == (2 if name == "paper" else 5)
    tree = FrameTree(robot, prefix=PREFIX)
    rng = np.random.default_rng(19)
    for _ in range(5):
        q = random_configuration(rng, robot)
        model, data = pinocchio_frames(scene, lambda m, q: full_configuration(m, robot, q), q)
        poses = world_frames(tree, q)
        names = {f.name for f in model.frames if f.type == pin.FrameType.BODY}
        assert names == set(poses) == {PREFIX + link for link in tree.links}
        for frame, pose in poses.items():
            reference = data.oMf[model.getFrameId(frame)]
            assert np.max(np.abs(pose.translation - reference.translation)) < TOL, frame
            assert np.max(np.abs(pose.rotation - reference.rotation)) < TOL, frame


@pytest.mark.parametrize("name", CASES)
def test_link_frames_are_the_dynamics_frames(name):
    """Joint frame k (arm_link_k) sits at O_k with R_k, the tip at the core's tip, all lifted by
    the wheel radius (the core measures heights from the axle)."""
    scene = SCENES[name]
    robot = scene.robot
    tree, dyn = FrameTree(robot), core_dynamics(scene)
    lift = np.array([0.0, 0.0, robot.base.wheel_radius])
    rng = np.random.default_rng(5)
    for _ in range(5):
        q = random_configuration(rng, robot)
        poses = world_frames(tree, q)
        origins, rotations = dyn.joint_origins(q), dyn.link_rotations(q)
        assert np.max(np.abs(poses["base_link"].translation - origins[0] - lift)) < TOL
        assert np.max(np.abs(poses["base_link"].rotation - rotations[0])) < TOL
        for k in range(1, robot.n_links + 1):
            frame = poses[f"arm_link_{k}"]
            assert np.max(np.abs(frame.translation - origins[k] - lift)) < TOL
            assert np.max(np.abs(frame.rotation - rotations[k])) < TOL
        assert np.max(np.abs(poses["tip"].translation - origins[-1] - lift)) < TOL


@pytest.mark.parametrize("name", CASES)
def test_the_tree_has_one_parent_per_frame_and_the_fixed_joints_on_tf_static(name):
    robot = SCENES[name].robot
    tree = FrameTree(robot, root="footprint", prefix=PREFIX)
    q = random_configuration(np.random.default_rng(1), robot)
    static, moving = tree.static_transforms(), tree.moving_transforms(q)
    children = [t.child for t in static + moving]
    assert len(children) == len(set(children)) == len(tree.links) - 1
    assert {t.parent for t in static + moving} <= set(children) | {PREFIX + "footprint"}
    assert [t.child for t in static] == [PREFIX + "base_link", PREFIX + "tip"]
    assert [j.name for j in tree.moving] == robot.joint_names()
    base = tree.base_transform(q, "odom")
    assert (base.parent, base.child) == (PREFIX + "odom", PREFIX + "footprint")
    for t in static + moving + [base]:
        assert abs(np.linalg.norm(t.rotation) - 1.0) < 1e-15


def test_two_prefixes_share_no_frame():
    robot = SCENES[FIVE_LINKS].robot
    one, two = FrameTree(robot, prefix="robot1/"), FrameTree(robot, prefix="robot2/")
    q = np.zeros(robot.n_q)
    names = lambda tree: {name for t in tree.static_transforms() + tree.moving_transforms(q)
                          + [tree.base_transform(q)] for name in (t.parent, t.child)}
    assert not names(one) & names(two)
    assert FrameTree(robot).root == FOOTPRINT


def test_rpy_quaternion_is_the_urdf_rotation():
    rng = np.random.default_rng(0)
    for rpy in rng.uniform(-np.pi, np.pi, (20, 3)):
        x, y, z, w = rpy_quaternion(*rpy)
        assert np.max(np.abs(pin.Quaternion(w, x, y, z).matrix() - rpy_matrix(*rpy))) < 1e-14
