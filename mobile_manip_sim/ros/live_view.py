"""The live view: a Foxglove WebSocket server (PyPI ``foxglove-sdk``) carrying the simulator's
topics as foxglove_bridge advertises ROS 2 topics — each channel with its ROS 2 schema (schema
encoding ``ros2msg``: the full message definition, as bags store it) and ``cdr`` payloads (as
rclpy serialises them for DDS, or /tf's exact bytes) — so Foxglove's 3D, plot and raw-message
panels work unchanged, with no ROS install and no bridge. A channel nobody subscribed to costs
no serialisation.

Channels (topics.LIVE_TOPIC_TYPES): /tf, /tf_static, /robot_description, /joint_states, /odom,
/imu, /energy. /tf_static and /robot_description are latched: the view keeps their last message
and sends it again when a client subscribes, so a client that connects late still draws the
robot. The SDK can only send to every subscriber at once, so the re-sends of a topic are
coalesced: at most one per LATCHED_INTERVAL, however often clients subscribe. Message times
(log time, and the server time the view broadcasts) are the simulated stamps, the clock the
messages' headers use.

    view = LiveView(8765)                 # 0: any free port (see view.port)
    view.publish(stamp_ns, {"/tf": cdr_bytes, "/joint_states": rclpy_message, ...})
    view.close()

The host is loopback (127.0.0.1) unless given: 0.0.0.0 serves every interface (a laptop on the
network). The SDK speaks the subprotocol ``foxglove.sdk.v1`` only: the Foxglove app and
clients that offer it connect; clients that offer only ``foxglove.websocket.v1`` (older
Lichtblick, older @foxglove/ws-protocol) are refused at the handshake.

`close` never waits on a client: the SDK's stop waits until every connection has drained, which
a client that stopped reading (a sleeping laptop, a half-open connection) never does, so it runs
in a thread of its own and `close` returns after at most CLOSE_WAIT seconds (the thread, and the
connection, end with the process).

`HeadlessSource` composes one sample's messages for `simulate --view`.
"""
from __future__ import annotations

import socket
import threading
import time

from rclpy.serialization import serialize_message  # rclpy's C serialiser, as DDS's

from ..runtime.pacing import Pacer
from ..runtime.timeline import Grid
from ..scene import limits
from ..scene.errors import UserError
from .frames import BASE_LINK, ODOM, FrameTree
from .imu import Imu
from .message_definitions import definition_text
from .messages import description, energy, imu, state_messages, tf_cdr, tf_static_cdr
from .topics import (
    CLOCK_TOPIC,
    DESCRIPTION_TOPIC,
    ENERGY_TOPIC,
    IMU_TOPIC,
    LATCHED_TOPICS,
    LIVE_TOPIC_TYPES,
    TF_STATIC_TOPIC,
    TF_TOPIC,
)
from .urdf import robot_description

DEFAULT_PORT = 8765
DEFAULT_HOST = "127.0.0.1"   # loopback; "0.0.0.0" serves every interface
SERVER_NAME = "mobile_manip_sim"
CLOSE_WAIT = 1.0             # s: the longest `close` waits for the server to stop
LATCHED_INTERVAL = 1.0       # s: at most one re-send of a latched topic this often
TICK = 0.05                  # s: the sending thread looks this often when not batching


class LiveView:
    """A Foxglove WebSocket server on ``host:port`` with one channel per live topic. With
    ``batch`` (s of wall time) publications are queued and sent by a thread of the view at most
    that often: what the server costs most is waking its sending per burst, not per message
    (bench/NODE.md), and each message keeps its own stamp."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = DEFAULT_HOST,
                 name: str = SERVER_NAME, batch: float = 0.0):
        try:
            import foxglove
            from foxglove.websocket import Capability
        except ImportError:
            raise UserError("live view", "the Python package foxglove-sdk is not installed "
                                         "(pip install foxglove-sdk)") from None
        check_port(port, "port")
        host = check_host(host, "host")
        self.host = host
        self._lock = threading.Lock()
        self._latched: dict[str, tuple[int, bytes]] = {}
        self._due: set[str] = set()            # latched topics a new subscriber waits for
        self._resent: dict[str, float] = {}    # topic → monotonic time of its last re-send
        self._context = foxglove.Context()
        self.channels = {
            topic: foxglove.Channel(
                topic, message_encoding="cdr", context=self._context,
                schema=foxglove.Schema(name=type_name, encoding="ros2msg",
                                       data=definition_text(type_name).encode()))
            for topic, type_name in LIVE_TOPIC_TYPES.items()}
        self._by_id = {channel.id(): topic for topic, channel in self.channels.items()}
        try:
            self.server = foxglove.start_server(
                name=name, host=host, port=port, context=self._context,
                server_listener=_Listener(self._on_subscribe),
                capabilities=[Capability.Time], supported_encodings=["cdr"])
        except Exception as error:   # the SDK's own error type: port in use, bad host
            raise UserError(f"port {port}", f"cannot start the Foxglove server on {host} "
                                            f"({error})") from None
        self.port = self.server.port
        self._batch, self._pending = batch, []   # (stamp, messages) not sent yet
        self._stopping = threading.Event()
        self._sender = threading.Thread(target=self._send_batches, name="live view",
                                        daemon=True)
        self._sender.start()

    @property
    def url(self) -> str:
        host = "localhost" if self.host in ("127.0.0.1", "::1", "localhost") else (
            socket.gethostname() if self.host in ("0.0.0.0", "::") else self.host)
        return f"ws://{host}:{self.port}"

    def publish(self, stamp: int, messages: dict) -> None:
        """Send the messages of one publication (topic → rclpy message, or its CDR bytes),
        stamped ``stamp`` ns of simulated time; topics without a channel are left out."""
        if self._batch <= 0:
            self._send(stamp, messages)
            return
        with self._lock:
            self._pending.append((stamp, messages))

    def _send_batches(self) -> None:
        while not self._stopping.wait(self._batch if self._batch > 0 else TICK):
            self._flush()
            self._resend_latched()

    def _resend_latched(self) -> None:
        """Send each latched topic a client subscribed to since, at most once per
        LATCHED_INTERVAL (the SDK sends it to every subscriber of the topic)."""
        now = time.monotonic()
        with self._lock:
            due = [topic for topic in self._due
                   if now - self._resent.get(topic, -LATCHED_INTERVAL) >= LATCHED_INTERVAL]
            for topic in due:
                self._due.discard(topic)
                self._resent[topic] = now
            messages = [(topic, self._latched.get(topic)) for topic in due]
        for topic, latched in messages:
            if latched is not None:
                self.channels[topic].log(latched[1], log_time=latched[0])

    def _flush(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, []
        for stamp, messages in pending:
            self._send(stamp, messages)

    def _send(self, stamp: int, messages: dict) -> None:
        self.server.broadcast_time(stamp)
        for topic, message in messages.items():
            channel = self.channels.get(topic)
            latched = topic in LATCHED_TOPICS
            if channel is None or not (latched or channel.has_sinks()):
                continue   # nobody subscribed: not even serialised
            data = message if isinstance(message, bytes) else serialize_message(message)
            if latched:
                with self._lock:
                    self._latched[topic] = (stamp, data)
            channel.log(data, log_time=stamp)

    def wants(self, topic: str) -> bool:
        """A client is subscribed to ``topic`` (a message only it would get can be left
        uncomputed)."""
        channel = self.channels.get(topic)
        return channel is not None and channel.has_sinks()

    def _on_subscribe(self, channel) -> None:
        """A new subscriber of a latched topic gets its last message from the sending thread,
        within TICK (or the batch) when none was re-sent in the last LATCHED_INTERVAL, else at
        the interval's end (on the server's thread: only noted)."""
        topic = self._by_id.get(channel.id)
        if topic in LATCHED_TOPICS:
            with self._lock:
                self._due.add(topic)

    def close(self) -> None:
        """Send what is queued, then stop the server, waiting CLOSE_WAIT s at most."""
        if self._stopping.is_set():
            return
        self._stopping.set()
        self._sender.join()
        self._flush()
        stopper = threading.Thread(target=self.server.stop, name="live view stop", daemon=True)
        stopper.start()
        stopper.join(CLOSE_WAIT)


def check_port(port, key: str) -> int:
    """A port to listen on, 0 for any free one (one line naming ``key`` otherwise)."""
    low, high = limits.PORT
    if isinstance(port, bool) or not isinstance(port, int) or not low <= port <= high:
        raise UserError(key, f"{port!r} is not a port number ({low} to {high}; 0: any free one)")
    return port


def check_host(host, key: str) -> str:
    """A host name or address to listen on (one line naming ``key`` otherwise)."""
    if not isinstance(host, str) or not host or len(host) > 253 or any(
            c.isspace() or not c.isprintable() or c in "/\\@[]" for c in host):
        raise UserError(key, f"{host!r} is not a host name or address (127.0.0.1: this machine "
                             f"only; 0.0.0.0: every interface)")
    return host


def _Listener(on_subscribe):
    """A foxglove.websocket.ServerListener (its other callbacks: the SDK's defaults)."""
    from foxglove.websocket import ServerListener

    class Listener(ServerListener):
        def on_subscribe(self, client, channel) -> None:
            on_subscribe(channel)

    return Listener()


class HeadlessSource:
    """What `simulate --view` publishes at each sample of a run: the states (as the node
    publishes them), /tf with every link, /imu, /energy, and the latched ones at sample 0."""

    def __init__(self, scene, odom_frame: str = ODOM):
        self.tree = FrameTree(scene.robot)
        self.names = scene.robot.joint_names()
        self.odom_frame = odom_frame
        self.imu = Imu()
        self.latched = {TF_STATIC_TOPIC: tf_static_cdr(self.tree, 0),
                        DESCRIPTION_TOPIC: description(robot_description(scene))}

    def messages(self, sim, k: int, stamp: int) -> dict:
        messages = state_messages(sim, stamp, self.names, self.odom_frame)
        del messages[CLOCK_TOPIC]   # the view broadcasts its time instead
        messages[TF_TOPIC] = tf_cdr(self.tree, sim.q, stamp, self.odom_frame)
        messages[IMU_TOPIC] = imu(self.imu.read(sim, k), stamp, self.tree.frame(BASE_LINK),
                                  self.imu.noise)
        messages[ENERGY_TOPIC] = energy(sim)
        if k == 0:
            messages.update(self.latched)
        return messages


class PacedView:
    """`simulate --view`: a `LiveView` fed by a `HeadlessSource`, each sample published when the
    wall clock reaches it (real-time factor 1, `pacing.Pacer`; a run that cannot keep up paces
    on from where it is, without bursts). Stamps are the run's time line (`timeline.Grid`)."""

    def __init__(self, port: int, scene, sample_rate: float, duration: float | None = None,
                 host: str = DEFAULT_HOST):
        self.view = LiveView(port, host)
        self.url = self.view.url
        self.source = HeadlessSource(scene)
        self.grid = Grid(sample_rate, duration)
        self.pacer = Pacer(1.0, 1.0 / sample_rate)
        self._k = 0

    def sample(self, sim) -> None:
        k, stamp = self._k, self.grid.stamp(self._k)
        self.pacer.wait_for(stamp, first=k == 0)
        self.view.publish(stamp, self.source.messages(sim, k, stamp))
        self._k += 1

    def close(self) -> None:
        self.view.close()
