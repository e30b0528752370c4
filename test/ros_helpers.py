"""A test-side ROS context: its own rclpy context on the test's domain, a node spun in a thread."""
import contextlib
import threading

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor


@contextlib.contextmanager
def spinning(make_probe, domain_id: int):
    """Yield ``make_probe(context)`` (anything with a ``.node``) while an executor spins it."""
    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    probe = make_probe(context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(probe.node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        yield probe
    finally:
        executor.shutdown()
        probe.node.destroy_node()
        rclpy.shutdown(context=context)
        thread.join(timeout=5)


def child_env(domain_id: int) -> dict:
    """The environment of a node started by a test: the test's own domain, on this host only."""
    import os
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               RCUTILS_COLORIZED_OUTPUT="0", PYTHONUNBUFFERED="1")
    env.pop("ROS_LOCALHOST_ONLY", None)
    return env


def spin_until(node, done) -> int:
    """For a test's helper process: spin `node` until ``done()``, then shut down; exit status."""
    while not done():
        rclpy.spin_once(node, timeout_sec=0.1)
    node.destroy_node()
    rclpy.shutdown()
    return 0
