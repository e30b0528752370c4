"""The one place that names the simulator's topics, their message types and their QoS.

In a bag a topic carries its canonical name (``/odom``): a bag holds one robot's run. The node
creates every topic under its RELATIVE name (``odom``), so ``__ns:=/robot1`` puts it at
``/robot1/odom`` and a remap (``-r odom:=ground_truth``) works as in any ROS node — except
/clock, /tf and /tf_static, which stay absolute whatever the namespace, as Gazebo's /clock and
tf2_ros's topics do (use_sim_time clients and tf listeners read them there).

  joint_states                      sensor_msgs/msg/JointState      state, reliable, depth 100
  odom                              nav_msgs/msg/Odometry           state
  clock                             rosgraph_msgs/msg/Clock         state
  tf                                tf2_msgs/msg/TFMessage          state: odom → root, every
                                                                    moving joint
  tf_static                         tf2_msgs/msg/TFMessage          latched: every fixed joint,
                                                                    one message
  robot_description                 std_msgs/msg/String             latched (transient local, 1)
  imu                               sensor_msgs/msg/Imu             state (imu.py)
  energy                            std_msgs/msg/Float64MultiArray  state: [T, V, T + V] (J),
                                                                    live view only
  wheel_effort_controller/commands  std_msgs/msg/Float64MultiArray  command, depth 10
  arm_effort_controller/commands    std_msgs/msg/Float64MultiArray  command
  cmd_vel                           geometry_msgs/msg/Twist (or TwistStamped)  command,
                                    velocity mode
  arm_position_controller/commands  std_msgs/msg/Float64MultiArray  command, arm_controller position
  arm_velocity_controller/commands  std_msgs/msg/Float64MultiArray  command, arm_controller velocity
  joint_trajectory_controller/joint_trajectory  trajectory_msgs/msg/JointTrajectory  command,
                                    arm_controller joint_trajectory (and the action
                                    joint_trajectory_controller/follow_joint_trajectory)
  joint_trajectory_controller/controller_state  control_msgs/msg/JointTrajectoryControllerState
                                    state, arm_controller joint_trajectory
  topic_based_joint_commands        sensor_msgs/msg/JointState      command, ros2_control: by
                                    joint name, from joint_state_topic_hardware_interface
  topic_based_joint_states          sensor_msgs/msg/JointState      state, ros2_control: what
                                    joint_states carries (which is then not published)

A bag holds the state topics, the view topics (what a viewer needs to draw the robot: /tf,
/tf_static, /robot_description; the latched ones with their transient-local QoS) and the command
topics of its run's mode (`recorded_topics`); a node's bag /imu too (re-simulated with its
noise). A bag recorded before the view topics existed has
none of them; replay and plot do not need them.
"""
from __future__ import annotations

from ..scene.arm_controller import EFFORT, MODES

JOINT_STATES_TOPIC = "/joint_states"
ODOM_TOPIC = "/odom"
CLOCK_TOPIC = "/clock"
TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"
DESCRIPTION_TOPIC = "/robot_description"
IMU_TOPIC = "/imu"
ENERGY_TOPIC = "/energy"
TF_TYPE = "tf2_msgs/msg/TFMessage"
WHEEL_TOPIC = "/wheel_effort_controller/commands"
CMD_VEL_TOPIC = "/cmd_vel"
ARM_TOPIC = MODES[EFFORT].topic   # the arm's effort commands
STATE_TOPICS = (JOINT_STATES_TOPIC, ODOM_TOPIC, CLOCK_TOPIC)
# Published once (at start and on reset), transient local, depth 1: late joiners get them.
LATCHED_TOPICS = (TF_STATIC_TOPIC, DESCRIPTION_TOPIC)
VIEW_TOPICS = (TF_TOPIC, TF_STATIC_TOPIC, DESCRIPTION_TOPIC)
COMMAND_TOPICS = (WHEEL_TOPIC, ARM_TOPIC, CMD_VEL_TOPIC)
# The base's command modes (the node's base_command parameter, a bag's base_command metadata)
# and the topic that commands the base in each.
BASE_COMMANDS = ("effort", "velocity")
BASE_COMMAND_TOPICS = dict(zip(BASE_COMMANDS, (WHEEL_TOPIC, CMD_VEL_TOPIC), strict=True))
# In a bag cmd_vel is always a Twist (the applied v, ω; its log time says when it applied),
# whichever of Twist or TwistStamped the node took.
CMD_VEL_TYPE = "geometry_msgs/msg/Twist"

# Topic → message type name, as bags and `ros2 topic` spell it: the topics of a bag of an
# effort-commanded run (headless runs and base_command effort).
TOPIC_TYPES = {
    JOINT_STATES_TOPIC: "sensor_msgs/msg/JointState",
    ODOM_TOPIC: "nav_msgs/msg/Odometry",
    CLOCK_TOPIC: "rosgraph_msgs/msg/Clock",
    WHEEL_TOPIC: "std_msgs/msg/Float64MultiArray",
    ARM_TOPIC: "std_msgs/msg/Float64MultiArray",
    TF_TOPIC: TF_TYPE,
    TF_STATIC_TOPIC: TF_TYPE,
    DESCRIPTION_TOPIC: "std_msgs/msg/String",
}
# The live view's channels (live_view.py): the states, the view topics, the IMU and the energy.
LIVE_TOPIC_TYPES = {topic: TOPIC_TYPES[topic] for topic in (*VIEW_TOPICS, JOINT_STATES_TOPIC,
                                                            ODOM_TOPIC)}
LIVE_TOPIC_TYPES.update({IMU_TOPIC: "sensor_msgs/msg/Imu",
                         ENERGY_TOPIC: "std_msgs/msg/Float64MultiArray"})
# Every topic one of our bags may hold (/imu: a node's bags).
BAG_TOPIC_TYPES = {**TOPIC_TYPES, CMD_VEL_TOPIC: CMD_VEL_TYPE,
                   IMU_TOPIC: LIVE_TOPIC_TYPES[IMU_TOPIC]}

# --- the arm's controllers (node parameter arm_controller; a bag's arm_controller metadata) ---
# One command topic per mode, as ros2_controllers names them (the table of modes,
# `scene.arm_controller.MODES`); joint_trajectory mode also has the FollowJointTrajectory action
# and publishes the controller's state. A bag records the commands of its run's mode as applied
# (the row's message type): arrays, or trajectories in the node's joint order, stamped with the
# simulated time they applied (no points: hold where it is).
ARM_POSITION_TOPIC = MODES["position"].topic
ARM_VELOCITY_TOPIC = MODES["velocity"].topic
TRAJECTORY_TOPIC = MODES["joint_trajectory"].topic
TRAJECTORY_ACTION = "/joint_trajectory_controller/follow_joint_trajectory"
CONTROLLER_STATE_TOPIC = "/joint_trajectory_controller/controller_state"
TRAJECTORY_ACTION_TYPE = "control_msgs/action/FollowJointTrajectory"
CONTROLLER_STATE_TYPE = "control_msgs/msg/JointTrajectoryControllerState"
TRAJECTORY_TYPE = MODES["joint_trajectory"].recorded
ARM_COMMAND_TOPICS = {name: mode.topic for name, mode in MODES.items()}
BAG_TOPIC_TYPES.update({mode.topic: mode.recorded for mode in MODES.values()})
COMMAND_TOPICS = (*COMMAND_TOPICS, *(topic for topic in ARM_COMMAND_TOPICS.values()
                                     if topic not in COMMAND_TOPICS))

# --- ros2_control's topic-based hardware interface (node parameter ros2_control) ---
# joint_state_topic_hardware_interface publishes sensor_msgs/JointState commands by joint name
# (position, velocity or effort per the joint's command interface; QoS depth 1, reliable) and
# reads joint states (SensorDataQoS: best effort, which our reliable publisher serves). The
# names are those of that interface's documented example; the URDF block names them
# (urdf.ros2_control_block).
JOINT_COMMANDS_TOPIC = "/topic_based_joint_commands"
ROBOT_JOINT_STATES_TOPIC = "/topic_based_joint_states"

def recorded_topics(base_command: str = "effort", view: bool = True, imu: bool = False,
                    arm_controller: str = "effort") -> dict:
    """Topic → type of the bag of a run whose base takes ``base_command`` (effort|velocity)
    and whose arm is driven by ``arm_controller`` (ARM_COMMAND_TOPICS' modes), with the view
    topics unless ``view`` is false, and /imu if ``imu``."""
    base, arm = BASE_COMMAND_TOPICS[base_command], ARM_COMMAND_TOPICS[arm_controller]
    return {topic: kind for topic, kind in BAG_TOPIC_TYPES.items()
            if (topic not in BASE_COMMAND_TOPICS.values() or topic == base)
            and (topic not in ARM_COMMAND_TOPICS.values() or topic == arm)
            and (view or topic not in VIEW_TOPICS) and (imu or topic != IMU_TOPIC)}
STATE_QOS_DEPTH = 100      # the node's state publishers: room for slow subscribers
COMMAND_QOS_DEPTH = 10     # rclpy's default publisher depth, what command senders use


def relative(topic: str) -> str:
    """The name the node gives ``topic``: relative, so namespaces and remaps apply."""
    return topic.lstrip("/")


def state_qos():
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    return QoSProfile(depth=STATE_QOS_DEPTH, reliability=ReliabilityPolicy.RELIABLE)


def latched_qos():
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    return QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def command_qos():
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    return QoSProfile(depth=COMMAND_QOS_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
