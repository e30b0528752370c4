"""The URDF describes the simulated robot: Pinocchio's URDF parser, given a planar root joint,
builds a multibody whose projected mass matrix ``M = Sᵀ M_full S`` equals the Gibbs–Appell core's
(scenes built through `parse_scene`, so payload and wheel-inertia effects take the real path);
joint names and types match /joint_states; ``describe`` behaves as a command-line tool."""
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
import zlib
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml

from hostile_yaml import ALIAS_BOMB
from mobile_manip_sim.dynamics import Dynamics
from mobile_manip_sim.ros.urdf import robot_description
from mobile_manip_sim.scene.coordinates import JOINTS, OMEGA, YAW, V, X, Y
from mobile_manip_sim.scene.effects import settings as effect_settings
from mobile_manip_sim.scene.loading import load_scene, parse_scene
from robots import random_configuration, random_robot_document

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "config" / "paper_two_link.yaml"
TOL = 1e-9
SEEDS = list(range(12))


def paper_document() -> dict:
    return yaml.safe_load(PAPER.read_text())


def payload_scene():
    doc = paper_document()
    doc["effects"]["payload"] = {"mass": 0.75}
    return parse_scene(doc, "paper_payload")


def random_scene(seed):
    """A random robot (`robots.random_robot_document`, 0–5 links) with effects that vary with the
    seed: payload, wheel inertia, damping, effort limits."""
    rng = np.random.default_rng(seed)
    n = seed % 6
    doc = random_robot_document(rng, n)
    doc["efforts"] = {}
    effects = {"gravity": 9.81, "wheel_inertia": bool(seed % 3 != 2)}
    if n and seed % 2:
        effects["payload"] = float(rng.uniform(0.1, 3.0))
    if seed % 4 == 1:
        effects["joint_damping"] = 0.3
        effects["wheel_damping"] = 0.05
        effects["effort_limits"] = {"wheels": 2.0, "joints": 50.0}
    doc["effects"] = effects
    return parse_scene(doc, f"random_{seed}")


def scenes():
    yield "paper", load_scene()
    yield "payload", payload_scene()
    for seed in SEEDS:
        yield f"random_{seed}", random_scene(seed)


SCENES = dict(scenes())


class UrdfModel:
    """Pinocchio's model of the URDF with a planar root, and the map S from u to v_full built by
    joint NAME (the parser's joint order is its own)."""

    def __init__(self, scene):
        self.scene = scene
        self.model = pin.buildModelFromXML(robot_description(scene), pin.JointModelPlanar())
        self.data = self.model.createData()
        robot = scene.robot
        self.root = self.model.joints[1]
        assert self.model.names[1] == "root_joint" and self.root.nq == 4 and self.root.nv == 3
        names = robot.joint_names()
        assert sorted(self.model.names[2:]) == sorted(names)
        self.joints = [self.model.joints[self.model.getJointId(name)] for name in names]
        r, b = robot.base.wheel_radius, robot.base.half_track
        S = np.zeros((self.model.nv, robot.n_u))
        v0 = self.root.idx_v
        S[v0 + 0, 0] = 1.0                   # v_x (base_link) = v
        S[v0 + 2, 1] = 1.0                   # ω_z = ω
        right, left = self.joints[0].idx_v, self.joints[1].idx_v
        S[right, 0], S[right, 1] = 1.0 / r, b / r    # θ̇_R = (v + bω)/r
        S[left, 0], S[left, 1] = 1.0 / r, -b / r     # θ̇_L = (v − bω)/r
        for column, joint in enumerate(self.joints[2:], start=2):
            S[joint.idx_v, column] = 1.0
        self.S = S

    def full_configuration(self, q) -> np.ndarray:
        q_full = np.empty(self.model.nq)
        i = self.root.idx_q
        q_full[i:i + 4] = q[X], q[Y], np.cos(q[YAW]), np.sin(q[YAW])
        for joint, value in zip(self.joints, q[JOINTS], strict=True):
            if joint.nq == 2:    # continuous joints: (cos θ, sin θ)
                q_full[joint.idx_q:joint.idx_q + 2] = np.cos(value), np.sin(value)
            else:
                q_full[joint.idx_q] = value
        return q_full

    def mass_matrix(self, q) -> np.ndarray:
        M = pin.crba(self.model, self.data, self.full_configuration(q)).copy()
        M = np.triu(M) + np.triu(M, 1).T
        return self.S.T @ M @ self.S


def core_dynamics(scene) -> Dynamics:
    return Dynamics(scene.robot, **effect_settings(scene).dynamics_options())


@pytest.mark.parametrize("name", SCENES)
def test_urdf_mass_matrix_equals_core_mass_matrix(name):
    scene = SCENES[name]
    urdf, dyn = UrdfModel(scene), core_dynamics(scene)
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    for _ in range(5):
        q = random_configuration(rng, scene.robot)
        M, M_urdf = dyn.mass_matrix(q), urdf.mass_matrix(q)
        assert np.max(np.abs(M - M_urdf)) <= TOL * np.linalg.norm(M), (M - M_urdf)


@pytest.mark.parametrize("name", SCENES)
def test_urdf_frames_are_the_core_frames(name):
    """Joint frame k of the URDF (child of arm_revolute_k) is O_k, R_k; `tip` is the core's tip;
    the planar root maps (x, y, yaw) and (v, ω) as the core does."""
    scene = SCENES[name]
    urdf, dyn = UrdfModel(scene), core_dynamics(scene)
    model, data = urdf.model, urdf.data
    rng = np.random.default_rng(7)
    for _ in range(3):
        q = random_configuration(rng, scene.robot)
        u = rng.normal(size=scene.robot.n_u)
        pin.forwardKinematics(model, data, urdf.full_configuration(q), urdf.S @ u)
        pin.updateFramePlacements(model, data)
        # The URDF's root is base_footprint, on the ground: the core's points are r lower.
        lift = np.array([0.0, 0.0, scene.robot.base.wheel_radius])
        origins = [origin + lift for origin in dyn.joint_origins(q)]
        rotations = dyn.link_rotations(q)
        base = data.oMi[1]
        assert np.allclose(base.translation, [q[X], q[Y], 0.0], atol=1e-12)
        assert np.allclose(base.rotation, rotations[0], atol=1e-12)
        assert np.allclose(data.v[1].linear, [u[V], 0.0, 0.0], atol=1e-12)
        assert np.allclose(data.v[1].angular, [0.0, 0.0, u[OMEGA]], atol=1e-12)
        for k in range(scene.robot.n_links):
            frame = data.oMi[model.getJointId(f"arm_revolute_{k + 1}")]
            assert np.allclose(frame.translation, origins[k + 1], atol=1e-12)
            assert np.allclose(frame.rotation, rotations[k + 1], atol=1e-12)
        tip = data.oMf[model.getFrameId("tip")]
        assert np.allclose(tip.translation, origins[-1], atol=1e-12)


@pytest.mark.parametrize("name", SCENES)
def test_urdf_stands_on_the_floor_with_the_axle_at_the_wheel_radius(name):
    """Rooted at base_footprint (z = 0, the floor): both wheel axes, and base_link, are r above
    it, so every wheel's lowest point touches the ground, whatever the pose."""
    scene = SCENES[name]
    urdf = UrdfModel(scene)
    model, data = urdf.model, urdf.data
    r, b = scene.robot.base.wheel_radius, scene.robot.base.half_track
    assert model.frames[model.getFrameId("base_footprint")].parentJoint == 1
    q = random_configuration(np.random.default_rng(3), scene.robot)
    pin.forwardKinematics(model, data, urdf.full_configuration(q))
    pin.updateFramePlacements(model, data)
    footprint = data.oMf[model.getFrameId("base_footprint")]
    assert np.allclose(footprint.translation, [q[X], q[Y], 0.0], atol=1e-12)
    assert np.allclose(data.oMf[model.getFrameId("base_link")].translation, [q[X], q[Y], r],
                       atol=1e-12)
    for side, sign in (("right", -1.0), ("left", 1.0)):
        axle = footprint.actInv(data.oMi[model.getJointId(f"{side}_wheel_joint")]).translation
        assert np.allclose(axle, [0.0, sign * b, r], atol=1e-12)


@pytest.mark.parametrize("name", SCENES)
def test_urdf_joint_names_and_types_match_joint_states(name):
    scene = SCENES[name]
    robot = scene.robot
    root = ET.fromstring(robot_description(scene))
    assert root.tag == "robot" and root.get("name") == scene.name
    joints = root.findall("joint")
    moving = [j for j in joints if j.get("type") != "fixed"]
    assert [j.get("name") for j in moving] == robot.joint_names()
    links = {link.get("name") for link in root.findall("link")}
    for joint in joints:
        assert joint.find("parent").get("link") in links
        assert joint.find("child").get("link") in links
    expected = {"right_wheel_joint": ("continuous", "0.0 1.0 0.0"),
                "left_wheel_joint": ("continuous", "0.0 1.0 0.0")}
    for k in range(robot.n_links):
        expected[f"arm_revolute_{k + 1}"] = ("continuous", "0.0 0.0 1.0")
        expected[f"arm_prismatic_{k + 1}"] = ("prismatic", "1.0 0.0 0.0")
    for joint in moving:
        assert (joint.get("type"), joint.find("axis").get("xyz")) == expected[joint.get("name")]
    for k in range(robot.n_links):
        limit = root.find(f"joint[@name='arm_prismatic_{k + 1}']/limit")
        assert [float(limit.get("lower")), float(limit.get("upper"))] == list(robot.stroke[k])
    assert [j.get("name") for j in joints if j.get("type") == "fixed"] == [
        "base_footprint_joint", "tip_joint"]
    tip = root.find("link[@name='tip']")
    if scene.effects.payload:
        assert float(tip.find("inertial/mass").get("value")) == scene.effects.payload
    else:
        assert tip.find("inertial") is None
    wheel = root.find("link[@name='right_wheel']")
    assert (wheel.find("inertial") is not None) == bool(scene.effects.wheel_inertia)


def run_describe(*args):
    return subprocess.run([sys.executable, "-m", "mobile_manip_sim.programs.describe", *args],
                          capture_output=True, text=True, timeout=60, cwd=ROOT)


def test_describe_prints_the_scene_urdf():
    result = run_describe("--scene", str(PAPER))
    assert result.returncode == 0, result.stderr
    assert result.stdout == robot_description(load_scene(PAPER))
    assert ET.fromstring(result.stdout).get("name") == "paper_two_link"


def test_describe_without_scene_prints_the_default_scene():
    result = run_describe()
    assert result.returncode == 0, result.stderr
    assert result.stdout == robot_description(load_scene())


@pytest.mark.parametrize("kind, problem",
                         [("missing", "cannot read"), ("fifo", "not a regular file"),
                          ("alias bomb", "expands to more than")])
def test_describe_of_a_bad_scene_file_is_a_one_line_user_error(tmp_path, kind, problem):
    scene = tmp_path / "no_such_scene.yaml"
    if kind == "fifo":
        os.mkfifo(scene)     # a blocking read would hang describe
    elif kind == "alias bomb":
        scene.write_text(ALIAS_BOMB)
    result = run_describe("--scene", str(scene))
    assert result.returncode == 2
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and str(scene.stem) in lines[0] and problem in lines[0], result.stderr


def test_describe_bad_flag_is_a_one_line_user_error():
    result = run_describe("--no-such-flag")
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
