"""Benchmark of the `simulator` node: CPU use and publication jitter at real-time
factor 1, the free-running real-time factor, resident memory. A script, not a test:

    python bench/node_benchmark.py [--duration 20] [--free-duration 10] [--out bench/NODE.md]

The node runs as users run it (the installed executable, its own process, real DDS on a private
domain) on the paper scene with rk4 at dt = 1 ms, driven by the scene's efforts (sent once,
command timeout off). This process subscribes to /clock and measures:
- CPU: utime + stime of the node process from /proc/<pid>/stat over the measuring window,
  as % of one core;
- jitter: wall-clock intervals between successive /clock receptions here (so it includes this
  subscriber's own scheduling): mean, std, p99, max;
- resident memory: VmRSS (and its anonymous / file-backed split) and VmHWM from /proc;
- free-running real-time factor (real_time_factor 0): simulated seconds (from /clock stamps) per
  wall second;
- the live view's cost: the node at real_time_factor 1 with foxglove_port on and a third-party
  Foxglove client (test/helpers/foxglove_client.js under Node.js) subscribed to every channel,
  against the same node without the server, in alternating phases of the same run (CPU time).
The node publishes what it publishes by default: the whole tree on /tf and /tf_static (with
tf2_msgs as tools/bootstrap.sh builds it into the venv), /imu, /robot_description.
Prints a markdown table and writes it to --out.
"""
from __future__ import annotations

import argparse
import os
import platform
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray

from mobile_manip_sim.ros.topics import LIVE_TOPIC_TYPES
from mobile_manip_sim.scene.loading import load_scene

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "test" / "helpers"))   # the tests' ROS harness, shared
import foxglove_js  # noqa: E402
import interfaces_build  # noqa: E402
import ros_harness  # noqa: E402

DOMAIN_ID = ros_harness.private_domain(100, 199)
RK4_1KHZ = ["-p", "integrator.method:=rk4", "-p", "integrator.dt:=0.001"]
WARM_UP = 3.0          # s of wall time before measuring (start-up, first impacts)


def memory_mb(pid: int) -> dict:
    status = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM", "RssAnon", "RssFile", "RssShmem"):
            status[key] = int(value.split()[0]) / 1024.0
    return status


class Listener:
    def __init__(self, context: Context):
        self.node = rclpy.create_node("node_benchmark", context=context)
        self.lock = threading.Lock()
        self.ticks: list[tuple[int, float]] = []   # (stamp ns, receive time s)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(Clock, "/clock", self._on_clock, qos)
        self.wheels = self.node.create_publisher(Float64MultiArray,
                                                 "/wheel_effort_controller/commands", 10)
        self.arm = self.node.create_publisher(Float64MultiArray,
                                              "/arm_effort_controller/commands", 10)

    def _on_clock(self, msg):
        now = time.monotonic()
        with self.lock:
            self.ticks.append((msg.clock.sec * 10 ** 9 + msg.clock.nanosec, now))

    def count(self) -> int:
        with self.lock:
            return len(self.ticks)

    def since(self, index: int) -> list:
        with self.lock:
            return self.ticks[index:]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def foxglove_client(port: int) -> subprocess.Popen:
    """The tests' Foxglove client subscribed to every live channel, decoding every message
    (without end: its counts are never reached), its output discarded."""
    modules = foxglove_js.install()
    wanted = [f"{topic}:{10 ** 9}" for topic in LIVE_TOPIC_TYPES]
    return subprocess.Popen(["node", str(foxglove_js.SCRIPT), f"ws://localhost:{port}", *wanted],
                            env=dict(os.environ, NODE_PATH=str(modules)),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def run_phase(listener: Listener, env: dict, args: list[str], duration: float,
              view: bool = False) -> dict:
    """Start the node with `args`, drive it with the scene's efforts, measure for `duration` s;
    ``view``: with foxglove_port on and a Foxglove client subscribed to every channel."""
    scene = load_scene(None)
    log_dir = tempfile.mkdtemp(prefix="node_benchmark_")
    port = free_port()
    if view:
        args = [*args, "-p", f"foxglove_port:={port}"]
    node = ros_harness.NodeProcess(log_dir, *args, "-p", "command_timeout:=0.0", env=env)
    code = None
    client = None
    try:
        start = listener.count()
        ros_harness.wait_for(lambda: not node.running() or (
            listener.count() > start and listener.wheels.get_subscription_count() > 0
            and listener.arm.get_subscription_count() > 0), "the node", 120.0)
        if not node.running():
            sys.exit(f"node_benchmark: the node exited: {node.output()}")
        listener.wheels.publish(Float64MultiArray(data=scene.wheel_efforts.tolist()))
        listener.arm.publish(Float64MultiArray(data=scene.joint_efforts.tolist()))
        if view:
            client = foxglove_client(port)
        time.sleep(WARM_UP)
        first = listener.count()
        cpu0, wall0 = ros_harness.cpu_seconds(node.pid), time.monotonic()
        peak_rss = 0.0
        while time.monotonic() < wall0 + duration:
            time.sleep(0.5)
            peak_rss = max(peak_rss, memory_mb(node.pid)["VmRSS"])
        cpu1, wall1 = ros_harness.cpu_seconds(node.pid), time.monotonic()
        memory = memory_mb(node.pid)
        ticks = listener.since(first)
        if client is not None and client.poll() is not None:
            sys.exit(f"node_benchmark: the Foxglove client ended: {client.stderr.read()}")
    except ros_harness.TimedOut as error:
        sys.exit(f"node_benchmark: {error}")
    finally:
        if client is not None and client.poll() is None:
            client.kill()
            client.wait()
        code = node.stop(signal.SIGTERM)
        if code is None:
            code = "killed after SIGTERM timeout"
    if len(ticks) < 2:
        sys.exit(f"node_benchmark: only {len(ticks)} /clock messages in {wall1 - wall0:.0f} s")
    stamps = np.array([t[0] for t in ticks], dtype=np.int64)
    received = np.array([t[1] for t in ticks])
    intervals = np.diff(received) * 1e3
    steps = np.diff(stamps)
    period = int(np.median(steps)) if steps.size else 0
    return {
        "cpu_percent": 100.0 * (cpu1 - cpu0) / (wall1 - wall0),
        "rtf": (stamps[-1] - stamps[0]) / 1e9 / (received[-1] - received[0]),
        "received": len(ticks), "missing": int(np.sum(steps // period - 1)) if period else 0,
        "interval_mean": float(intervals.mean()), "interval_std": float(intervals.std()),
        "interval_p99": float(np.percentile(intervals, 99)), "interval_max": float(intervals.max()),
        "rss": memory["VmRSS"], "rss_peak": max(peak_rss, memory["VmHWM"]),
        "rss_anon": memory.get("RssAnon", float("nan")),
        "rss_file": memory.get("RssFile", float("nan")),
        "rss_shmem": memory.get("RssShmem", float("nan")), "exit": code,
        "window": wall1 - wall0,
    }


def view_rows(pairs) -> list:
    """The live view's cost from (off, on) phase pairs: CPU of one core, and relative."""
    off = np.mean([a["cpu_percent"] for a, _ in pairs])
    on = np.mean([b["cpu_percent"] for _, b in pairs])
    each = ", ".join(f"{a['cpu_percent']:.1f} → {b['cpu_percent']:.1f} %" for a, b in pairs)
    return [
        ("CPU at real_time_factor 1, foxglove_port off → on with a client on every channel "
         "(each pair)", each, ""),
        ("  mean off / on", f"{off:.1f} / {on:.1f} % of one core", ""),
        ("  cost of the live view: extra CPU, in % of one core", f"{on - off:+.1f} %", "≤ 5 %"),
        ("  the same relative to the node's CPU with it off", f"{100.0 * (on - off) / off:+.1f} %",
         "≤ 5 %"),
        ("  achieved real-time factor with the live view on",
         " / ".join(f"{b['rtf']:.4f}" for _, b in pairs), "1"),
    ]


def machine() -> str:
    lines = Path("/proc/cpuinfo").read_text().splitlines()
    model = next((line.split(":", 1)[1].strip() for line in lines if line.startswith("model name")),
                 platform.processor() or "unknown CPU")
    load = Path("/proc/loadavg").read_text().split()[:3]
    return (f"{os.cpu_count()} × {model}, Python {platform.python_version()}, "
            f"load average {' '.join(load)} at start")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=20.0,
                        help="s measured at real-time factor 1")
    parser.add_argument("--free-duration", type=float, default=10.0,
                        help="s measured free-running")
    parser.add_argument("--out", default=str(HERE / "NODE.md"), help="markdown file to write")
    args = parser.parse_args(argv)

    interfaces_build.installed()   # tf2_msgs, for /tf: tools/bootstrap.sh builds it into the venv
    env = ros_harness.child_env(DOMAIN_ID)
    # Both integrators' kernels compiled (or loaded) here, so that no node compiles one while
    # it is being measured.
    ros_harness.warm_kernels(("rk4", 0.001), (None, None))
    where = machine()
    with ros_harness.on_domain(DOMAIN_ID), ros_harness.spinning(Listener, DOMAIN_ID) as listener:
        paced_args = [*RK4_1KHZ, "-p", "real_time_factor:=1.0"]
        # The live view's cost: off, on, off, on (alternating, so drifts in load fall on both)
        pairs = [(run_phase(listener, env, paced_args, args.duration),
                  run_phase(listener, env, paced_args, args.duration, view=True))
                 for _ in range(2)]
        paced = pairs[0][0]
        free = run_phase(listener, env, [*RK4_1KHZ, "-p", "real_time_factor:=0.0"],
                         args.free_duration)
        default = run_phase(listener, env, ["-p", "real_time_factor:=0.0"], args.free_duration)

    rows = [
        ("CPU at real_time_factor 1 (rk4, dt = 1 ms, 100 Hz publishing)",
         f"{paced['cpu_percent']:.1f} % of one core", "< 25 %"),
        ("achieved real-time factor when paced at 1", f"{paced['rtf']:.4f}", "1"),
        ("/clock reception interval: mean ± std",
         f"{paced['interval_mean']:.3f} ± {paced['interval_std']:.3f} ms", "10 ms"),
        ("/clock reception interval: p99 / max",
         f"{paced['interval_p99']:.3f} / {paced['interval_max']:.3f} ms", ""),
        ("messages received / missing in the window",
         f"{paced['received']} / {paced['missing']}", "— / 0"),
        ("resident memory VmRSS (anonymous + file-backed + shmem)",
         f"{paced['rss']:.0f} MB ({paced['rss_anon']:.0f} + {paced['rss_file']:.0f} + "
         f"{paced['rss_shmem']:.0f})", "< 200 MB"),
        ("peak resident memory VmHWM", f"{paced['rss_peak']:.0f} MB", "< 200 MB"),
        ("free-running real-time factor (rk4, dt = 1 ms)",
         f"{free['rtf']:.1f} (CPU {free['cpu_percent']:.0f} %)", ""),
        ("  the same per CPU second: simulated s / node CPU s (load-independent)",
         f"{100.0 * free['rtf'] / free['cpu_percent']:.1f}", ""),
        ("free-running real-time factor (scene's dop853, rtol 1e-10)",
         f"{default['rtf']:.1f} (CPU {default['cpu_percent']:.0f} %)", ""),
        ("  the same per CPU second", f"{100.0 * default['rtf'] / default['cpu_percent']:.1f}", ""),
        *view_rows(pairs),
        ("exit status after SIGTERM (paced / free / default)",
         f"{paced['exit']} / {free['exit']} / {default['exit']}", "0"),
    ]
    table = ["| measure | value | target |", "| --- | --- | --- |"]
    table += [f"| {name} | {value} | {target} |" for name, value, target in rows]
    text = "\n".join([
        "# Simulator node benchmark",
        "",
        f"`python bench/node_benchmark.py` — paper scene, driven by the scene's efforts; "
        f"{paced['window']:.0f} s measured at real_time_factor 1 after {WARM_UP:.0f} s of warm-up, "
        f"{free['window']:.0f} s free-running (real_time_factor 0). Machine: {where}.",
        "",
        *table,
        "",
        "Jitter is measured where a user sees it: receive times of /clock in a separate subscriber "
        "process (Python), so it includes that subscriber's scheduling. CPU is the node process's "
        "utime + stime over the window. Free-running figures include publishing every message; "
        "a free-running CPU well below 100 % means the node was competing for the cores with "
        "other processes (see the load average), so those real-time factors are lower bounds.",
        "",
        "The node runs with its defaults: the whole tree on /tf (odom → base_footprint, both "
        "wheels, every arm link and rod) and /tf_static, /imu and /robot_description besides "
        "/joint_states, /odom and /clock. The live view's cost is measured with a Foxglove "
        "client (@foxglove/ws-protocol under Node.js, in its own process) subscribed to every "
        "channel and decoding every message, against the same node with foxglove_port 0, in "
        "alternating phases of one run (off, on, off, on); the cost is the node's extra CPU "
        "time per wall second, as a share of one core and relative to the node without the "
        "server. Most of it is foxglove-sdk's sending of each message as its own WebSocket "
        "frame from its own threads (the node serialises each state once, for DDS and the view "
        "alike, and a channel nobody subscribed to costs nothing).",
        "",
    ])
    print(text)
    Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
