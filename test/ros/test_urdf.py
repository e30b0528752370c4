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
    wheel = root.find("link[@name='right_wheel']/inertial/inertia")
    spin = float(wheel.get("iyy")) if wheel is not None else 0.0
    assert spin == (robot.base.wheel_inertia if scene.effects.wheel_inertia else 0.0)


def inertials(root) -> dict:
    """Link name → (mass, centre of mass in the link, 3×3 inertia about it)."""
    found = {}
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is None:
            continue
        i = inertial.find("inertia").attrib
        inertia = np.array([[i["ixx"], i["ixy"], i["ixz"]], [i["ixy"], i["iyy"], i["iyz"]],
                            [i["ixz"], i["iyz"], i["izz"]]], dtype=float)
        com = np.array(inertial.find("origin").get("xyz").split(), dtype=float)
        found[link.get("name")] = (float(inertial.find("mass").get("value")), com, inertia)
    return found


@pytest.mark.parametrize("name", SCENES)
def test_urdf_masses_and_inertias_are_the_scenes(name):
    """Every link's mass and inertia from the scene: the wheels are discs of the scene's spin
    inertia (m_w = 2 I_w / r², unless the base's share would not be physical), base + wheels
    weigh M_pw with their centre of mass at G = (d, 0) and yaw inertia I_pw about it; each rod is
    μL with the slender-rod inertia; every inertia is positive semi-definite, and those the URDF
    makes up (base, wheels) obey the triangle inequalities."""
    scene = SCENES[name]
    robot, base = scene.robot, scene.robot.base
    d, b, r = base.com_offset, base.half_track, base.wheel_radius
    links = inertials(ET.fromstring(robot_description(scene)))
    m_w = links["right_wheel"][0] if "right_wheel" in links else 0.0
    assert m_w <= 2.0 * base.wheel_inertia / r ** 2 * (1 + 1e-12)
    if name in ("paper", "payload"):
        assert m_w == pytest.approx(2.0 * base.wheel_inertia / r ** 2, rel=1e-12) and m_w > 0
    m_base, c_base, I_base = links["base_link"]
    assert m_base + 2 * m_w == pytest.approx(base.mass, rel=1e-12)
    x_g = (m_base * c_base[0]) / base.mass   # the wheels sit at x = 0
    assert x_g == pytest.approx(d, rel=1e-12, abs=1e-15)
    yaw = I_base[2, 2] + m_base * (c_base[0] - d) ** 2
    if m_w:
        I_wheel = links["right_wheel"][2]
        yaw += 2 * (I_wheel[2, 2] + m_w * (d ** 2 + b ** 2))
    assert yaw == pytest.approx(base.yaw_inertia, rel=1e-9)
    for k in range(robot.n_links):
        mass, com, inertia = links[f"arm_rod_{k + 1}"]
        L = robot.length[k]
        assert mass == pytest.approx(robot.mass_per_length[k] * L, rel=1e-15)
        assert com[0] == pytest.approx(-L / 2)
        assert inertia[2, 2] == pytest.approx(mass * L ** 2 / 12
                                              + robot.inertia_per_length[k][2, 2] * L)
    total = sum(mass for mass, _, _ in links.values())
    expected = base.mass + float(np.sum(robot.mass_per_length * robot.length))
    expected += scene.effects.payload or 0.0
    assert total == pytest.approx(expected, rel=1e-12)
    for link, (mass, _, inertia) in links.items():
        assert mass >= 0.0, link
        assert np.allclose(inertia, inertia.T)
        moments = np.linalg.eigvalsh(inertia)
        tol = 1e-12 * max(1.0, moments.max())
        assert moments.min() >= -tol, link
        a, b_, c = moments
        if link.startswith("arm_rod"):   # the scene's own J: the URDF states it as it is
            continue
        assert a + b_ >= c - tol and a + c >= b_ - tol and b_ + c >= a - tol, link
    assert links["base_link"][2][0, 0] != base.yaw_inertia   # no copy of yaw into roll, pitch


def document_limits(doc: dict, n_u: int) -> tuple[np.ndarray, np.ndarray]:
    """(effort, velocity) per joint (τ_R, τ_L, τ_1, F_1, …) as a scene document states them:
    the numbers of effects.effort_limits, else of robot.limits.effort (or where the effect is
    `true`), else the simulator's largest; robot.limits.velocity, else the largest speed."""
    from mobile_manip_sim.scene import limits
    declared = doc["robot"].get("limits", {})
    effect = doc.get("effects", {}).get("effort_limits")
    columns = []
    for largest, owners in (
            (limits.EFFORT, [effect if isinstance(effect, dict) else {},
                             declared.get("effort", {})]),
            (limits.SPEED, [declared.get("velocity", {})])):
        values = np.full(n_u, largest)
        for owner in reversed(owners):   # the first owner that gives a group wins
            for group, where in (("wheels", slice(0, 2)), ("joints", slice(2, None))):
                if owner.get(group) is not None:
                    values[where] = owner[group]
        columns.append(values)
    return columns[0], columns[1]


@pytest.mark.parametrize("name", ["paper", "random_1", "random_5"])
def test_urdf_limits_and_collision_shapes(name):
    """Prismatic limits are the strokes; efforts and velocities those the scene's file states
    (the enforced effort limits, else the robot's own, else the largest the simulator accepts);
    a box collides for the base, cylinders for wheels and rods."""
    scene = SCENES[name]
    robot = scene.robot
    root = ET.fromstring(robot_description(scene))
    effort, velocity = document_limits(scene.document, robot.n_u)
    if name == "paper":   # a motor's, from the file: none of them the simulator's bounds
        assert np.all(effort < 1e3) and np.all(velocity < 1e3)
    for j, joint_name in enumerate(robot.joint_names()):
        limit = root.find(f"joint[@name='{joint_name}']/limit")
        assert float(limit.get("effort")) == effort[j], joint_name
        assert float(limit.get("velocity")) == velocity[j], joint_name
    for k in range(robot.n_links):
        limit = root.find(f"joint[@name='arm_prismatic_{k + 1}']/limit")
        assert (float(limit.get("lower")), float(limit.get("upper"))) == tuple(robot.stroke[k])
        assert root.find(f"link[@name='arm_rod_{k + 1}']/collision/geometry/cylinder") \
            is not None
    assert root.find("link[@name='base_link']/collision/geometry/box") is not None
    for wheel in ("right_wheel", "left_wheel"):
        shape = root.find(f"link[@name='{wheel}']/collision/geometry/cylinder")
        assert float(shape.get("radius")) == robot.base.wheel_radius


def test_pinocchio_mass_matrix_at_the_initial_state_is_ours():
    scene = SCENES["paper"]
    urdf, dyn = UrdfModel(scene), core_dynamics(scene)
    M, M_urdf = dyn.mass_matrix(scene.initial_q), urdf.mass_matrix(scene.initial_q)
    assert np.max(np.abs(M - M_urdf)) <= TOL * np.linalg.norm(M)


@pytest.mark.parametrize("wheels, arm", [("velocity", "position"), ("effort", "effort"),
                                         ("velocity", "velocity")])
def test_ros2_control_block_for_the_topic_based_hardware_interface(wheels, arm):
    """describe --ros2-control: one system of joint_state_topic_hardware_interface, naming the
    node's command and state topics, every joint of /joint_states with one command interface
    (the wheels', the arm's) and position, velocity, effort states starting at the scene's pose."""
    from mobile_manip_sim.ros.topics import JOINT_COMMANDS_TOPIC, ROBOT_JOINT_STATES_TOPIC
    result = run_describe("--ros2-control", "--wheel-interface", wheels, "--arm-interface", arm)
    assert result.returncode == 0, result.stderr
    root = ET.fromstring(result.stdout)
    scene = load_scene()
    blocks = root.findall("ros2_control")
    assert len(blocks) == 1 and blocks[0].get("type") == "system"
    hardware = blocks[0].find("hardware")
    assert hardware.findtext("plugin").strip() == \
        "joint_state_topic_hardware_interface/JointStateTopicSystem"
    params = {p.get("name"): p.text for p in hardware.findall("param")}
    assert params["joint_commands_topic"] == JOINT_COMMANDS_TOPIC.lstrip("/")
    assert params["joint_states_topic"] == ROBOT_JOINT_STATES_TOPIC.lstrip("/")
    joints = blocks[0].findall("joint")
    assert [j.get("name") for j in joints] == scene.robot.joint_names()
    urdf_joints = {j.get("name") for j in root.findall("joint")}
    for j, joint in enumerate(joints):
        assert joint.get("name") in urdf_joints
        assert [c.get("name") for c in joint.findall("command_interface")] == \
            [wheels if j < 2 else arm]
        states = joint.findall("state_interface")
        assert [s.get("name") for s in states] == ["position", "velocity", "effort"]
        assert float(states[0].findtext("param")) == scene.initial_q[3 + j]
    assert run_describe("--ros2-control", "--arm-interface", "joint_trajectory").returncode == 2
    plain = run_describe()
    assert "ros2_control" not in plain.stdout


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


def test_describe_writes_the_paper_robots_limits():
    """describe's URDF carries the limits the paper scene's file declares for its motors."""
    result = run_describe("--scene", str(PAPER))
    assert result.returncode == 0, result.stderr
    root = ET.fromstring(result.stdout)
    declared = paper_document()["robot"]["limits"]
    efforts = declared["effort"]["wheels"] + declared["effort"]["joints"]
    velocities = declared["velocity"]["wheels"] + declared["velocity"]["joints"]
    names = load_scene(PAPER).robot.joint_names()
    written = [root.find(f"joint[@name='{name}']/limit") for name in names]
    assert [float(limit.get("effort")) for limit in written] == efforts
    assert [float(limit.get("velocity")) for limit in written] == velocities


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
