"""The node as the hardware of ros2_control's topic-based interface (parameter ros2_control):
the client here behaves as `joint_state_topic_hardware_interface/JointStateTopicSystem` does in
its source (write(): one sensor_msgs/JointState on the joint-command topic, QoS depth 1, naming
every joint of its <ros2_control> block in block order, with a position value for each joint
whose command interface is position, a velocity value for each velocity one, an effort value
for each effort one; read(): the latest JointState of the joint-states topic, SensorDataQoS,
taken by name). The node runs in its own process on real DDS, as `ros2 run` starts it."""
import threading
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import rclpy
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import JointState

from mobile_manip_sim.ros.topics import (
    JOINT_COMMANDS_TOPIC,
    JOINT_STATES_TOPIC,
    ROBOT_JOINT_STATES_TOPIC,
)
from mobile_manip_sim.ros.urdf import robot_description
from mobile_manip_sim.scene.coordinates import ARM_Q
from mobile_manip_sim.scene.loading import load_scene
from ros_harness import NodeProcess, child_env, on_domain, private_domain, spinning, wait_for

DOMAIN_ID = private_domain(1, 232)
FAST = ["-p", "integrator.method:=rk4", "-p", "integrator.dt:=0.001",
        "-p", "real_time_factor:=5.0", "-p", "ros2_control:=true"]
TIMEOUT = 60.0
SCENE = load_scene()


def block(wheels: str, arm: str):
    """The <ros2_control> block `describe --ros2-control` writes: (joint, command interface)."""
    root = ET.fromstring(robot_description(SCENE, ros2_control={"wheels": wheels, "arm": arm}))
    return [(joint.get("name"), joint.find("command_interface").get("name"))
            for joint in root.find("ros2_control").findall("joint")]


class HardwareInterface:
    """What JointStateTopicSystem does on the wire, for the joints of ``joints``."""

    def __init__(self, context, joints):
        self.node = rclpy.create_node("topic_based_hardware", context=context)
        self.joints = joints
        self.lock = threading.Lock()
        self.states: list[JointState] = []
        self.commands = self.node.create_publisher(JointState, JOINT_COMMANDS_TOPIC,
                                                   QoSProfile(depth=1))
        self.node.create_subscription(JointState, ROBOT_JOINT_STATES_TOPIC, self._on_state,
                                      qos_profile_sensor_data)

    def _on_state(self, message):
        with self.lock:
            self.states.append(message)

    def latest(self) -> dict:
        """read(): name → (position, velocity, effort) of the latest joint state."""
        with self.lock:
            if not self.states:
                return {}
            m = self.states[-1]
        return {name: (m.position[i], m.velocity[i], m.effort[i])
                for i, name in enumerate(m.name)}

    def write(self, commands: dict) -> None:
        """write(): ``commands`` joint → value of its command interface."""
        message = JointState()
        message.header.stamp = self.node.get_clock().now().to_msg()
        for name, interface in self.joints:
            message.name.append(name)
            getattr(message, interface).append(float(commands[name]))
        self.commands.publish(message)

    def connected(self) -> bool:
        return self.commands.get_subscription_count() > 0 and bool(self.latest())


@pytest.fixture
def hardware_of(tmp_path):
    """A node with ``args`` and the hardware interface's client for the block's ``joints``."""
    started = []

    def make(joints, *args):
        simulator = NodeProcess(tmp_path, *FAST, *args, env=child_env(DOMAIN_ID))
        started.append(simulator)
        context = spinning(lambda c: HardwareInterface(c, joints), DOMAIN_ID)
        started.append(context)
        client = context.__enter__()
        wait_for(lambda: not simulator.running() or client.connected(),
                 "the node's joint-command subscription and first joint state", TIMEOUT)
        assert simulator.running(), simulator.output()
        return simulator, client

    with on_domain(DOMAIN_ID):
        yield make
        for item in reversed(started):
            if isinstance(item, NodeProcess):
                assert item.stop() == 0, item.output()
            else:
                item.__exit__(None, None, None)


def test_diff_drive_wheel_velocities_and_jtc_arm_positions_drive_the_robot(hardware_of,
                                                                           tmp_path):
    """Wheels by velocity (diff_drive_controller's interface), the arm by position
    (joint_trajectory_controller's): the wheels turn at the commanded speeds, the arm reaches the
    commanded pose, and our joint_states go to the interface's topic only. The node's bag
    records the commands as applied and re-simulates bit for bit."""
    joints = block("velocity", "position")
    bag = tmp_path / "ros2_control_run"
    simulator, hw = hardware_of(joints, "-p", "base_command:=velocity",
                                "-p", "arm_controller:=position", "-p", f"record:={bag}")
    names = [name for name, _ in joints]
    target = dict(zip(names[2:], SCENE.initial_q[ARM_Q] + [0.2, 0.05, -0.1, 0.05], strict=True))
    speeds = {"right_wheel_joint": 3.0, "left_wheel_joint": 2.0}
    # command only when it changes, as the interface's threshold does: a few sends, then none
    for _ in range(3):
        hw.write({**speeds, **target})

    def arrived():
        state = hw.latest()
        return all(abs(state[name][1] - speed) < 1e-3 for name, speed in speeds.items()) and \
            all(abs(state[name][0] - value) < 2e-3 for name, value in target.items())
    wait_for(arrived, "wheel speeds (3, 2) rad/s and the arm at its commanded pose", TIMEOUT)
    # no command timeout: long after the last command (> command_timeout 0.5 s of sim time)
    first = hw.latest()["right_wheel_joint"][0]
    wait_for(lambda: hw.latest()["right_wheel_joint"][0] > first + 3.0 * 2.0,
             "2 s of simulated time more", TIMEOUT)
    assert arrived(), hw.latest()
    topics = dict(hw.node.get_topic_names_and_types())
    assert "/joint_states" not in topics or not hw.node.get_publishers_info_by_topic(
        JOINT_STATES_TOPIC), "joint_states is joint_state_broadcaster's under ros2_control"
    assert simulator.stop() == 0, simulator.output()
    import subprocess

    from executables import executable
    result = subprocess.run([executable("replay"), str(bag), "--resimulate"],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0 and "IDENTICAL" in result.stdout, result.stdout + result.stderr


def test_efforts_by_joint_name_are_applied_and_reported_as_efforts(hardware_of):
    """Effort interfaces everywhere; a message whose names come in another order than the
    block's (fields as long as the names: by name) applies each value to the joint it names."""
    joints = block("effort", "effort")
    simulator, hw = hardware_of(joints, "-p", "base_command:=effort",
                                "-p", "arm_controller:=effort")
    names = [name for name, _ in joints]
    assert "mode: ros2_control hardware" in simulator.output()
    efforts = dict(zip(names, [0.1, 0.2, 1.5, 4.0, -0.3, 1.0], strict=True))
    hw.write(efforts)
    wait_for(lambda: all(hw.latest()[name][2] == value for name, value in efforts.items()),
             "the commanded efforts in the joint states", TIMEOUT)
    shuffled = JointState(name=names[::-1], effort=[0.5 * efforts[n] for n in names[::-1]])
    hw.commands.publish(shuffled)
    wait_for(lambda: all(hw.latest()[name][2] == 0.5 * value for name, value in efforts.items()),
             "the reordered efforts applied by name", TIMEOUT)
    # unknown joint: refused with one warning, the last command kept
    hw.commands.publish(JointState(name=["no_such_joint"], effort=[1.0]))
    wait_for(lambda: "no_such_joint" in simulator.output(), "the warning naming the joint",
             TIMEOUT)
    assert all(hw.latest()[name][2] == 0.5 * value for name, value in efforts.items())


def test_an_arm_position_the_engine_refuses_is_said_under_the_joint_command_topic(hardware_of):
    """A prismatic set-point far beyond its stroke, sent as a joint command: refused with the
    topic that carried it (it was said under arm_position_controller/commands, which nobody
    published on), the last set-point kept."""
    joints = block("velocity", "position")
    simulator, hw = hardware_of(joints, "-p", "base_command:=velocity",
                                "-p", "arm_controller:=position")
    names = [name for name, _ in joints]
    start = dict(zip(names, [0.0, 0.0, *SCENE.initial_q[ARM_Q]], strict=True))
    hw.write({**start, "arm_prismatic_1": 100.0})
    wait_for(lambda: "keeping the last set-point" in simulator.output(), "the refusal", TIMEOUT)
    line = next(line for line in simulator.output().splitlines()
                if "keeping the last set-point" in line)
    assert f"{JOINT_COMMANDS_TOPIC}: " in line and "arm_position_controller" not in line, line


def test_a_partial_command_keeps_the_other_joints_commands(hardware_of):
    joints = block("effort", "effort")
    simulator, hw = hardware_of(joints, "-p", "base_command:=effort",
                                "-p", "arm_controller:=effort")
    names = [name for name, _ in joints]
    hw.write(dict.fromkeys(names, 0.25))
    wait_for(lambda: all(hw.latest()[n][2] == 0.25 for n in names), "efforts 0.25", TIMEOUT)
    hw.commands.publish(JointState(name=["left_wheel_joint"], effort=[-0.5]))
    expected = {**dict.fromkeys(names, 0.25), "left_wheel_joint": -0.5}
    wait_for(lambda: all(hw.latest()[n][2] == v for n, v in expected.items()),
             "only the left wheel's effort changed", TIMEOUT)


def test_ros2_control_with_the_trajectory_controller_inside_is_a_one_line_error(tmp_path):
    import subprocess

    from executables import executable
    result = subprocess.run([executable("simulator"), "--ros-args", "-p", "ros2_control:=true",
                             "-p", "arm_controller:=joint_trajectory"],
                            env=child_env(DOMAIN_ID), capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "ros2_control" in lines[0], result.stderr


def test_wheel_velocities_become_the_base_twist():
    """The conversion the intake applies: v = r(ω_R + ω_L)/2, ω = r(ω_R − ω_L)/(2b)."""
    from mobile_manip_sim.node.commands import JointCommands
    base = SCENE.robot.base
    joints = JointCommands.__new__(JointCommands)
    joints._velocity_mode, joints._r, joints._b = True, base.wheel_radius, base.half_track
    v, omega = joints.base(np.array([3.0, 2.0]))
    assert v == pytest.approx(base.wheel_radius * 2.5)
    assert omega == pytest.approx(base.wheel_radius * 1.0 / (2 * base.half_track))


def joint_commands(velocity_mode: bool = True, arm_interface: str = "position"):
    """A `JointCommands` of the scene's joints without a node."""
    from types import SimpleNamespace

    from mobile_manip_sim.node.commands import JointCommands

    class NoNode:
        def create_subscription(self, *args, **kwargs):
            return SimpleNamespace(topic_name=JOINT_COMMANDS_TOPIC)

    base = SCENE.robot.base
    return JointCommands(NoNode(), None, SCENE.robot.joint_names(), velocity_mode=velocity_mode,
                         arm_interface=arm_interface, wheel_radius=base.wheel_radius,
                         half_track=base.half_track,
                         arm_initial=np.array(SCENE.initial_q)[ARM_Q])


@pytest.mark.parametrize("velocity_mode, field, value, bound", [
    (True, "velocity", 1e308, "10000"), (True, "velocity", -2e4, "10000"),
    (False, "effort", 1e300, "1e+06")])
def test_a_wheel_command_beyond_the_scenes_bounds_is_refused_naming_the_joint(
        velocity_mode, field, value, bound):
    """1e308 rad/s passed as finite, and v = r(ω_R + ω_L)/2 overflowed in the engine: the
    segment failed naming efforts.cmd_vel and inf, not the joint that carried it."""
    joints = joint_commands(velocity_mode, "effort")
    names = SCENE.robot.joint_names()
    values, problem = joints.read(JointState(name=names[:2], **{field: [1.0, value]}))
    assert values is None and problem == f"{field} of {names[1]} is {value:g}: must be " \
                                         f"within ±{bound}"
    values, problem = joints.read(JointState(name=names[:2], **{field: [1.0, 2.0]}))
    assert problem is None and values[:2].tolist() == [1.0, 2.0]


def test_a_huge_unknown_joint_name_is_cut_in_the_refusal():
    values, problem = joint_commands().read(JointState(name=["j" * 1_000_000], effort=[1.0]))
    assert values is None and problem.startswith("unknown joint 'jjj") and len(problem) < 400


def test_a_nan_joint_command_is_no_command_and_an_infinite_one_is_refused():
    """ros2_control writes NaN for "no command" (a command interface never written, or one a
    controller released): that joint keeps its last command while the others take theirs; an
    infinite value refuses the whole message."""
    names = SCENE.robot.joint_names()
    initial = np.array(SCENE.initial_q)[ARM_Q]
    joints = joint_commands()
    nan = float("nan")
    full = JointState(name=names, velocity=[1.0, nan, nan, nan, nan, nan],
                      position=[nan, nan, 0.4, nan, -0.1, 0.5])
    values, problem = joints.read(full)
    assert problem is None
    assert values.tolist() == [1.0, 0.0, 0.4, initial[1], -0.1, 0.5]
    short = JointState(name=names, velocity=[nan, 2.0], position=[nan, 0.6, nan, nan])
    values, problem = joints.read(short)   # the fields as the hardware interface fills them
    assert problem is None and values.tolist() == [0.0, 2.0, *initial[:1], 0.6, *initial[2:]]
    for bad in (float("inf"), -float("inf")):
        values, problem = joints.read(JointState(name=names[:2], velocity=[1.0, bad]))
        assert values is None and problem == f"velocity of {names[1]} is {bad}"
