"""The node's parameters: their table (the one owner: the shell declares it, the shipped params
file is checked against it, `--help` prints it) and `read`, which validates the values once into
a `NodeParameters` record. No ROS: the shell hands in the values rclpy parsed."""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Mapping, NamedTuple

from ..engine.simulation import DEFAULT_WHEEL_SPEED_GAINS
from ..ros.frames import BASE_LINK, FOOTPRINT, ODOM
from ..ros.imu import ImuNoise
from ..ros.topics import BASE_COMMANDS
from ..scene import limits
from ..scene.arm_controller import (
    ARM_MODES,
    DEFAULT_FEEDFORWARD,
    FEEDFORWARDS,
    ArmController,
    ModelError,
)
from ..scene.errors import UserError
from ..scene.loading import METHODS

NODE_NAME = "mobile_manip_sim"
PUBLISH_TF = ("all", "base", "none")
IMU_NOISE = "imu.noise."
# A tf frame name (and a frame_prefix): letters, digits, _ . - and single / between parts; no
# leading /, no white space (tf2 refuses or silently mangles the others).
FRAME_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]*(/[A-Za-z0-9_.\-]+)*")
# Values a YAML null is written as (-p record:=null): a mistake, not a directory name.
NULL_WORDS = ("null", "Null", "NULL", "~")
# The slowest pacing the node takes: at 100 Hz a publication every 10 s of wall time. Slower
# ones (1e-12 once stopped the node for good) are refused; 0 means as fast as possible.
MIN_REAL_TIME_FACTOR = 1e-3


class Parameter(NamedTuple):
    default: object
    description: str
    range: tuple[float, float] | None = None   # floats: the declared [low, high]
    dynamic: bool = False                      # may be set while the node runs


PARAMETERS = {
    "scene": Parameter("", "Scene YAML file; empty = the embedded paper scene."),
    "publish_rate": Parameter(100.0, "Publications per second of SIMULATED time (Hz).",
                              limits.PUBLISH_RATE),
    "real_time_factor": Parameter(1.0, f"Simulated seconds per wall second: 0 (as fast as "
                                       f"possible) or at least {MIN_REAL_TIME_FACTOR:g}.",
                                  limits.REAL_TIME_FACTOR, True),
    "command_timeout": Parameter(0.5, "Seconds of SIMULATED time after the last command of a "
                                      "group (wheels, arm) before its efforts fall to zero; 0 "
                                      "disables.", limits.COMMAND_TIMEOUT, True),
    "odom_frame": Parameter(ODOM, "frame_id of /odom and parent frame of /tf."),
    "base_frame": Parameter(FOOTPRINT, "child_frame_id of /odom and /tf, and the URDF's "
                                              "root: the frame on the ground under the axle "
                                              "midpoint (base_link is fixed at wheel-radius "
                                              "height above it)."),
    # --- what viewers and estimators see (node/view.py) ---
    "publish_tf": Parameter("all", "all: tf carries odom_frame → base_frame and every moving "
                                   "joint at the publication rate, tf_static every fixed joint; "
                                   "base: only odom_frame → base_frame (for robot_state_publisher "
                                   "users); none: nothing (tf needs tf2_msgs)."),
    "frame_prefix": Parameter("", "Prefix of every frame the node names (tf, tf_static, /odom, "
                                  "/imu, the URDF's links), e.g. robot1/: two robots then make "
                                  "one tree without a shared frame. Joint names stay bare."),
    "publish_clock": Parameter(True, "Publish simulated time on the absolute /clock (namespaces "
                                     "do not move it); false leaves it to another simulator "
                                     "and follows the /clock it hears: a state goes out once "
                                     "that clock has reached its stamp (real_time_factor "
                                     "then moot)."),
    "foxglove_port": Parameter(0, "Port of a Foxglove WebSocket server inside the node (the "
                                  "channels of simulate --view); 0 = off.", limits.PORT),
    "foxglove_host": Parameter("127.0.0.1", "Address the Foxglove server listens on: 127.0.0.1 "
                                            "this machine only; 0.0.0.0 every interface (a "
                                            "laptop on the network)."),
    "browser_port": Parameter(0, "Port of the browser view inside the node (a local web page "
                                 "drawing the robot, as simulate --view browser); 0 = off.",
                              limits.PORT),
    "browser_host": Parameter("127.0.0.1", "Address the browser view listens on: 127.0.0.1 this "
                                           "machine only; 0.0.0.0 every interface."),
    "imu.noise.angular_velocity_stddev": Parameter(
        [0.0, 0.0, 0.0], "IMU: white-noise standard deviation of the rate gyro per axis "
                         "(x, y, z, rad/s); its variance is the message's covariance."),
    "imu.noise.angular_velocity_bias": Parameter(
        [0.0, 0.0, 0.0], "IMU: constant bias of the rate gyro per axis (rad/s)."),
    "imu.noise.linear_acceleration_stddev": Parameter(
        [0.0, 0.0, 0.0], "IMU: white-noise standard deviation of the accelerometer per axis "
                         "(m/s²); its variance is the message's covariance."),
    "imu.noise.linear_acceleration_bias": Parameter(
        [0.0, 0.0, 0.0], "IMU: constant bias of the accelerometer per axis (m/s²)."),
    "imu.noise.seed": Parameter(0, "IMU: seed of the noise (sample k's noise depends only on "
                                   "the seed and k: runs and re-simulations read the same).",
                                limits.IMU_SEED),
    # --- end of node/view.py's parameters ---
    "record": Parameter("", "Record a rosbag2 (MCAP) bag to this new directory; empty = off."),
    "synchronous": Parameter(False, "Lockstep: after publishing state k, compute segment k only "
                                    "once a new command has arrived (or sync_timeout has "
                                    "passed); the first state waits for a state subscriber and "
                                    "a command publisher."),
    "base_command": Parameter("effort", "effort: the wheels take torques from "
                                        "wheel_effort_controller/commands; velocity: the base "
                                        "takes cmd_vel, turned into wheel torques by a "
                                        "wheel-speed PI loop inside the simulated system."),
    "ros2_control": Parameter(False, "Be the hardware of ros2_control's topic-based interface "
                                     "(joint_state_topic_hardware_interface): take sensor_msgs/"
                                     "JointState commands by joint name on "
                                     "topic_based_joint_commands and publish the joint states on "
                                     "topic_based_joint_states instead of joint_states (whose "
                                     "publisher is then joint_state_broadcaster); the wheels' "
                                     "interface follows base_command, the arm's arm_controller "
                                     "(position, velocity or effort); no command times out."),
    "cmd_vel_stamped": Parameter(False, "Velocity mode: cmd_vel is geometry_msgs/TwistStamped "
                                        "(as Jazzy's diff_drive_controller takes it) rather "
                                        "than Twist."),
    "wheel_speed.kp": Parameter(DEFAULT_WHEEL_SPEED_GAINS[0], "Velocity mode: proportional gain "
                                "of the wheel-speed loop (N·m·s/rad).", limits.WHEEL_SPEED_GAIN),
    "wheel_speed.ki": Parameter(DEFAULT_WHEEL_SPEED_GAINS[1], "Velocity mode: integral gain of "
                                "the wheel-speed loop (N·m/rad).", limits.WHEEL_SPEED_GAIN),
    "controller_rate": Parameter(-1.0, "Update rate (Hz) of the simulated controllers (the "
                                       "wheel-speed loop, the arm controller), as ros2_control's "
                                       "controller manager's update_rate: their efforts are held "
                                       "between updates; 0 = continuous controllers; -1 = the "
                                       "scene's controller.rate.",
                                 (-1.0, limits.CONTROL_RATE[1])),
    "sync_timeout": Parameter(1.0, "Synchronous mode: wall seconds to wait for a command before "
                                   "holding the last one (and saying so).", limits.SYNC_TIMEOUT),
    "integrator.method": Parameter("", f"Integrator overriding the scene's ({', '.join(METHODS)}"
                                       f"); empty = the scene's."),
    "integrator.dt": Parameter(0.0, "Fixed step (s) overriding the scene's; 0 = the scene's.",
                               limits.INTEGRATOR_OVERRIDE),
    "integrator.rtol": Parameter(0.0, "Relative tolerance overriding the scene's; 0 = the "
                                      "scene's.", limits.INTEGRATOR_OVERRIDE),
    "integrator.atol": Parameter(0.0, "Absolute tolerance overriding the scene's; 0 = the "
                                      "scene's.", limits.INTEGRATOR_OVERRIDE),
}


# --- the arm controller (start-up only): a `scene.arm_controller.ArmController` --------------
# The gains take one number (every joint) or a list (one per arm joint); "" = the documented
# defaults for the scene's robot (`engine.arm_control.for_robot`). Declared with dynamic typing.
# The default mode holds the initial pose, as a ros2_control robot whose
# joint_trajectory_controller starts with the current state (docs/controllers.md).
ARM_GAIN_PARAMETERS = ("arm_gains.kp", "arm_gains.ki", "arm_gains.kd")
DEFAULT_ARM_CONTROLLER = "joint_trajectory"
PARAMETERS.update({
    "arm_controller": Parameter(DEFAULT_ARM_CONTROLLER,
                                f"How the arm is driven ({', '.join(ARM_MODES)}): effort takes "
                                "arm_effort_controller/commands; the others run a PID per joint "
                                "inside the simulated system on arm_position_controller/commands,"
                                " arm_velocity_controller/commands, or "
                                "joint_trajectory_controller's topic and action (the default: "
                                "holds the initial pose until a trajectory comes)."),
    "arm_feedforward": Parameter(DEFAULT_FEEDFORWARD,
                                 f"An arm controller's model-based feed-forward "
                                 f"({', '.join(FEEDFORWARDS)}), from the project's inverse "
                                 f"dynamics."),
    "arm_model_error.mass": Parameter(0.0, "The feed-forward's relative error on every link's "
                                           "mass (0.2: 20 % heavier than the plant).",
                                      limits.MODEL_ERROR),
    "arm_model_error.inertia": Parameter(0.0, "The feed-forward's relative error on the "
                                              "rotational inertias (rods' cross-section, base "
                                              "yaw, wheel spin).", limits.MODEL_ERROR),
    "arm_model_error.payload": Parameter(-1.0, "The payload mass (kg) the feed-forward assumes; "
                                               "negative = the scene's.",
                                         limits.MODEL_PAYLOAD),
    **{name: Parameter("", f"An arm controller's {name[-2:]} per joint: one number for all, a "
                           f"list (arm_revolute_1, arm_prismatic_1, …), or \"\" for the "
                           f"defaults (README).") for name in ARM_GAIN_PARAMETERS},
})


def arm_gains(name: str, value) -> tuple:
    """The gains of parameter ``name``: () for "" (the defaults), else a tuple of numbers
    (`ArmController` checks their range, the engine their count); UserError naming it
    otherwise."""
    if isinstance(value, str) and value == "":
        return ()
    if value is None:   # -p arm_gains.kp:=[]: rclpy cannot type an empty list
        raise UserError(name, "expected a number or a list of numbers, got an empty list")
    scalar = isinstance(value, (bool, int, float, str))
    values = [value] if scalar else list(value)   # a list: rclpy gives an array.array
    if not values or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in values):
        raise UserError(name, f"expected a number or a list of numbers, got {value!r}")
    return tuple(float(v) for v in values)


def bounds(name: str) -> str:
    """The declared range of parameter ``name`` as a message shows it: ``[0.001, 100000]``."""
    return "[{}, {}]".format(*(v if isinstance(v, int) else f"{v:g}"
                               for v in PARAMETERS[name].range))


def expected_kind(name: str) -> str:
    """What a value of parameter ``name`` must be written as, for error messages."""
    default = PARAMETERS[name].default
    if name in ARM_GAIN_PARAMETERS:
        return "a number or a list of numbers"
    if isinstance(default, bool):
        return "true or false"
    if isinstance(default, float):
        return "a floating-point number (write 1.0, not 1)"
    if isinstance(default, int):
        return "an integer"
    if isinstance(default, list):
        return f"a list of {len(default)} floating-point numbers (write [0.1, 0.0, 0.0])"
    return "a string"


@dataclass(frozen=True)
class NodeParameters:
    """The node's parameters as read at start-up, validated."""
    scene: str                     # "" = the embedded paper scene
    publish_rate: float            # Hz of simulated time
    real_time_factor: float
    command_timeout: float         # s of simulated time, 0 = off
    odom_frame: str
    base_frame: str
    publish_tf: str                # one of PUBLISH_TF
    frame_prefix: str
    publish_clock: bool
    foxglove_port: int             # 0 = off
    foxglove_host: str             # what the live view listens on
    browser_port: int              # 0 = off
    browser_host: str              # what the browser view listens on
    imu_noise: ImuNoise
    record: str                    # "" = off
    synchronous: bool
    sync_timeout: float            # wall s
    base_command: str              # one of BASE_COMMANDS
    cmd_vel_stamped: bool
    wheel_speed_gains: tuple[float, float]   # (kp, ki)
    controller_rate: float | None  # Hz; None = the scene's controller.rate
    method: str | None             # integrator overrides; None = the scene's
    dt: float | None
    rtol: float | None
    atol: float | None

    arm_controller: ArmController = ArmController()   # not yet resolved for the robot
    ros2_control: bool = False     # joint commands and states of the topic-based interface

    @property
    def velocity_mode(self) -> bool:
        return self.base_command == "velocity"


def value_problem(name: str, value) -> str | None:
    """Why ``value`` cannot be parameter ``name`` (beyond its declared type and range), or None.
    Checked at start-up and for every change while running."""
    if isinstance(value, float) and not math.isfinite(value):
        return f"must be finite, got {value}"
    if name == "controller_rate" and isinstance(value, (int, float)) and -1.0 < value < 0.0:
        return f"must be -1 (the scene's), 0 (continuous) or a rate in Hz, got {value:g}"
    if (name == "real_time_factor" and isinstance(value, (int, float))
            and 0.0 < value < MIN_REAL_TIME_FACTOR):
        return (f"must be 0 (as fast as possible) or at least {MIN_REAL_TIME_FACTOR:g}, got "
                f"{value:g}")
    return None


def read(values: Mapping[str, object]) -> NodeParameters:
    """The record of the parameter ``values`` (name → value, every name of PARAMETERS);
    UserError naming the first that is wrong."""
    for name in PARAMETERS:
        problem = value_problem(name, values[name])
        if problem is not None:
            raise UserError(name, problem)
    odom, base = values["odom_frame"], values["base_frame"]
    for name in ("odom_frame", "base_frame"):
        if not values[name] or values[name] == BASE_LINK or odom == base:
            raise UserError(name, f"{values[name]!r}: frame names must be non-empty, distinct, "
                                  f"and not base_link (the URDF's body frame)")
        if not FRAME_NAME.fullmatch(values[name]):
            raise UserError(name, f"{values[name]!r} is not a tf frame name (letters, digits, "
                                  f"_ . - and single / between parts; no leading /, no spaces)")
    if values["record"] in NULL_WORDS:
        raise UserError("record", f"{values['record']!r} is YAML's null, not a directory: give "
                                  f"a directory name, or \"\" for no recording")
    if values["base_command"] not in BASE_COMMANDS:
        raise UserError("base_command", f"{values['base_command']!r} is not effort or velocity")
    if values["ros2_control"] and values["arm_controller"] == "joint_trajectory":
        raise UserError("ros2_control", "takes the arm's commands from controller_manager: set "
                                        "arm_controller to position, velocity or effort (the "
                                        "arm's command interface; joint_trajectory_controller "
                                        "then runs in controller_manager)")
    view = _view_parameters(values)
    return NodeParameters(
        scene=values["scene"], publish_rate=values["publish_rate"],
        real_time_factor=values["real_time_factor"], command_timeout=values["command_timeout"],
        odom_frame=odom, base_frame=base, **view,
        record=values["record"], synchronous=values["synchronous"],
        sync_timeout=values["sync_timeout"], base_command=values["base_command"],
        cmd_vel_stamped=values["cmd_vel_stamped"],
        wheel_speed_gains=(values["wheel_speed.kp"], values["wheel_speed.ki"]),
        controller_rate=None if values["controller_rate"] < 0.0 else values["controller_rate"],
        method=values["integrator.method"] or None, dt=values["integrator.dt"] or None,
        rtol=values["integrator.rtol"] or None, atol=values["integrator.atol"] or None,
        arm_controller=ArmController(
            values["arm_controller"],
            *(arm_gains(name, values[name]) for name in ARM_GAIN_PARAMETERS),
            values["arm_feedforward"],
            ModelError(values["arm_model_error.mass"], values["arm_model_error.inertia"],
                       None if values["arm_model_error.payload"] < 0.0
                       else values["arm_model_error.payload"])),
        ros2_control=values["ros2_control"])


def _view_parameters(values: Mapping[str, object]) -> dict:
    """The NodeParameters fields of node/view.py's parameters, validated."""
    if values["publish_tf"] not in PUBLISH_TF:
        raise UserError("publish_tf", f"{values['publish_tf']!r} is not one of "
                                      f"{', '.join(PUBLISH_TF)}")
    prefix = values["frame_prefix"]
    if prefix and not FRAME_NAME.fullmatch(prefix.removesuffix("/")):
        raise UserError("frame_prefix", f"{prefix!r}: tf frame names start with no '/', hold "
                                        f"no white space and no empty part ('//')")
    from ..ros.live_view import check_host
    host = check_host(values["foxglove_host"], "foxglove_host")
    settings = {name[len(IMU_NOISE):]: value if isinstance(value, (str, int, float)) else
                list(value) for name, value in values.items() if name.startswith(IMU_NOISE)}
    return dict(publish_tf=values["publish_tf"], frame_prefix=prefix,
                publish_clock=values["publish_clock"], foxglove_port=values["foxglove_port"],
                foxglove_host=host, browser_port=values["browser_port"],
                browser_host=check_host(values["browser_host"], "browser_host"),
                imu_noise=ImuNoise.from_settings(settings, IMU_NOISE.rstrip(".")))
