"""`RunRecorder`: one simulated run (one time line) → one self-describing rosbag2 bag.

Topics (types and offered QoS as the node publishes them, see ``topics.py``):
/joint_states, /odom, /clock, /tf (reliable, volatile, keep_last 100), /tf_static and
/robot_description (reliable, transient local, keep_last 1: written at t = 0, before the first
state, and again on a reset) and the run's command topics
(reliable, volatile, keep_last 10): the arm's efforts and the base's command, wheel torques or,
with base_command velocity, /cmd_vel (a Twist: v, ω). Every record's log_time and publish_time
is the simulated time it belongs to: a state's stamp; a command's segment start, the simulated
time from which the engine held it. Commands are written as applied (after the command timeout
and the effort limits), at t = 0 and then only when they change, so the bag determines the
whole command sequence (zero-order hold between records, `timeline.CommandHistory`).

Self-describing (``bag_format``): attachment ``scene.yaml``, written first; MCAP metadata
``mobile_manip_sim`` (`bag_format.run_metadata`); attachment ``impacts.json`` (the end-stop
impacts up to the last recorded state), written at close.

Payloads are the exact CDR of rclpy's serialisation (``cdr.exact_cdr``): equal runs give equal
bags, byte for byte. Errors are ``UserError`` from the ``BagWriter``; after one the recorder is
unusable and ``abandon()`` releases the file.
"""
from __future__ import annotations

import contextlib
import json
import time

import numpy as np

from mobile_manip_sim.recording.bag_format import (
    IMPACTS_ATTACHMENT,
    LEDGER_NAME,
    METADATA_NAME,
    SCENE_ATTACHMENT,
    energy_ledger,
    run_metadata,
)
from mobile_manip_sim.recording.bag_writer import DEFAULT_CHUNK_SIZE, BagWriter, qos_yaml
from mobile_manip_sim.ros.cdr import exact_cdr
from mobile_manip_sim.ros.messages import command_message
from mobile_manip_sim.ros.topics import (
    ARM_TOPIC,
    BASE_COMMAND_TOPICS,
    COMMAND_QOS_DEPTH,
    COMMAND_TOPICS,
    IMU_TOPIC,
    LATCHED_TOPICS,
    STATE_QOS_DEPTH,
    STATE_TOPICS,
    TF_TOPIC,
    recorded_topics,
)
from mobile_manip_sim.scene.arm_controller import EFFORT, MODES
from mobile_manip_sim.scene.errors import UserError

# The order in which one publication's messages are written (the latched ones come first).
WRITTEN_TOPICS = (*LATCHED_TOPICS, *STATE_TOPICS, TF_TOPIC, IMU_TOPIC)


def topic_qos(topic: str) -> str:
    """The offered QoS YAML of one of our topics (the latched ones: transient local, depth 1)."""
    if topic in LATCHED_TOPICS:
        return qos_yaml("reliable", "transient_local", 1)
    return qos_yaml("reliable", "volatile",
                    COMMAND_QOS_DEPTH if topic in COMMAND_TOPICS else STATE_QOS_DEPTH)


class RunRecorder:
    """Records one run into a new bag directory ``path`` (see the module docstring).

    ``extra_metadata`` adds to the metadata map: ``source`` (node|simulate) and the rate
    (``publish_rate`` or ``sample_rate``) at least; a node run also its ``base_command``
    (effort|velocity, default effort), which chooses the base's command topic.
    ``flush_interval`` (wall seconds, None = off) closes the open chunk that often, bounding what a
    SIGKILL loses in a slow run; headless runs leave it off so that their chunks, and hence their
    bags, do not depend on the wall clock.
    ``view`` adds the view topics (/tf, /tf_static, /robot_description) to the bag, ``imu``
    /imu (its noise settings: in ``extra_metadata``, `imu.ImuNoise.as_metadata`).
    """

    def __init__(self, path, scene, settings, extra_metadata: dict, *,
                 chunk_size: int = DEFAULT_CHUNK_SIZE, flush_interval: float | None = None,
                 view: bool = False, imu: bool = False):
        metadata = run_metadata(scene, settings, extra_metadata)
        base_command = metadata.get("base_command", "effort")
        if base_command not in BASE_COMMAND_TOPICS:
            raise UserError("base_command", f"{base_command!r} is not effort or velocity")
        self._base_topic = BASE_COMMAND_TOPICS[base_command]
        arm_controller = metadata.get("arm_controller", EFFORT)
        self._arm_topic = MODES[arm_controller].topic
        self.writer = BagWriter(path, chunk_size=chunk_size)
        self.path = self.writer.path
        try:
            for topic, type_name in recorded_topics(base_command, view, imu,
                                                    arm_controller).items():
                self.writer.add_topic(topic, type_name, topic_qos(topic))
            self.writer.add_attachment(SCENE_ATTACHMENT, "application/yaml",
                                       scene.to_yaml().encode())
            self.writer.add_metadata(METADATA_NAME, metadata)
        except BaseException:
            self.abandon()
            raise
        self._last_commands: dict[str, bytes] = {}
        self._impacts: list[dict] = []
        self._last_stamp = 0
        self._flush_interval = flush_interval
        self._flushed_at = time.monotonic()

    def states(self, stamp: int, messages: dict) -> None:
        """Write the messages published at ``stamp`` ns (topic → rclpy message, or its CDR
        bytes): states, /tf, and the latched ones when they are (re)published."""
        for topic in WRITTEN_TOPICS:
            message = messages.get(topic)
            if message is not None:
                data = message if isinstance(message, bytes) else exact_cdr(message)
                self.writer.write(topic, data, stamp, stamp)
        self._last_stamp = max(self._last_stamp, stamp)
        self._maybe_flush()

    def commands(self, stamp: int, base, joints) -> None:
        """The commands held from ``stamp`` ns on: ``base`` the wheel torques (or, in velocity
        mode, v and ω; None = none given), ``joints`` the arm efforts. Each is written when it
        differs (bit for bit) from the last one written, and always the first time."""
        for topic, values in ((self._base_topic, base), (ARM_TOPIC, joints)):
            if values is None:
                continue
            values = np.asarray(values, dtype=float)
            key = values.tobytes()
            if self._last_commands.get(topic) != key:
                self.writer.write(topic, exact_cdr(command_message(topic, values)), stamp, stamp)
                self._last_commands[topic] = key
        self._last_stamp = max(self._last_stamp, stamp)

    def arm_command(self, stamp: int, message) -> None:
        """An arm controller's command (its mode's topic: an array or a JointTrajectory) applied
        from ``stamp`` ns on. Each is written: each applies anew (a velocity ramp restarts, a
        trajectory starts)."""
        self.writer.write(self._arm_topic, exact_cdr(message), stamp, stamp)
        self._last_stamp = max(self._last_stamp, stamp)

    def impacts(self, impacts) -> None:
        """The engine's impact list so far (``Impact`` objects); only new ones are taken, so
        call it whenever a state is recorded."""
        self._impacts.extend({key: _plain(value) for key, value in impact.as_dict().items()}
                             for impact in impacts[len(self._impacts):])

    @property
    def recorded_impacts(self) -> list[dict]:
        return list(self._impacts)

    def close(self) -> None:
        """Attach ``impacts.json`` and the energy ledger, then finish the bag (summary,
        metadata.yaml). Idempotent."""
        if self.writer is None:
            return
        writer, self.writer = self.writer, None
        try:
            writer.add_attachment(IMPACTS_ATTACHMENT, "application/json",
                                  json.dumps(self._impacts, indent=1).encode(), self._last_stamp)
            writer.add_metadata(LEDGER_NAME, energy_ledger(self._impacts))
        except BaseException:
            with contextlib.suppress(Exception):
                writer.close()
            raise
        writer.close()

    def abandon(self) -> None:
        """After an error: finish the bag if the writer still can, else just release the file.
        Never raises (the error that led here has been reported)."""
        writer, self.writer = self.writer, None
        if writer is not None:
            with contextlib.suppress(Exception):
                writer.close()

    def _maybe_flush(self) -> None:
        self.flush_if_due()

    def flush_if_due(self) -> None:
        """Close the open chunk when ``flush_interval`` has passed since the last time: after
        each state, and from a timer while none come (a paused or failed node)."""
        if self._flush_interval is None or self.writer is None:
            return
        now = time.monotonic()
        if now - self._flushed_at >= self._flush_interval:
            self._flushed_at = now
            if self.writer.buffered_bytes:
                self.writer.flush()


def _plain(value):
    """A JSON-ready Python scalar (the engine may hand numpy ones)."""
    return value.item() if isinstance(value, np.generic) else value
