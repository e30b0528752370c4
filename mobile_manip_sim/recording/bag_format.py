"""A bag of ours: what mobile_manip_sim adds to a rosbag2 bag, written by `RunRecorder` and read
back here by replay, re-simulation and the plots.

Beside the recorded topics (``topics.recorded_topics``) a bag of ours holds:

- attachment ``scene.yaml`` (SCENE_ATTACHMENT): the full scene, defaults applied;
- MCAP metadata ``mobile_manip_sim`` (METADATA_NAME): a map of strings — the package version,
  the integrator settings, the scene name, the source (``simulate`` or ``node``, SOURCES), the
  source's rate, a `simulate` run's duration, the controllers' update rate (``controller_rate``,
  Hz; 0: continuous), the base command mode and, in velocity mode, the
  wheel-speed gains, a node's IMU noise settings (`imu.ImuNoise.as_metadata`); floats as
  ``repr`` (exact). `run_metadata` writes it,
  `checked_run_metadata` checks it on the way back in;
- attachment ``impacts.json`` (IMPACTS_ATTACHMENT): the end-stop impacts, one record of
  IMPACT_FIELDS each (`read_impacts`), and since the energy ledger also ``held`` and
  ``hold_energy`` (J) per record;
- MCAP metadata ``mobile_manip_sim_energy`` (LEDGER_NAME), written when the bag closes: the
  run's energy ledger (`energy_ledger`) — impacts, the energy the impact law removed, how many
  impacts the engine held and the energy those holds removed beyond the law (J, ``repr``);
  `checked_energy_ledger` checks it.

`RecordedRun` is what such a bag says about its run: scene, integrator, source, rates, its time
line and the recorded commands (starting a re-run from it is replay's:
`replay.resimulate.start_run`). Messages are decoded by `decode` (the rclpy class named by the
bag's type name), their stamps read by `stamp_ns`. ROS is imported only to decode: a CSV's
impacts are checked here too (`impact_record`) without it.
"""
from __future__ import annotations

from mobile_manip_sim import __version__
from mobile_manip_sim.recording.arm_metadata import (
    MODEL_ERROR_FIELDS,
    arm_controller_from_metadata,
    check_gain_counts,
)
from mobile_manip_sim.ros.imu import METADATA_KEYS, METADATA_SEED, ImuNoise
from mobile_manip_sim.ros.message_types import message_class
from mobile_manip_sim.ros.topics import (
    ARM_TOPIC,
    BAG_TOPIC_TYPES,
    BASE_COMMAND_TOPICS,
    BASE_COMMANDS,
    JOINT_STATES_TOPIC,
    ODOM_TOPIC,
)
from mobile_manip_sim.runtime.cli import critical
from mobile_manip_sim.runtime.timeline import NS, CommandHistory, Grid
from mobile_manip_sim.scene import limits, schema
from mobile_manip_sim.scene.coordinates import ARM_U, arm_width
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.methods import METHODS

METADATA_NAME = "mobile_manip_sim"
SCENE_ATTACHMENT = "scene.yaml"
IMPACTS_ATTACHMENT = "impacts.json"
SOURCES = ("node", "simulate")
SOURCE_RATE = {"simulate": "sample_rate", "node": "publish_rate"}   # source → its rate's key
RUN_METADATA_KEYS = ("version", "integrator_method", "dt", "rtol", "atol", "scene_name", "source",
                     "sample_rate", "publish_rate", "duration", "controller_rate",
                     "base_command", "wheel_speed_kp",
                     "wheel_speed_ki", *METADATA_KEYS.values(), METADATA_SEED)
# An arm controller's settings (a run not in effort mode): its mode, feedforward and gains per
# arm joint (space-separated reprs, exact), and its feed-forward's model error when it has one.
# An effort-mode bag has none of them.
ARM_METADATA_KEYS = ("arm_controller", "arm_feedforward", "arm_kp", "arm_ki", "arm_kd",
                     *(f"arm_model_error_{name}" for name in MODEL_ERROR_FIELDS))
RUN_METADATA_KEYS += ARM_METADATA_KEYS
RUN_METADATA_NUMBERS = {"dt": limits.DT, "rtol": limits.RTOL, "atol": limits.ATOL,
                        "sample_rate": limits.SAMPLE_RATE, "publish_rate": limits.SAMPLE_RATE,
                        "duration": limits.RECORDED_DURATION,
                        "controller_rate": limits.CONTROL_RATE,
                        "wheel_speed_kp": limits.WHEEL_SPEED_GAIN,
                        "wheel_speed_ki": limits.WHEEL_SPEED_GAIN}
IMPACT_FIELDS = ("time", "link", "stop", "ld_before", "ld_after", "energy_lost", "resting")
LEDGER_NAME = "mobile_manip_sim_energy"
LEDGER_KEYS = ("impacts", "impact_energy_lost", "holds", "hold_energy")


def energy_ledger(impacts: list[dict]) -> dict:
    """The ``mobile_manip_sim_energy`` metadata map of a run's impact records (`Impact.as_dict`):
    counts and joules (the law's losses, the holds' energy) as strings, floats as ``repr``."""
    return {"impacts": str(len(impacts)),
            "impact_energy_lost": repr(float(sum(i["energy_lost"] for i in impacts))),
            "holds": str(sum(1 for i in impacts if i.get("held"))),
            "hold_energy": repr(float(sum(i.get("hold_energy", 0.0) for i in impacts)))}


def checked_energy_ledger(value, path: str = LEDGER_NAME) -> dict:
    """A bag's energy ledger checked (its four keys, counts and finite joules ≥ 0), parsed."""
    value = schema.string_map(value, path, max_entries=len(LEDGER_KEYS), max_length=40)
    schema.keys(value, path, required=LEDGER_KEYS, optional=[])
    parsed = {}
    for key in LEDGER_KEYS:
        try:
            number = float(value[key])
        except ValueError:
            raise UserError(f"{path}.{key}",
                            f"expected a number, got {schema.short(value[key])}") from None
        number = schema.number(number, f"{path}.{key}", nonnegative=True)
        if key in ("impacts", "holds"):
            if number != int(number):
                raise UserError(f"{path}.{key}", f"expected a count, got {value[key]}")
            number = int(number)
        parsed[key] = number
    return parsed


# --- the run metadata ------------------------------------------------------------------------

def run_metadata(scene, settings, extra: dict) -> dict:
    """The ``mobile_manip_sim`` metadata map: everything besides the scene that a re-run needs.
    ``controller_rate``: the scene's ``controller.rate`` unless `extra` names the rate the run
    used (a node's ``controller_rate`` parameter)."""
    from mobile_manip_sim.scene.controller import control_rate

    metadata = {"version": __version__, "integrator_method": settings.method,
                "dt": repr(float(settings.dt)), "rtol": repr(float(settings.rtol)),
                "atol": repr(float(settings.atol)), "scene_name": scene.name,
                "controller_rate": repr(float(control_rate(scene.controller)))}
    metadata.update({key: str(value) for key, value in extra.items()})
    if metadata.get("source") not in SOURCES:
        raise UserError("source", f"{metadata.get('source')!r} is not one of {SOURCES}")
    return metadata


def checked_run_metadata(value, path: str = METADATA_NAME) -> dict:
    """A bag's ``mobile_manip_sim`` metadata map (strings, as MCAP stores them) checked and with
    its numbers parsed (repr-exact floats), for a replay or re-run to trust: the source's rate
    is required (and a `simulate` run's duration, which fixes its sample times)."""
    value = schema.string_map(value, path, max_entries=len(RUN_METADATA_KEYS), max_length=200)
    required = ("version", "integrator_method", "dt", "rtol", "atol", "source")
    schema.keys(value, path, required=required,
                optional=[key for key in RUN_METADATA_KEYS if key not in required])
    if value["integrator_method"] not in METHODS:
        raise UserError(f"{path}.integrator_method", f"unknown method "
                                                     f"{schema.short(value['integrator_method'])}")
    parsed = dict(value)
    for key, (lo, hi) in RUN_METADATA_NUMBERS.items():
        if key in value:
            try:
                number_value = float(value[key])
            except ValueError:
                raise UserError(f"{path}.{key}",
                                f"expected a number, got {schema.short(value[key])}") from None
            parsed[key] = schema.number(number_value, f"{path}.{key}", lo=lo, hi=hi)
    if value["source"] not in SOURCE_RATE:
        raise UserError(f"{path}.source",
                        f"expected node or simulate, got {schema.short(value['source'])}")
    if value.setdefault("base_command", "effort") not in BASE_COMMANDS:
        raise UserError(f"{path}.base_command", f"expected effort or velocity, got "
                                                f"{schema.short(value['base_command'])}")
    parsed["base_command"] = value["base_command"]
    needed = ([SOURCE_RATE[value["source"]]]
              + (["duration"] if value["source"] == "simulate" else []))
    if value["base_command"] == "velocity":   # the wheel-speed loop's gains shape the run
        needed += ["wheel_speed_kp", "wheel_speed_ki"]
    for key in needed:
        if key not in value:
            raise UserError(f"{path}.{key}", f"missing (a {value['source']} run records it)")
    parsed["arm_controller"] = arm_controller_from_metadata(value, path)
    return parsed


# --- messages ---------------------------------------------------------------------------------

def stamp_ns(stamp) -> int:
    """A message stamp (builtin_interfaces/Time) in integer nanoseconds (the inverse of
    `messages.time_msg`)."""
    return stamp.sec * NS + stamp.nanosec


def decode(message, type_name: str | None = None):
    """The rclpy message of a `BagMessage`; with ``type_name``, its topic must carry that type.
    A payload that does not decode is one `UserError` naming the topic and the log time."""
    from rclpy.serialization import deserialize_message

    if type_name is not None and message.type_name != type_name:
        raise UserError(message.topic, f"recorded as {message.type_name}, expected {type_name}")
    try:
        # rclpy's pybind11 call swallows an exception raised inside it (a SIGINT's
        # KeyboardInterrupt while it builds the message became "does not decode", status 2):
        # a stop signal waits for its end.
        with critical():
            return deserialize_message(bytes(message.data), message_class(message.type_name))
    except UserError:
        raise
    except Exception as error:   # rclpy raises bare exceptions on bad CDR
        raise UserError(message.topic, f"message at {message.log_time_ns} ns does not decode as "
                                       f"{message.type_name} ({error})") from None


def first_message(bag, topics=None):
    """The first complete message of ``topics`` (all if None)."""
    for message in bag.messages(topics):
        return message
    raise UserError(str(bag.path), "no complete message in the bag (truncated before its first "
                                   "chunk?)")


# --- the attachments --------------------------------------------------------------------------

def read_scene(bag):
    """The scene of the ``scene.yaml`` attachment, checked as a scene file is; None if the bag
    has none (not recorded by mobile_manip_sim)."""
    from mobile_manip_sim.scene.loading import scene_from_text

    data = bag.attachments().get(SCENE_ATTACHMENT)
    if data is None:
        return None
    where = f"{bag.path}: {SCENE_ATTACHMENT}"
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise UserError(where, f"not UTF-8 text (byte {error.start})") from None
    return scene_from_text(text, where)


def read_impacts(bag, n_links: int) -> list[dict]:
    """The ``impacts.json`` attachment's records (`impact_record`); none if it has none."""
    data = bag.attachments().get(IMPACTS_ATTACHMENT)
    if data is None:
        return []
    where = f"{bag.path}: {IMPACTS_ATTACHMENT}"
    records = schema.sequence(schema.load_json(data, where), where)
    return [impact_record(record, where, i + 1, n_links) for i, record in enumerate(records)]


def impact_record(record, where: str, line, n_links: int) -> dict:
    """One impact record (CSV strings or JSON values) → typed dict; a damaged one (a missing
    field, a non-number, a link the scene does not have) is one UserError naming it."""
    key = f"{where}: impact {line}"
    record = schema.mapping(record, key)
    missing = [name for name in IMPACT_FIELDS if name not in record]
    if missing:
        raise UserError(key, f"missing {', '.join(missing)}")

    def number(name):
        value = record[name]
        if isinstance(value, str):   # a CSV cell
            try:
                value = float(value)
            except ValueError:
                raise UserError(f"{key}.{name}", f"expected a number, got {schema.short(value)}") \
                    from None
        return schema.number(value, f"{key}.{name}")

    link = record["link"]
    if isinstance(link, str) and link.strip().isdigit() and len(link) <= schema.MAX_INT_DIGITS:
        link = int(link)
    resting = record["resting"]
    if isinstance(resting, str):
        resting = resting.strip().lower() in ("true", "1", "yes")
    impact = {"time": number("time"), "link": schema.integer(link, f"{key}.link", lo=1, hi=n_links),
              "stop": record["stop"], "ld_before": number("ld_before"),
              "ld_after": number("ld_after"), "energy_lost": number("energy_lost"),
              "resting": schema.flag(resting, f"{key}.resting")}
    if impact["stop"] not in ("lower", "upper"):
        raise UserError(f"{key}.stop",
                        f"expected lower or upper, got {schema.short(impact['stop'])}")
    return impact


# --- the recorded states ----------------------------------------------------------------------

def read_joint_states(bag, names, scene_name: str):
    """Every /joint_states message, its joints in the order ``names``: (stamps ns, log times
    ns, positions, velocities, efforts — a row None where a message has no effort per joint)."""
    topic = JOINT_STATES_TOPIC
    stamps, log_times, positions, velocities, efforts = [], [], [], [], []
    for message in bag.messages([topic]):
        state = decode(message, BAG_TOPIC_TYPES[topic])
        index = {name: i for i, name in enumerate(state.name)}
        absent = [name for name in names if name not in index]
        if absent:
            plural = "s" if len(absent) > 1 else ""
            raise UserError(str(bag.path), f"{topic} lacks joint{plural} "
                                           f"{', '.join(absent)} of scene {scene_name!r}")
        order = [index[name] for name in names]
        position, velocity = list(state.position), list(state.velocity)
        if len(position) != len(state.name) or len(velocity) != len(state.name):
            raise UserError(str(bag.path), f"{topic}: a message without position or velocity "
                                           "for every joint")
        stamps.append(stamp_ns(state.header.stamp))
        log_times.append(message.log_time_ns)
        positions.append([position[i] for i in order])
        velocities.append([velocity[i] for i in order])
        effort = list(state.effort)
        efforts.append([effort[i] for i in order] if len(effort) == len(state.name) else None)
    return stamps, log_times, positions, velocities, efforts


def read_odometry(bag):
    """Every /odom message: (stamps ns, rows of (x, y, orientation, v_x, v_y, ω)), the
    orientation the message's quaternion, the twist in the base frame."""
    stamps, rows = [], []
    for message in bag.messages([ODOM_TOPIC]):
        odometry = decode(message, BAG_TOPIC_TYPES[ODOM_TOPIC])
        pose, twist = odometry.pose.pose, odometry.twist.twist
        stamps.append(stamp_ns(odometry.header.stamp))
        rows.append((pose.position.x, pose.position.y, pose.orientation, twist.linear.x,
                     twist.linear.y, twist.angular.z))
    return stamps, rows


def read_commands(bag, topic: str, width: int) -> CommandHistory:
    """The commands recorded on ``topic`` (each ``width`` values), held from their log times."""
    from mobile_manip_sim.ros.messages import command_values

    history = CommandHistory()
    for message in bag.messages([topic]):
        values = command_values(topic, decode(message, BAG_TOPIC_TYPES[topic]))
        if len(values) != width:
            raise UserError(topic, f"command of {len(values)} values, expected {width}")
        try:
            history.add(message.log_time_ns, values)
        except ValueError as error:
            raise UserError(topic, str(error)) from None
    return history


# --- the recorded run -------------------------------------------------------------------------

class RecordedRun:
    """What a bag of ours says about its run: scene, integrator, source, rates."""

    def __init__(self, bag):
        from mobile_manip_sim.scene.loading import check_work, make_integrator

        self.bag = bag
        metadata = bag.metadata().get(METADATA_NAME)
        if SCENE_ATTACHMENT not in bag.attachments() or metadata is None:
            raise UserError(str(bag.path), "not recorded by mobile_manip_sim (no scene.yaml "
                                           "attachment or mobile_manip_sim metadata): cannot "
                                           "resimulate")
        self.scene = read_scene(bag)
        # The metadata is checked here (keys, types, ranges) and the run's work by the limits
        # `simulate` applies: a crafted bag cannot ask for a billion sample times.
        self.metadata = metadata = checked_run_metadata(metadata, METADATA_NAME)
        self.source = metadata["source"]
        self.settings = make_integrator(self.scene.integrator, metadata["integrator_method"],
                                        metadata["dt"], metadata["rtol"], metadata["atol"],
                                        prefix=f"{METADATA_NAME}")
        self.rate = metadata[SOURCE_RATE[self.source]]
        self.duration = metadata.get("duration")
        if self.source == "simulate":
            check_work(self.duration, self.settings, f"{METADATA_NAME}.duration",
                       f"{METADATA_NAME}.dt", self.rate, f"{METADATA_NAME}.sample_rate")
        # A headless run ends at its duration (without one, its grid is endless like a node's).
        self.grid = Grid(self.rate, self.duration if self.source == "simulate" else None)
        self.base_command = metadata["base_command"]
        self.velocity = self.base_command == "velocity"
        self.gains = ((metadata["wheel_speed_kp"], metadata["wheel_speed_ki"]) if self.velocity
                      else None)
        # None: a bag that names none (recorded before the controllers were sampled)
        self.control_rate = metadata.get("controller_rate")
        self.names = self.scene.robot.joint_names()
        self.arm_controller = metadata["arm_controller"]
        check_gain_counts(self.arm_controller, arm_width(len(self.names)), METADATA_NAME)
        self.imu_noise = ImuNoise.from_metadata(metadata, METADATA_NAME)   # a node's /imu

    def check_robot(self) -> None:
        """The recorded topics fit this scene's robot: types, joint names, command lengths."""
        topics = self.bag.topics()
        for topic in (JOINT_STATES_TOPIC, ODOM_TOPIC):
            if topic not in topics:
                raise UserError(str(self.bag.path), f"no {topic} topic: nothing to compare")
        for topic, type_name in BAG_TOPIC_TYPES.items():
            if topic in topics and topics[topic] != type_name:
                raise UserError(topic, f"recorded as {topics[topic]}, expected {type_name} "
                                       f"(a bag from another robot?)")
        self.check_joint_state(decode(first_message(self.bag, JOINT_STATES_TOPIC)))

    def check_joint_state(self, message) -> None:
        names = list(message.name)
        if names != self.names or len(message.position) != len(self.names) \
                or len(message.velocity) != len(self.names):
            raise UserError(JOINT_STATES_TOPIC, f"joints {names} ({len(message.position)} "
                                                f"positions) do not match the bag's scene "
                                                f"{self.scene.name!r} with joints {self.names}: "
                                                f"a bag from another robot")

    def check_command(self, topic: str, values) -> None:
        expected = len(self.names[ARM_U]) if topic == ARM_TOPIC else 2
        if len(values) != expected:
            raise UserError(topic, f"{len(values)} values where the bag's scene "
                                   f"{self.scene.name!r} takes {expected}: a bag from another "
                                   f"robot")

    def segments(self, start: int, end: int):
        """The source's segments from stamp ``start`` to stamp ``end`` (ns): (segment start
        stamp, time in s the source advanced its engine to). One per recorded state, unless
        states are missing in between."""
        if self.source == "node":   # a node's run is as long as its bag says: bound the work
            from mobile_manip_sim.scene.loading import check_work
            check_work(end / NS, self.settings, f"{JOINT_STATES_TOPIC} stamp",
                       f"{METADATA_NAME}.dt", self.rate, f"{METADATA_NAME}.publish_rate")
        try:
            return self.grid.segments(start, end)
        except ValueError as error:
            raise UserError(JOINT_STATES_TOPIC, str(error)) from None

    def commands(self) -> tuple[CommandHistory, CommandHistory]:
        """The recorded base and arm commands (the base's: wheel torques, or v and ω)."""
        from mobile_manip_sim.ros.messages import command_values

        base_topic = BASE_COMMAND_TOPICS[self.base_command]
        histories = {base_topic: CommandHistory(), ARM_TOPIC: CommandHistory()}
        topics = [topic for topic in histories if topic in self.bag.topics()]
        for message in self.bag.messages(topics) if topics else ():
            values = command_values(message.topic, decode(message))
            self.check_command(message.topic, values)
            try:
                histories[message.topic].add(message.log_time_ns, values)
            except ValueError as error:
                raise UserError(message.topic, str(error)) from None
        return histories[base_topic], histories[ARM_TOPIC]

    def arm_commands(self) -> dict:
        """An arm controller's recorded commands: segment start stamp → the commands applied
        there, in order (`timeline.apply_arm_command`'s); none in effort mode."""
        from mobile_manip_sim.ros.messages import arm_command_values

        row, events = self.arm_controller.row, {}
        if not row.controlled:
            return events
        mode, topic = row.name, row.topic
        arm_names = self.names[ARM_U]
        for message in self.bag.messages([topic]) if topic in self.bag.topics() else ():
            decoded = decode(message, BAG_TOPIC_TYPES[topic])
            if not row.array and list(decoded.joint_names) != arm_names:
                raise UserError(topic, f"joints {list(decoded.joint_names)} at "
                                       f"{message.log_time_ns} ns, expected the scene's "
                                       f"{arm_names}")
            command = arm_command_values(mode, decoded)
            if row.array:
                self.check_command(ARM_TOPIC, command)
            events.setdefault(message.log_time_ns, []).append(command)
        return events
