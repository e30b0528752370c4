"""The ROS harness of the node tests and of bench/node_benchmark.py: a private DDS domain on this
host, the `simulator` executable started as users start it (its own process, its output in a
file), a probe node of ours spun in a thread of this process, and the one `wait_for`
(waiting.py). Real rclpy over real DDS throughout; nothing is mocked."""
import contextlib
import os
import random
import signal
import subprocess
import threading
import time
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

from executables import executable
from waiting import TimedOut, found, wait_for  # noqa: F401  (re-exported: one harness)

STOP_TIMEOUT = 15.0   # s a stopped node may take to exit before it is killed


def private_domain(first: int, last: int) -> int:
    """A random ROS_DOMAIN_ID in [first, last], within this xdist worker's share of the domains
    Fast DDS takes (1-232): the modules that run at once, one per worker, never meet (random
    ranges that overlapped did: a node found another of its name), and concurrent runs of the
    suite rarely do."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")[2:]
    count = max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
    index = int(worker) % count if worker.isdigit() else 0
    share = 232 // count
    low, high = 1 + index * share, (index + 1) * share
    low, high = max(low, first), min(high, last)
    if low > high:   # the module's own range lies outside this worker's share: the share
        low, high = 1 + index * share, (index + 1) * share
    return random.randint(low, high)


def child_env(domain_id: int) -> dict:
    """The environment of a process started by a test: the test's own domain, on this host only."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               RCUTILS_COLORIZED_OUTPUT="0", PYTHONUNBUFFERED="1")
    env.pop("ROS_LOCALHOST_ONLY", None)
    return env


@contextlib.contextmanager
def on_domain(domain_id: int):
    """This process's own nodes on ``domain_id`` (discovery reads the environment)."""
    keys = ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")
    saved = {key: os.environ.get(key) for key in keys}
    os.environ.update(ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


@contextlib.contextmanager
def spinning(make_probe, domain_id: int):
    """Yield ``make_probe(context)`` (anything with a ``.node``) while an executor spins it in a
    thread, in a context of its own on ``domain_id``."""
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


def spin_until(node, done) -> int:
    """For a test's helper process: spin `node` until ``done()``, then shut down; exit status."""
    while not done():
        rclpy.spin_once(node, timeout_sec=0.1)
    node.destroy_node()
    rclpy.shutdown()
    return 0


class NodeProcess:
    """The installed `simulator` executable started as `ros2 run` starts it, with ``args`` after
    --ros-args; its stdout and stderr in a log file in ``log_dir``."""

    def __init__(self, log_dir, *args, env: dict, preexec_fn=None):
        self.log_path = Path(log_dir) / f"simulator-{time.monotonic_ns()}.log"
        self.log = open(self.log_path, "w")
        self.process = subprocess.Popen([executable("simulator"), "--ros-args", *args], env=env,
                                        stdout=self.log, stderr=subprocess.STDOUT,
                                        preexec_fn=preexec_fn)

    @property
    def pid(self) -> int:
        return self.process.pid

    def running(self) -> bool:
        return self.process.poll() is None

    def output(self) -> str:
        return self.log_path.read_text()

    def stop(self, sig=signal.SIGTERM):
        """Send ``sig`` (SIGTERM, as a launch system sends it; SIGINT as Ctrl-C does) and wait;
        the exit status, or None when it had to be killed."""
        if self.process.poll() is None:
            self.process.send_signal(sig)
        try:
            return self.process.wait(timeout=STOP_TIMEOUT)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
            return None
        finally:
            self.log.close()


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (s), from /proc."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")   # utime, stime
