"""/tf and /tf_static payloads (`cdr.tf_message_cdr`, encoded without tf2_msgs) are what rclpy
serialises where tf2_msgs is installed (built into the venv by tools/bootstrap.sh), byte for
byte, and decode with rosbags and mcap_ros2 from the bundled definition; the bundled type hash is
rosidl's and rosbags'."""
import json
import subprocess
import sys

import numpy as np
import pytest
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
from rosbags.typesys import Stores, get_typestore

from mobile_manip_sim.ros.cdr import TF_MESSAGE_TYPE, tf_message_cdr
from mobile_manip_sim.ros.frames import FrameTree
from mobile_manip_sim.ros.message_definitions import BUNDLED, definition_text, type_hash
from mobile_manip_sim.ros.messages import tf_cdr, tf_static_cdr
from robots import random_configuration
from test_urdf import SCENES

STAMP = 12 * 10 ** 9 + 345_678_901


def payloads():
    """(name, stamp, transforms) cases: the 5-link arm's /tf with odd-length names (every
    padding case), its /tf_static, and an empty message."""
    robot = SCENES["random_5"].robot
    tree = FrameTree(robot, prefix="r1/")
    q = random_configuration(np.random.default_rng(2), robot)
    return [("tf", STAMP, [tree.base_transform(q, "odom")] + tree.moving_transforms(q)),
            ("tf_static", 0, tree.static_transforms()), ("empty", 5, [])]


def as_dicts(transforms):
    return [{"parent": t.parent, "child": t.child, "translation": list(t.translation),
             "rotation": list(t.rotation)} for t in transforms]


RCLPY_SERIALISE = r"""
import json, sys
from geometry_msgs.msg import TransformStamped
from tf2_msgs.msg import TFMessage
from mobile_manip_sim.ros.cdr import exact_cdr
out = {}
for name, stamp, transforms in json.loads(sys.stdin.read()):
    message = TFMessage()
    for t in transforms:
        ts = TransformStamped()
        ts.header.stamp.sec, ts.header.stamp.nanosec = divmod(stamp, 10 ** 9)
        ts.header.frame_id, ts.child_frame_id = t["parent"], t["child"]
        tr, ro = ts.transform.translation, ts.transform.rotation
        tr.x, tr.y, tr.z = t["translation"]
        ro.x, ro.y, ro.z, ro.w = t["rotation"]
        message.transforms.append(ts)
    out[name] = exact_cdr(message).hex()
print(json.dumps(out))
"""


def test_payloads_equal_rclpys_serialisation_with_tf2_msgs(interfaces_prefix):
    cases = payloads()
    result = subprocess.run([sys.executable, "-c", RCLPY_SERIALISE], text=True,
                            input=json.dumps([(n, s, as_dicts(t)) for n, s, t in cases]),
                            capture_output=True, timeout=120)
    assert result.returncode == 0, result.stderr
    expected = json.loads(result.stdout)
    for name, stamp, transforms in cases:
        assert tf_message_cdr(stamp, transforms).hex() == expected[name], name


@pytest.mark.parametrize("case", range(3))
def test_payloads_decode_with_rosbags_and_mcap_ros2(case):
    name, stamp, transforms = payloads()[case]
    data = tf_message_cdr(stamp, transforms)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    decoded = typestore.deserialize_cdr(data, TF_MESSAGE_TYPE)
    schema = Schema(id=1, name=TF_MESSAGE_TYPE, encoding="ros2msg",
                    data=definition_text(TF_MESSAGE_TYPE).encode())
    other = DecoderFactory().decoder_for("cdr", schema)(data)
    for message in (decoded, other):
        assert len(message.transforms) == len(transforms)
        for got, t in zip(message.transforms, transforms, strict=True):
            assert (got.header.stamp.sec * 10 ** 9 + got.header.stamp.nanosec) == stamp
            assert (got.header.frame_id, got.child_frame_id) == (t.parent, t.child)
            tr, ro = got.transform.translation, got.transform.rotation
            assert (tr.x, tr.y, tr.z) == t.translation
            assert (ro.x, ro.y, ro.z, ro.w) == t.rotation


def test_bundled_definition_and_hash_are_the_upstream_ones(interfaces_prefix):
    text, rihs = BUNDLED[TF_MESSAGE_TYPE]
    assert type_hash(TF_MESSAGE_TYPE) == rihs == get_typestore(Stores.ROS2_JAZZY).hash_rihs01(
        TF_MESSAGE_TYPE)
    built = interfaces_prefix / "share" / "tf2_msgs" / "msg"
    assert (built / "TFMessage.msg").read_text() == text
    hashes = json.loads((built / "TFMessage.json").read_text())["type_hashes"]
    assert {h["type_name"]: h["hash_string"] for h in hashes}[TF_MESSAGE_TYPE] == rihs
    assert definition_text(TF_MESSAGE_TYPE).startswith(text + "=" * 80 + "\nMSG: geometry_msgs/")


def test_tf_carries_the_base_and_every_moving_joint_and_tf_static_the_fixed_ones():
    robot = SCENES["paper"].robot
    tree = FrameTree(robot)
    q = random_configuration(np.random.default_rng(4), robot)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    tf = typestore.deserialize_cdr(tf_cdr(tree, q, STAMP), TF_MESSAGE_TYPE).transforms
    assert [t.child_frame_id for t in tf] == ["base_footprint", "right_wheel", "left_wheel",
                                              "arm_link_1", "arm_rod_1", "arm_link_2", "arm_rod_2"]
    base_only = typestore.deserialize_cdr(tf_cdr(tree, q, STAMP, moving=False), TF_MESSAGE_TYPE)
    assert [(t.header.frame_id, t.child_frame_id) for t in base_only.transforms] == [
        ("odom", "base_footprint")]
    static = typestore.deserialize_cdr(tf_static_cdr(tree, 0), TF_MESSAGE_TYPE).transforms
    assert [(t.header.frame_id, t.child_frame_id) for t in static] == [
        ("base_footprint", "base_link"), ("arm_rod_2", "tip")]
