"""`replay`: play a recorded bag back onto ROS topics, or re-simulate it and compare.

    replay BAG [--rate R] [--loop] [--topics T ...] [--start-offset S] [--wait-for-subscribers]
    replay BAG --resimulate [--tolerance TOL]

Playback (like ``ros2 bag play --clock``): every recorded message is published as recorded (its
serialized CDR, untouched) when the wall clock reaches its log time, counted from the first
played message and divided by ``--rate``; each topic gets the QoS the bag says its publisher
offered. ``/clock`` comes from the bag and is always played, whatever ``--topics`` selects; a
bag without it gets one ``rosgraph_msgs/Clock`` per distinct log time. ``--wait-for-subscribers``
holds playback until every played topic has a subscriber (for scripts and tests). Without it,
playback still waits (at most DISCOVERY_TIMEOUT s) until the subscribers that already run are
matched: a reliable subscriber matched late would miss the first ~0.4 s of the bag.

Re-simulation: rebuild the `Simulation` from the bag alone (attachment ``scene.yaml``, metadata
``mobile_manip_sim``: integrator settings, rates, source, base command mode and wheel-speed
gains), run the source's time line (`timeline`: its grid of segments, its start, the recorded
commands — efforts and cmd_vel — held from their recorded simulated times), and compare each
recorded /joint_states and /odom with the messages the re-run gives at that stamp (built by the
same ``messages`` functions). Prints the largest difference per quantity; status 1 if one exceeds
``--tolerance`` (default 0: bit for bit), else 0.

A missing, unreadable or non-rosbag2 bag, a bag with no complete message, an unknown topic, a
bag whose messages do not fit its own scene (another robot) → one line, status 2.
"""
from __future__ import annotations

import importlib
import math
import sys
import time

from . import __version__, cli, schema
from .errors import UserError
from .messages import (ARM_TOPIC, CLOCK_TOPIC, JOINT_STATES_TOPIC, NS, ODOM_TOPIC, clock,
                       command_values, joint_state, odometry, quaternion_yaw)
from .recording.bag_reader import open_bag
from .recording.recorder import METADATA_NAME, SCENE_ATTACHMENT
from .timeline import CommandHistory, Grid, apply_commands, start_node_time_line
from .topics import BAG_TOPIC_TYPES, BASE_COMMAND_TOPICS

ACK_TIMEOUT = 2.0          # s: how long to wait at the end for reliable subscribers to ack
# Discovery: with subscribers on the played topics known and matched, and the graph unchanged
# for DISCOVERY_SETTLE s, play; with none known yet, wait up to DISCOVERY_TIMEOUT s for one (on a
# loaded machine a running subscriber can take over a second to show up at all: a test lost the
# bag's first second so).
DISCOVERY_TIMEOUT = 3.0
DISCOVERY_SETTLE = 0.5
SLEEP_SLICE = 0.05         # s: longest sleep between checks for a shutdown
MAX_QOS_PROFILES = 100     # recorded publishers of one topic
MAX_QOS_DEPTH = 100_000    # history depth: a deeper one is damage, and would be allocated


def main(argv=None) -> int:
    return cli.run(_main, argv)


def _main(argv) -> int:
    parser = cli.ArgumentParser(prog="replay", description=__doc__.split("\n\n")[0])
    parser.add_argument("bag", type=cli.path, help="bag directory (or its .mcap file)")
    parser.add_argument("--rate", type=float, default=1.0, help="playback speed factor (> 0)")
    parser.add_argument("--loop", action="store_true", help="play again from the start, forever")
    parser.add_argument("--topics", nargs="+", metavar="T", help="play only these topics")
    parser.add_argument("--start-offset", type=float, default=0.0, metavar="S",
                        help="start S seconds (of recorded time) into the bag")
    parser.add_argument("--wait-for-subscribers", action="store_true",
                        help="start only when every played topic has a subscriber")
    parser.add_argument("--resimulate", action="store_true",
                        help="re-run the simulation from the bag and compare the states")
    parser.add_argument("--tolerance", type=float, default=0.0,
                        help="largest accepted difference with --resimulate (default 0)")
    args = parser.parse_args(argv)
    if not (math.isfinite(args.rate) and args.rate > 0):
        raise UserError("--rate", f"must be a positive number, got {args.rate}")
    if not (math.isfinite(args.start_offset) and args.start_offset >= 0):
        raise UserError("--start-offset", f"must be a number ≥ 0, got {args.start_offset}")
    if not args.tolerance >= 0:   # inf is allowed: compare, report, never fail
        raise UserError("--tolerance", f"must be ≥ 0, got {args.tolerance}")
    bag = open_bag(args.bag)
    _first_message(bag)
    if bag.recovered:
        print(f"replay: warning: {bag.path} has no summary (a recording that was killed?): "
              f"using its complete chunks; `mcap recover` may save more", file=sys.stderr)
    if args.resimulate:
        return resimulate(bag, args.tolerance)
    return play(bag, args)


# --- reading our bags ----------------------------------------------------------------------

def message_class(type_name: str):
    """The rclpy class of ``pkg/msg/Type``."""
    package, _, name = type_name.partition("/msg/")
    try:
        return getattr(importlib.import_module(f"{package}.msg"), name)
    except (ImportError, AttributeError, ValueError):
        raise UserError(type_name, "message type not installed") from None


def _first_message(bag, topics=None):
    for message in bag.messages(topics):
        return message
    raise UserError(str(bag.path), "no complete message in the bag (truncated before its first "
                                   "chunk?)")


def _decode(message):
    from rclpy.serialization import deserialize_message

    try:
        return deserialize_message(bytes(message.data), message_class(message.type_name))
    except UserError:
        raise
    except Exception as error:
        raise UserError(message.topic, f"message at {message.log_time_ns} ns does not decode as "
                                       f"{message.type_name} ({error})") from None


class RecordedRun:
    """What a bag of ours says about its run: scene, integrator, source, rates."""

    def __init__(self, bag):
        self.bag = bag
        attachments = bag.attachments()
        metadata = bag.metadata().get(METADATA_NAME)
        if SCENE_ATTACHMENT not in attachments or metadata is None:
            raise UserError(str(bag.path), "not recorded by mobile_manip_sim (no scene.yaml "
                                           "attachment or mobile_manip_sim metadata): cannot "
                                           "resimulate")
        from .scene import check_work, make_integrator, scene_from_text

        try:
            text = attachments[SCENE_ATTACHMENT].decode()
        except UnicodeDecodeError:
            raise UserError(SCENE_ATTACHMENT, "attachment is not UTF-8 text") from None
        self.scene = scene_from_text(text, f"{SCENE_ATTACHMENT} in {bag.path}")
        # The metadata is checked by the schema (keys, types, ranges) and the run's work by the
        # limits `simulate` applies: a crafted bag cannot ask for a billion sample times.
        self.metadata = metadata = schema.run_metadata(metadata, METADATA_NAME)
        self.source = metadata["source"]
        self.settings = make_integrator(self.scene.integrator, metadata["integrator_method"],
                                        metadata["dt"], metadata["rtol"], metadata["atol"],
                                        prefix=f"{METADATA_NAME}")
        self.rate = metadata[schema.RUN_METADATA_RATE[self.source]]
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
        self.names = self.scene.robot.joint_names()

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
        first = _decode(_first_message(self.bag, JOINT_STATES_TOPIC))
        self.check_joint_state(first)

    def check_joint_state(self, message) -> None:
        names = list(message.name)
        if names != self.names or len(message.position) != len(self.names) \
                or len(message.velocity) != len(self.names):
            raise UserError(JOINT_STATES_TOPIC, f"joints {names} ({len(message.position)} "
                                                f"positions) do not match the bag's scene "
                                                f"{self.scene.name!r} with joints {self.names}: "
                                                f"a bag from another robot")

    def check_command(self, topic: str, values) -> None:
        expected = len(self.names) - 2 if topic == ARM_TOPIC else 2
        if len(values) != expected:
            raise UserError(topic, f"{len(values)} values where the bag's scene "
                                   f"{self.scene.name!r} takes {expected}: a bag from another "
                                   f"robot")

    def segments(self, start: int, end: int):
        """The source's segments from stamp ``start`` to stamp ``end`` (ns): (segment start
        stamp, time in s the source advanced its engine to). One per recorded state, unless
        states are missing in between."""
        if self.source == "node":   # a node's run is as long as its bag says: bound the work
            from .scene import check_work
            check_work(end / NS, self.settings, f"{JOINT_STATES_TOPIC} stamp", f"{METADATA_NAME}.dt",
                       self.rate, f"{METADATA_NAME}.publish_rate")
        try:
            return self.grid.segments(start, end)
        except ValueError as error:
            raise UserError(JOINT_STATES_TOPIC, str(error)) from None

    def commands(self) -> tuple[CommandHistory, CommandHistory]:
        """The recorded base and arm commands (the base's: wheel torques, or v and ω)."""
        base_topic = BASE_COMMAND_TOPICS[self.base_command]
        histories = {base_topic: CommandHistory(), ARM_TOPIC: CommandHistory()}
        topics = [topic for topic in histories if topic in self.bag.topics()]
        for message in self.bag.messages(topics) if topics else ():
            values = command_values(message.topic, _decode(message))
            self.check_command(message.topic, values)
            try:
                histories[message.topic].add(message.log_time_ns, values)
            except ValueError as error:
                raise UserError(message.topic, str(error)) from None
        return histories[base_topic], histories[ARM_TOPIC]

    def start(self):
        """The `Simulation` at the source's t = 0."""
        from .engine.simulation import Simulation

        sim = Simulation(self.scene, self.settings)
        if self.gains is not None:
            sim.set_wheel_speed_gains(*self.gains)
        if self.source == "node":
            start_node_time_line(sim)
        return sim


# --- re-simulation -------------------------------------------------------------------------

class Differences:
    """Largest |recorded − re-simulated| per quantity, and where it first exceeded tolerance."""

    def __init__(self, tolerance: float):
        self.tolerance = tolerance
        self.largest: dict[str, tuple[float, int]] = {}
        self.first_failure: tuple[int, str, float, float] | None = None

    def add(self, quantity: str, stamp: int, recorded: float, resimulated: float,
            angle: bool = False) -> None:
        if recorded == resimulated or (math.isnan(recorded) and math.isnan(resimulated)):
            difference = 0.0
        else:
            difference = abs(recorded - resimulated)
            if angle:
                difference = abs(math.remainder(recorded - resimulated, math.tau))
            if math.isnan(difference):
                difference = math.inf
        best = self.largest.get(quantity)
        if best is None or difference > best[0]:
            self.largest[quantity] = (difference, stamp)
        if difference > self.tolerance and self.first_failure is None:
            self.first_failure = (stamp, quantity, recorded, resimulated)

    def failed(self) -> list[str]:
        return [name for name, (difference, _) in self.largest.items()
                if difference > self.tolerance]


def resimulate(bag, tolerance: float) -> int:
    from .engine.simulation import SimulationError

    run = RecordedRun(bag)
    run.check_robot()
    base_commands, arm_commands = run.commands()
    if run.metadata.get("version") != __version__:
        print(f"note: recorded by mobile_manip_sim {run.metadata.get('version')}, re-simulated "
              f"by {__version__}: bit-for-bit agreement is only expected from the same build")

    sim = run.start()
    differences = Differences(tolerance)
    compared = {JOINT_STATES_TOPIC: 0, ODOM_TOPIC: 0}
    sim_stamp = None
    first_stamp = None
    try:
        for message in bag.messages([JOINT_STATES_TOPIC, ODOM_TOPIC]):
            recorded = _decode(message)
            stamp = recorded.header.stamp.sec * NS + recorded.header.stamp.nanosec
            if sim_stamp is None:
                if stamp != 0:
                    raise UserError(message.topic, f"the first state is at {stamp} ns, not at "
                                                   f"t = 0: cannot resimulate")
                sim_stamp = first_stamp = 0
            elif stamp < sim_stamp:
                raise UserError(message.topic, f"time goes back from {sim_stamp} to {stamp} ns")
            elif stamp > sim_stamp:
                for start, t_end in run.segments(sim_stamp, stamp):
                    apply_commands(sim, base_commands.at(start), arm_commands.at(start),
                                   run.velocity)
                    sim.advance_to(t_end)
                sim_stamp = stamp
            _compare(run, sim, stamp, message.topic, recorded, differences)
            compared[message.topic] += 1
    except SimulationError as error:
        print(f"replay: the re-simulation failed: {error}")
        return 1
    _report(run, bag, differences, compared, first_stamp, sim_stamp)
    return 1 if differences.failed() else 0


def _compare(run, sim, stamp: int, topic: str, recorded, differences: Differences) -> None:
    if topic == JOINT_STATES_TOPIC:
        run.check_joint_state(recorded)
        expected = joint_state(sim, stamp, run.names)
        for name, a, b in zip(run.names, recorded.position, expected.position):
            differences.add(f"{name} position", stamp, a, b)
        for name, a, b in zip(run.names, recorded.velocity, expected.velocity):
            differences.add(f"{name} velocity", stamp, a, b)
        if len(recorded.effort) != len(expected.effort):
            raise UserError(topic, f"{len(recorded.effort)} efforts at {stamp} ns, expected "
                                   f"{len(expected.effort)}")
        for name, a, b in zip(run.names, recorded.effort, expected.effort):
            differences.add(f"{name} effort", stamp, a, b)
    else:
        expected = odometry(sim, stamp)
        pose, twist = recorded.pose.pose, recorded.twist.twist
        differences.add("x", stamp, pose.position.x, expected.pose.pose.position.x)
        differences.add("y", stamp, pose.position.y, expected.pose.pose.position.y)
        differences.add("yaw", stamp, quaternion_yaw(pose.orientation),
                        quaternion_yaw(expected.pose.pose.orientation), angle=True)
        differences.add("v", stamp, twist.linear.x, expected.twist.twist.linear.x)
        differences.add("omega", stamp, twist.angular.z, expected.twist.twist.angular.z)


def _report(run, bag, differences: Differences, compared: dict, first: int, last: int) -> None:
    settings = run.settings
    detail = f"dt {settings.dt:g}" if settings.fixed_step else \
        f"rtol {settings.rtol:g}, atol {settings.atol:g}"
    print(f"re-simulated {bag.path} ({run.source} run of scene '{run.scene.name}', "
          f"{settings.method}, {detail}): {compared[JOINT_STATES_TOPIC]} /joint_states and "
          f"{compared[ODOM_TOPIC]} /odom messages from t = {first / NS:.9f} to "
          f"{last / NS:.9f} s")
    order = ["x", "y", "yaw", *(f"{name} position" for name in run.names),
             *(f"{name} velocity" for name in run.names), "v", "omega",
             *(f"{name} effort" for name in run.names)]
    rows = [(name, differences.largest[name]) for name in order if name in differences.largest]
    width = max(len(name) for name, _ in rows) + 2
    print(f"{'quantity':<{width}}largest |recorded - resimulated|   at t (s)")
    for name, (difference, stamp) in rows:
        where = f"{stamp / NS:.9f}" if difference > 0 else "-"
        mark = "   > tolerance" if difference > differences.tolerance else ""
        print(f"{name:<{width}}{difference:<34.6g}{where}{mark}")
    failed = differences.failed()
    if failed:
        stamp, quantity, recorded, resimulated = differences.first_failure
        print(f"DIFFERENT: {len(failed)} quantities exceed the tolerance {differences.tolerance:g}"
              f" ({', '.join(failed)}); first at t = {stamp / NS:.9f} s: {quantity} recorded "
              f"{recorded!r}, re-simulated {resimulated!r}")
    elif differences.tolerance == 0:
        print("IDENTICAL: the run is reproduced bit for bit")
    else:
        print(f"OK: every difference is within the tolerance {differences.tolerance:g}")


# --- playback ------------------------------------------------------------------------------

def qos_profile(offered: str | None, topic: str = "topic"):
    """A subscriber-compatible QoS for a topic from its ``offered_qos_profiles`` YAML: reliable
    only if every recorded publisher was, transient local likewise, the deepest history. None
    recorded: reliable, depth 10. A damaged entry is one `UserError` naming the topic."""
    from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)

    where = f"{topic}: offered_qos_profiles"
    profiles = schema.load_yaml(offered, what=where) if offered else None
    if not profiles:
        return QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    profiles = schema.sequence(profiles, where, max_length=MAX_QOS_PROFILES)
    for i, profile in enumerate(profiles):
        schema.mapping(profile, f"{where}[{i}]")
        if profile.get("depth") is not None:
            schema.integer(profile["depth"], f"{where}[{i}].depth", lo=0, hi=MAX_QOS_DEPTH)

    def policy(profile, key, names):
        value = profile.get(key)
        return names.get(value, value) if isinstance(value, int) else str(value).lower()

    reliable = all(policy(p, "reliability", {1: "reliable", 2: "best_effort"}) == "reliable"
                   for p in profiles)
    latched = all(policy(p, "durability", {1: "transient_local", 2: "volatile"})
                  == "transient_local" for p in profiles)
    keep_all = any(policy(p, "history", {1: "keep_last", 2: "keep_all"}) == "keep_all"
                   for p in profiles)
    depth = max((int(p.get("depth") or 0) for p in profiles), default=0) or 10
    return QoSProfile(
        history=HistoryPolicy.KEEP_ALL if keep_all else HistoryPolicy.KEEP_LAST, depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def play(bag, args) -> int:
    topics = bag.topics()
    if args.topics:
        for topic in args.topics:
            if topic not in topics:
                raise UserError(topic, f"not in bag {bag.path}; its topics: "
                                       f"{', '.join(sorted(topics))}")
        selected = list(dict.fromkeys(args.topics))
        if CLOCK_TOPIC in topics and CLOCK_TOPIC not in selected:
            selected.append(CLOCK_TOPIC)
    else:
        selected = list(topics)
    classes = {topic: message_class(topics[topic]) for topic in selected}
    first = _first_message(bag, selected).log_time_ns
    start = first + round(args.start_offset * NS)
    if _first_at(bag, selected, start) is None:
        raise UserError("--start-offset", f"{args.start_offset:g} s is past the end of the bag")
    if SCENE_ATTACHMENT in bag.attachments() and JOINT_STATES_TOPIC in topics:
        run = RecordedRun(bag)   # our bag: it must fit its own robot
        run.check_joint_state(_decode(_first_message(bag, JOINT_STATES_TOPIC)))

    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock

    rclpy.init()
    node = rclpy.create_node("mobile_manip_sim_replay")
    try:
        metadata = bag.channel_metadata()
        publishers = {topic: node.create_publisher(
            classes[topic], topic, qos_profile(metadata.get(topic, {}).get("offered_qos_profiles"), topic))
            for topic in selected}
        clock_publisher = None
        if CLOCK_TOPIC not in topics:
            clock_publisher = node.create_publisher(
                Clock, CLOCK_TOPIC, QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        waiting = dict(publishers)
        if clock_publisher is not None:
            waiting[CLOCK_TOPIC] = clock_publisher
        if args.wait_for_subscribers:
            while rclpy.ok() and not all(p.get_subscription_count() for p in waiting.values()):
                time.sleep(SLEEP_SLICE)
        else:
            _await_discovery(node, waiting)
        played = 0
        wall_start = time.monotonic()
        while rclpy.ok():
            played += _play_once(bag, selected, start, args.rate, publishers, clock_publisher)
            if not args.loop:
                break
        for publisher in publishers.values():
            _wait_acked(publisher)
        wall = time.monotonic() - wall_start
        print(f"played {played} messages on {len(selected)} topics in {wall:.3f} s "
              f"(rate {args.rate:g})")
    except KeyboardInterrupt:
        pass
    except Exception:
        if rclpy.ok():
            raise   # a failure of ours, not a shutdown by SIGINT/SIGTERM
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _await_discovery(node, publishers: dict) -> None:
    """Give discovery the time to match the subscribers that already run: until some
    subscriber is known on a played topic, every one known is matched and the graph (nodes,
    subscribers, matches) has not changed for DISCOVERY_SETTLE s; at most DISCOVERY_TIMEOUT s."""
    import rclpy

    start = time.monotonic()
    last, since = None, start
    while rclpy.ok():
        now = time.monotonic()
        if now - start >= DISCOVERY_TIMEOUT:
            return
        known = [node.count_subscribers(topic) for topic in publishers]
        matched = [publisher.get_subscription_count() for publisher in publishers.values()]
        graph = (known, matched, sorted(node.get_node_names_and_namespaces()))
        if graph != last:
            last, since = graph, now
        elif (now - since >= DISCOVERY_SETTLE and any(known)
              and all(m >= k for m, k in zip(matched, known))):
            return
        time.sleep(0.02)


def _first_at(bag, topics, start: int):
    for message in bag.messages(topics):
        if message.log_time_ns >= start:
            return message
    return None


def _play_once(bag, topics, start: int, rate: float, publishers, clock_publisher) -> int:
    """Publish the messages from log time ``start`` on, paced by the wall clock."""
    import rclpy

    wall_start = time.monotonic()
    played = 0
    last_clock = None
    for message in bag.messages(topics):
        if message.log_time_ns < start:
            continue
        due = wall_start + (message.log_time_ns - start) / NS / rate
        while True:
            if not rclpy.ok():
                return played
            remaining = due - time.monotonic()
            if remaining <= 0:
                break
            time.sleep(min(remaining, SLEEP_SLICE))
        if clock_publisher is not None and message.log_time_ns != last_clock:
            clock_publisher.publish(clock(message.log_time_ns))
            last_clock = message.log_time_ns
        publishers[message.topic].publish(bytes(message.data))
        played += 1
    return played


def _wait_acked(publisher) -> None:
    from rclpy.duration import Duration

    try:
        publisher.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT))
    except Exception:   # best effort publishers, or a context going down: nothing to wait for
        pass


if __name__ == "__main__":
    raise SystemExit(main())
