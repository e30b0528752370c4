"""A command flood in its own process: wheel commands at RATE per second for SECONDS seconds of
wall time, alternating two valid values (so every message is a change); prints how many went
out.

    python command_flood.py RATE SECONDS
"""
import sys
import time

import rclpy
from std_msgs.msg import Float64MultiArray


def main() -> int:
    rate, seconds = float(sys.argv[1]), float(sys.argv[2])
    rclpy.init()
    node = rclpy.create_node("command_flood")
    publisher = node.create_publisher(Float64MultiArray, "wheel_effort_controller/commands", 10)
    messages = [Float64MultiArray(data=[0.01, 0.02]), Float64MultiArray(data=[0.02, 0.01])]
    sent = 0
    start = time.monotonic()
    while (now := time.monotonic()) - start < seconds:
        due = int((now - start) * rate)
        while sent < due:   # catch up in a burst, then sleep: the rate holds on average
            publisher.publish(messages[sent % 2])
            sent += 1
        time.sleep(0.0005)
    print(f"sent {sent} in {time.monotonic() - start:.3f} s", flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
