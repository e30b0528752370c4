"""What the node shows besides its states: /tf, /tf_static and /robot_description (what a viewer
needs to draw the robot), /imu, and the live Foxglove view. The shell asks `messages` for each
publication (stepping thread, outside the loop's lock) and `publish` puts them out.

- /tf (parameter ``publish_tf``): ``all`` — odom_frame → base_frame and every moving joint's child
  (both wheels, every arm revolute and prismatic child) at each publication, stamped with its
  simulated time, from `frames.FrameTree`, the one owner of the frames; ``base`` — odom_frame →
  base_frame only (for users who run robot_state_publisher on /robot_description and
  /joint_states); ``none`` — no /tf. Both need tf2_msgs (a ROS install's, or the one
  tools/bootstrap.sh builds into .venv): without it the node says so once and runs on.
- /tf and /tf_static are ABSOLUTE names, as tf2_ros (robot_state_publisher) publishes them:
  robots in namespaces share one tree, their frames kept apart by ``frame_prefix``.
- /tf_static (``all`` only): ONE message holding every fixed joint, transient local, depth 1,
  reliable (as robot_state_publisher publishes it), at t = 0 of every time line (start, reset).
- /robot_description: the URDF (urdf.py, from the same tree), latched, at t = 0 of every time line.
- /imu (sensor_msgs/Imu, frame base_link): imu.py's reading of sample k, with the ``imu.noise.*``
  parameters (seeded: sample k's noise depends on the seed and k only).
- ``frame_prefix`` is applied by the tree to every frame named here and to /odom's frames.
- ``foxglove_port`` (not 0): a `live_view.LiveView` with the channels of `simulate --view`, on
  ``foxglove_host`` (127.0.0.1 by default; 0.0.0.0 for another machine). It
  and the bag always get the WHOLE tree on /tf and /tf_static, whatever ``publish_tf`` says (the
  ROS graph may have robot_state_publisher; a viewer of the live view or a bag has not).
- ``browser_port`` (not 0): a `view.browser.LiveBrowser` on ``browser_host``: the robot of the
  URDF above in a local web page, every link from the tree at each publication (at most
  `browser.FRAME_RATE` frames a second), with T + V and the impacts.
"""
from __future__ import annotations

from rclpy.serialization import serialize_message
from sensor_msgs.msg import Imu as ImuMessage
from std_msgs.msg import String

from ..ros.frames import BASE_LINK, FrameTree
from ..ros.imu import Imu
from ..ros.messages import description, energy, imu, tf_cdr, tf_static_cdr
from ..ros.topics import (
    DESCRIPTION_TOPIC,
    ENERGY_TOPIC,
    IMU_TOPIC,
    TF_STATIC_TOPIC,
    TF_TOPIC,
    latched_qos,
    state_qos,
)
from ..ros.urdf import robot_description
from ..scene.errors import UserError
from .qos import publisher

LIVE_BATCH = 0.04   # s of wall time: the live view sends at most 25 times a second (live_view.py)
# Key of the base-only /tf in a publication's messages (publish_tf base): what the ROS topic
# carries, while the bag and the live view get the whole tree under TF_TOPIC.
BASE_TF = "/tf (base only)"


class NodeView:
    """The view topics of ``node`` for ``scene``, by ``params`` (`NodeParameters`);
    ``warnings``: what the node says once it has started (tf2_msgs missing)."""

    def __init__(self, node, scene, params):
        self.tree = tree = FrameTree(scene.robot, params.base_frame, params.frame_prefix)
        links = tree.links
        for name, value, taken in (("odom_frame", params.odom_frame, links),
                                   ("base_frame", params.base_frame, links[1:])):
            if value in taken:   # two frames of one name: tf would see a loop, not a tree
                raise UserError(name, f"{value!r} is the name of one of the robot's links "
                                      f"({', '.join(links)}): give it another")
        self._odom = params.odom_frame   # bare: the tree prefixes it
        self.odom_frame, self.base_frame = tree.frame(params.odom_frame), tree.frame(tree.root)
        self.mode = params.publish_tf
        self.imu = Imu(params.imu_noise)
        self._imu_frame = tree.frame(BASE_LINK)
        self.latched = {TF_STATIC_TOPIC: tf_static_cdr(tree, 0), DESCRIPTION_TOPIC: description(
            robot_description(scene, root=params.base_frame, prefix=params.frame_prefix))}
        self.warnings = []
        self._ros = {DESCRIPTION_TOPIC: publisher(node, String, DESCRIPTION_TOPIC, latched_qos()),
                     IMU_TOPIC: publisher(node, ImuMessage, IMU_TOPIC, state_qos())}
        if self.mode != "none":
            try:
                from tf2_msgs.msg import TFMessage
            except ImportError:
                self.warnings.append("publish_tf: tf2_msgs does not import (source a ROS "
                                     "install, or run tools/bootstrap.sh, which builds it into "
                                     ".venv); no /tf")
            else:
                # Absolute, as tf2_ros publishes them: namespaced robots share one tree
                # (frame_prefix keeps their frames apart); -r /tf:=tf keeps it in the namespace.
                self._ros[TF_TOPIC] = publisher(node, TFMessage, TF_TOPIC, state_qos(),
                                                absolute=True)
                if self.mode == "all":
                    self._ros[TF_STATIC_TOPIC] = publisher(node, TFMessage, TF_STATIC_TOPIC,
                                                           latched_qos(), absolute=True)
        self.live = None
        self._wired: dict[str, bytes] = {}   # this publication's CDR, for the live view
        if params.foxglove_port:
            from ..ros.live_view import LiveView
            try:
                self.live = LiveView(params.foxglove_port, params.foxglove_host,
                                     name=node.get_fully_qualified_name(), batch=LIVE_BATCH)
            except UserError as error:   # the port in use: name the parameter
                raise UserError("foxglove_port", error.problem) from None

        self.browser = None
        if params.browser_port:
            from ..view.browser import LiveBrowser
            from ..view.drawing import read_urdf
            try:
                self.browser = LiveBrowser(scene, read_urdf(self.latched[DESCRIPTION_TOPIC].data),
                                           params.browser_port, params.browser_host,
                                           paced=False, tree=tree, odom=params.odom_frame)
            except UserError as error:   # the port in use: name the parameter
                raise UserError("browser_port", error.problem) from None

    def messages(self, sim, k: int, stamp: int) -> dict:
        """Topic → message (or its CDR bytes) of publication ``k`` at ``stamp`` ns, ``sim`` at
        that state: /tf (whole tree), /imu, the latched ones at k = 0, /energy when a live
        client wants it."""
        messages = {TF_TOPIC: tf_cdr(self.tree, sim.q, stamp, self._odom),
                    IMU_TOPIC: imu(self.imu.read(sim, k), stamp, self._imu_frame,
                                   self.imu.noise)}
        if self.mode == "base":
            messages[BASE_TF] = tf_cdr(self.tree, sim.q, stamp, self._odom, moving=False)
        if k == 0:
            messages.update(self.latched)
        if self.live is not None and self.live.wants(ENERGY_TOPIC):
            messages[ENERGY_TOPIC] = energy(sim)
        if self.browser is not None:
            self.browser.show(sim, stamp)
        return messages

    def publish_latched(self, messages: dict, published: dict) -> None:
        """At t = 0 of a time line, before the states: /tf_static and /robot_description."""
        self._put(self.latched, messages, published)

    def publish(self, stamp: int, messages: dict, published: dict) -> None:
        """After the states (the shell's): /tf and /imu, adding what went out to ``published``
        (the bag's); then the live view gets them all."""
        self._put((TF_TOPIC, IMU_TOPIC), messages, published)
        if self.live is not None:
            self.live.publish(stamp, {**messages, **self._wired})
            self._wired.clear()

    def wire(self, topic: str, message):
        """What to hand a ROS publisher of ``topic``: the message, or — when a live client
        wants the topic too — its CDR bytes, serialised once for both (rclpy publishes bytes
        as they are), so the live view costs no second serialisation."""
        if isinstance(message, bytes) or self.live is None or not self.live.wants(topic):
            return message
        self._wired[topic] = data = serialize_message(message)
        return data

    def _put(self, topics, messages: dict, published: dict) -> None:
        for topic in topics:
            if topic not in messages:
                continue
            pub = self._ros.get(topic)
            if pub is not None:
                pub.publish(self.wire(topic, messages[BASE_TF if topic == TF_TOPIC and
                                                      self.mode == "base" else topic]))
            published[topic] = messages[topic]

    def close(self) -> None:
        if self.live is not None:
            self.live.close()
            self.live = None
        if self.browser is not None:
            self.browser.close()
            self.browser = None
