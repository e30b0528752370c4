"""A PD controller in its own process, closing the loop over DDS with a synchronous simulator:
for each /joint_states it publishes one wheel and one arm command computed from that state
alone; on the state stamped STATES periods it pauses the simulator and exits.

    python pd_controller.py STATES
"""
import sys

import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool

from ros_harness import spin_until

TARGET = (0.6, 0.25, -0.4, 0.3)   # arm joints: q_1, l_1, q_2, l_2
KP, KD = 20.0, 4.0
WHEEL_SPEED, KD_WHEEL = 2.0, 0.5  # rad/s, N·m s/rad


def main() -> int:
    states = int(sys.argv[1])
    rclpy.init()
    node = rclpy.create_node("pd_controller")
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    wheels = node.create_publisher(Float64MultiArray, "wheel_effort_controller/commands", 10)
    arm = node.create_publisher(Float64MultiArray, "arm_effort_controller/commands", 10)
    pause = node.create_client(SetBool, "mobile_manip_sim/pause")
    done = []

    def on_state(msg):
        if done:
            return
        stamp = msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec
        if stamp >= states * 10 ** 7:      # publish_rate 100 Hz: state `states`
            done.append(pause.call_async(SetBool.Request(data=True)))
            return
        q, v = msg.position, msg.velocity
        wheels.publish(Float64MultiArray(data=[KD_WHEEL * (WHEEL_SPEED - v[i]) for i in (0, 1)]))
        arm.publish(Float64MultiArray(data=[KP * (TARGET[i] - q[2 + i]) - KD * v[2 + i]
                                            for i in range(4)]))

    # Listen only once both commands reach the simulator: its first state waits for a state
    # subscriber, so none of the replies can be lost to discovery.
    while not (wheels.get_subscription_count() and arm.get_subscription_count()):
        rclpy.spin_once(node, timeout_sec=0.01)
    node.create_subscription(JointState, "joint_states", on_state, qos)
    return spin_until(node, lambda: bool(done) and done[0].done())


if __name__ == "__main__":
    raise SystemExit(main())
