"""Playback (like ``ros2 bag play --clock``): every recorded message is published as recorded (its
serialized CDR, untouched) when the wall clock reaches its log time, counted from the first
played message and divided by the rate; each topic gets the QoS the bag says its publisher
offered. The latched topics (/robot_description, /tf_static: transient local) go first, at
once: their last message at or before the start. A topic whose message type is not installed
(tf2_msgs on a pip install), whose type is not one of the known message packages
(`message_types`: a bag's type name never chooses what is imported) or whose name is not a
valid ROS topic name is left out with a warning (named with ``--topics``: a one-line error).
``/clock`` comes from the bag and is always played, whatever the topics selected; a bag without
it gets one ``rosgraph_msgs/Clock`` per distinct log time. With ``wait_for_subscribers``
playback is held until some played topic has a subscriber and every subscriber discovery knows
of is matched, the graph unchanged for DISCOVERY_SETTLE s (for scripts and tests; a subscriber
of only some topics is enough). Without it, playback still waits so (at most DISCOVERY_TIMEOUT
s): a reliable subscriber matched late would miss the first ~0.4 s of the bag. Pacing starts at
the first message played, after the scan to ``--start-offset``: message m is due
(t_m − start) / rate after it, however long the scan took. The time it prints ("played N
messages … in S s") is the playing's alone, without these waits or the final wait for
acknowledgements.
"""
from __future__ import annotations

import re
import sys
import time

from mobile_manip_sim.recording.bag_format import (
    SCENE_ATTACHMENT,
    RecordedRun,
    decode,
    first_message,
    message_class,
)
from mobile_manip_sim.ros.messages import CLOCK_TOPIC, JOINT_STATES_TOPIC, NS, clock
from mobile_manip_sim.ros.topics import LATCHED_TOPICS, TF_TYPE
from mobile_manip_sim.scene import limits, schema
from mobile_manip_sim.scene.errors import UserError

ACK_TIMEOUT = 2.0          # s: how long to wait at the end for reliable subscribers to ack
# Discovery: with subscribers on the played topics known and matched, and the graph unchanged
# for DISCOVERY_SETTLE s, play; with none known yet, wait up to DISCOVERY_TIMEOUT s for one (on a
# loaded machine a running subscriber can take over a second to show up at all: a test lost the
# bag's first second so).
DISCOVERY_TIMEOUT = 3.0
DISCOVERY_SETTLE = 0.5
SLEEP_SLICE = 0.05         # s: longest sleep between checks for a shutdown
MAX_QOS_PROFILES = 100     # recorded publishers of one topic
MAX_QOS_DEPTH = limits.QOS_DEPTH[1]   # history depth: deeper is damage (and would be allocated)
# An absolute ROS 2 topic name as a bag records it: /token(/token)*, tokens of letters, digits
# and _, none starting with a digit (rcl's rules; anything else fails create_publisher).
TOPIC_NAME = re.compile(r"(/[A-Za-z_][A-Za-z0-9_]*)+")



def qos_profile(offered: str | None, topic: str = "topic"):
    """A subscriber-compatible QoS for a topic from its ``offered_qos_profiles`` YAML: reliable
    only if every recorded publisher was, transient local likewise, the deepest history. None
    recorded: reliable, depth 10. A damaged entry is one `UserError` naming the topic."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

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


def play(bag, topics=None, rate: float = 1.0, loop: bool = False, start_offset: float = 0.0,
         wait_for_subscribers: bool = False) -> int:
    """Play ``topics`` of the bag (all if None) from ``start_offset`` s of recorded time on, at
    ``rate`` times the recorded pace, once or (``loop``) until shut down."""
    chosen, topics = topics, bag.topics()
    if chosen:
        for topic in chosen:
            if topic not in topics:
                raise UserError(schema.label(topic, 80), f"not in bag {bag.path}; its topics: "
                                f"{', '.join(schema.label(t, 80) for t in sorted(topics))}")
            problem = _problem(topic, topics[topic])
            if problem is not None:
                raise UserError(schema.label(topic, 80), problem)
        selected = list(dict.fromkeys(chosen))
        if CLOCK_TOPIC in topics and CLOCK_TOPIC not in selected:
            selected.append(CLOCK_TOPIC)
    else:
        selected = _installed(topics)
    classes = {topic: message_class(topics[topic]) for topic in selected}
    first = first_message(bag, selected).log_time_ns
    start = first + round(start_offset * NS)
    if _first_at(bag, selected, start) is None:
        raise UserError("--start-offset", f"{start_offset:g} s is past the end of the bag")
    if SCENE_ATTACHMENT in bag.attachments() and JOINT_STATES_TOPIC in topics:
        run = RecordedRun(bag)   # our bag: it must fit its own robot
        run.check_joint_state(decode(first_message(bag, JOINT_STATES_TOPIC)))

    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock

    rclpy.init()
    node = rclpy.create_node("mobile_manip_sim_replay")
    try:
        metadata = bag.channel_metadata()
        publishers = {topic: node.create_publisher(
            classes[topic], topic,
            qos_profile(metadata.get(topic, {}).get("offered_qos_profiles"), topic))
            for topic in selected}
        clock_publisher = None
        if CLOCK_TOPIC not in topics:
            clock_publisher = node.create_publisher(
                Clock, CLOCK_TOPIC, QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        # Latched topics keep their message for subscribers that come later: no need to wait.
        waiting = {topic: publisher for topic, publisher in publishers.items()
                   if topic not in LATCHED_TOPICS}
        if clock_publisher is not None:
            waiting[CLOCK_TOPIC] = clock_publisher
        _await_discovery(node, waiting, None if wait_for_subscribers else DISCOVERY_TIMEOUT)
        played = 0
        wall_start = time.monotonic()
        while rclpy.ok():
            played += _play_latched(bag, selected, start, publishers)
            played += _play_once(bag, selected, start, rate, publishers, clock_publisher)
            if not loop:
                break
        wall = time.monotonic() - wall_start   # the playing alone: not the waits before and after
        for publisher in publishers.values():
            _wait_acked(publisher)
        print(f"played {played} messages on {len(selected)} topics in {wall:.3f} s "
              f"(rate {rate:g})")
    except KeyboardInterrupt:
        pass
    except Exception:
        if rclpy.ok():
            raise   # a failure of ours, not a shutdown by SIGINT/SIGTERM
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _await_discovery(node, publishers: dict, timeout: float | None) -> None:
    """Give discovery the time to match the subscribers that already run: until some
    subscriber is known on a played topic, every one known is matched and the graph (nodes,
    subscribers, matches) has not changed for DISCOVERY_SETTLE s; at most ``timeout`` s (None:
    until then, however long)."""
    import rclpy

    start = time.monotonic()
    last, since = None, start
    while rclpy.ok():
        now = time.monotonic()
        if timeout is not None and now - start >= timeout:
            return
        known = [node.count_subscribers(topic) for topic in publishers]
        matched = [publisher.get_subscription_count() for publisher in publishers.values()]
        graph = (known, matched, sorted(node.get_node_names_and_namespaces()))
        if graph != last:
            last, since = graph, now
        elif (now - since >= DISCOVERY_SETTLE and any(known)
              and all(m >= k for m, k in zip(matched, known, strict=True))):
            return
        time.sleep(0.02)


def _problem(topic: str, type_name: str) -> str | None:
    """Why ``topic`` of type ``type_name`` cannot be played, or None."""
    if not isinstance(topic, str) or not TOPIC_NAME.fullmatch(topic):
        return "not a valid ROS 2 topic name"
    try:
        message_class(type_name)
    except UserError as error:
        hint = " (tools/bootstrap.sh builds it into .venv, or source a ROS install)" \
            if type_name == TF_TYPE else ""
        return f"{error.key}: {error.problem}{hint}"
    return None


def _installed(topics: dict) -> list[str]:
    """The bag's topics that can be played here; the others are left out with one warning
    each (tf2_msgs, which PyPI has no wheel of, is the usual one)."""
    played, missing = [], {}
    for topic, type_name in topics.items():
        problem = _problem(topic, type_name)
        if problem is None:
            played.append(topic)
        else:
            missing.setdefault(problem, []).append(schema.label(topic, 80))
    for problem, left_out in missing.items():
        print(f"replay: warning: {', '.join(left_out)} not played: {problem}", file=sys.stderr)
    return played


def _play_latched(bag, topics, start: int, publishers) -> int:
    """The latched topics (transient local) first: for each, its last message at or before
    ``start``, published at once, so a subscriber of any time gets the robot description and
    the fixed frames before the first state."""
    latest = {}
    for message in bag.messages([t for t in topics if t in LATCHED_TOPICS]):
        if message.log_time_ns > start:
            break
        latest[message.topic] = message
    for message in latest.values():
        publishers[message.topic].publish(bytes(message.data))
    return len(latest)


def _first_at(bag, topics, start: int):
    for message in bag.messages(topics):
        if message.log_time_ns >= start:
            return message
    return None


def _play_once(bag, topics, start: int, rate: float, publishers, clock_publisher,
               wall=time.monotonic, sleep=time.sleep, ok=None) -> int:
    """Publish the messages from log time ``start`` on, paced by the wall clock ``wall`` from
    the instant the first of them is reached (the scan to ``start`` is not playing time)."""
    if ok is None:
        import rclpy
        ok = rclpy.ok

    wall_start = None
    played = 0
    last_clock = None
    for message in bag.messages(topics):
        if message.log_time_ns < start or (message.log_time_ns == start
                                           and message.topic in LATCHED_TOPICS):
            continue   # before the start, or played already (`_play_latched`)
        if wall_start is None:
            wall_start = wall()
        due = wall_start + (message.log_time_ns - start) / NS / rate
        while True:
            if not ok():
                return played
            remaining = due - wall()
            if remaining <= 0:
                break
            sleep(min(remaining, SLEEP_SLICE))
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
