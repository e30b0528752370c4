"""Print every /tf transform as one line `stamp_ns parent child x y qz qw`; exit after N."""
import sys

import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from tf2_msgs.msg import TFMessage

from ros_harness import spin_until


def main() -> int:
    wanted = int(sys.argv[1])
    rclpy.init()
    node = rclpy.create_node("tf_listener")
    seen = []

    def on_tf(msg):
        for t in msg.transforms:
            stamp = t.header.stamp.sec * 10 ** 9 + t.header.stamp.nanosec
            r, p = t.transform.rotation, t.transform.translation
            print(stamp, t.header.frame_id, t.child_frame_id, repr(p.x), repr(p.y),
                  repr(r.z), repr(r.w), flush=True)
            seen.append(stamp)

    node.create_subscription(TFMessage, "/tf",
                             on_tf, QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    return spin_until(node, lambda: len(seen) >= wanted)


if __name__ == "__main__":
    raise SystemExit(main())
