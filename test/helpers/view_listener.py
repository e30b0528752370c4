"""What a tf listener sees of the node, for test_node_view.py (run by the venv's Python, which
imports tf2_msgs: tools/bootstrap.sh builds it into the venv). Subscribes to /tf, /tf_static
(transient local, as tf2_ros does), NAMESPACE/robot_description (transient local),
NAMESPACE/joint_states and NAMESPACE/odom, collects until /tf brought COUNT messages (or STATIC
latched /tf_static messages when COUNT is 0) — COUNT from each publisher of a frame prefix in
PREFIXES (comma-separated; a listener that heard one publisher first could otherwise fill its count
before it heard the other) — and until MATCHED of the /tf stamps have come on joint_states and
odom too (each topic's subscription is matched on its own: the first /tf messages may come before
the listener hears the others), then prints one JSON document:

    view_listener.py COUNT [NAMESPACE] [STATIC] [PREFIXES] [MATCHED]

{"tf": [[stamp, parent, child, x, y, z, qx, qy, qz, qw], ...], "static": [[...same...], ...]
 (one list per /tf_static message), "description": URDF or null, "joints": {stamp: [names,
 positions]}, "odom": {stamp: [frame_id, child_frame_id, x, y, qz, qw]}}."""
import json
import sys

import rclpy
from nav_msgs.msg import Odometry
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from ros_harness import spin_until


def ns(stamp) -> int:
    return stamp.sec * 10 ** 9 + stamp.nanosec


def rows(message) -> list:
    return [[ns(t.header.stamp), t.header.frame_id, t.child_frame_id, t.transform.translation.x,
             t.transform.translation.y, t.transform.translation.z, t.transform.rotation.x,
             t.transform.rotation.y, t.transform.rotation.z, t.transform.rotation.w]
            for t in message.transforms]


def main() -> int:
    count = int(sys.argv[1])
    namespace = sys.argv[2].rstrip("/") if len(sys.argv) > 2 else ""
    statics = int(sys.argv[3]) if len(sys.argv) > 3 else 1
    prefixes = sys.argv[4].split(",") if len(sys.argv) > 4 else [""]
    matched = int(sys.argv[5]) if len(sys.argv) > 5 else 0
    rclpy.init()
    node = rclpy.create_node("view_listener")
    seen = {"tf": [], "static": [], "description": None, "joints": {}, "odom": {}}
    state = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    # depth 100 as tf2_ros's static listener: one latched message from EACH publisher is kept
    latched = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    tf_count = dict.fromkeys(prefixes, 0)

    def on_tf(message):
        seen["tf"] += rows(message)
        for prefix in prefixes:
            if message.transforms and message.transforms[0].header.frame_id.startswith(prefix):
                tf_count[prefix] += 1

    def on_description(message):
        seen["description"] = message.data

    def on_joints(message):
        seen["joints"][ns(message.header.stamp)] = [list(message.name), list(message.position)]

    def on_odom(message):
        pose = message.pose.pose
        seen["odom"][ns(message.header.stamp)] = [
            message.header.frame_id, message.child_frame_id, pose.position.x, pose.position.y,
            pose.orientation.z, pose.orientation.w]

    node.create_subscription(TFMessage, "/tf", on_tf, state)
    node.create_subscription(TFMessage, "/tf_static",
                             lambda m: seen["static"].append(rows(m)), latched)
    node.create_subscription(String, f"{namespace}/robot_description", on_description, latched)
    node.create_subscription(JointState, f"{namespace}/joint_states", on_joints, state)
    node.create_subscription(Odometry, f"{namespace}/odom", on_odom, state)
    try:
        code = spin_until(node, lambda: min(tf_count.values()) >= count
                          and len(seen["static"]) >= statics
                          and seen["description"] is not None
                          and len({row[0] for row in seen["tf"]} & seen["joints"].keys()
                                  & seen["odom"].keys()) >= matched)
    except KeyboardInterrupt:   # the test gave up: say what came
        print(f"/tf {tf_count} of {count} each, /tf_static {len(seen['static'])} of {statics}, "
              f"description {seen['description'] is not None}", file=sys.stderr)
        return 1
    print(json.dumps(seen), flush=True)
    return code


if __name__ == "__main__":
    raise SystemExit(main())
