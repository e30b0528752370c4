"""One forward-dynamics evaluation per lane: the compiled core's vector lanes (its kernels
instantiated on a lane type of `build_info()["lane_width"]` doubles) against the same kernels in
double, and against the vector peak a multiply-and-add loop measures on this CPU.

- **Flops** are counted, not estimated: the core's frames and articulated forward dynamics of the
  paper robot, instantiated once on a number type that counts every +, −, ×, ÷ done on it and
  every sine and cosine (`core.Dynamics.count_forward_dynamics`), in the kernels' own operation
  order. Operations between two model constants are not counted (they are a double's).
- **Time** is CPU time of the core's own loops (`time_forward_dynamics`, `_lanes`): the scalar
  kernel on one run, the lanes kernel on one block of different runs, per lane.
- **The peak** is measured, not looked up: the core's loop of independent vector multiplies and
  additions in its lane type (`core.time_multiply_add`, no fused multiply-add, as the kernels).
  The ratio of the two rates is a ratio of two measurements on this CPU, whatever its clock.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from ..core import build_info, time_multiply_add
from ..dynamics import Dynamics
from ..scene.loading import load_scene
from . import loops
from .tables import table, verdict

GOAL = 2.0           # per run in lanes within 2× of the vector peak
SCALAR_GOAL = 250e-9  # s, one scalar evaluation of the paper robot
RUNS_A_CALL = 64


@dataclass
class LanesResult:
    width: int = 0                                 # doubles a lane block (the build's)
    flops: dict = field(default_factory=dict)      # counted operations of one evaluation
    scalar_ns: float = math.nan                    # ns per evaluation, scalar kernel
    lanes_ns: float = math.nan                     # ns per lane-evaluation, one vector block
    call_ns: float = math.nan                      # … RUNS_A_CALL runs a call from Python
    peak_per_ns: float = math.nan                  # flops per ns of the mul + add loop
    ghz: float = math.nan                          # /proc/cpuinfo's clock
    bits_equal: bool = False
    counted_same: bool = False                     # the counted run's u̇ = the kernel's, bitwise

    @property
    def total_flops(self) -> int:
        return sum(self.flops.get(k, 0) for k in ("add", "sub", "mul", "div"))


def paper_runs(count: int, seed: int = 28):
    """The paper robot's compiled dynamics and `count` different runs of it (states around the
    initial one, efforts around the scene's): (dynamics, q, u, Q) with one row a run."""
    scene = load_scene()
    dyn = Dynamics(scene.robot, gravity=scene.effects.gravity,
                   wheel_inertia=scene.effects.wheel_inertia)
    rng = np.random.default_rng(seed)
    nq, nu = scene.robot.n_q, scene.robot.n_u
    Q0 = np.concatenate([dyn.wheel_forces(*scene.wheel_efforts), scene.joint_efforts])
    q = np.array(scene.initial_q) + rng.normal(size=(count, nq)) * 0.1
    u = rng.normal(size=(count, nu))
    Q = Q0 + rng.normal(size=(count, nu)) * 0.1
    return dyn, q, u, Q


def bits_equal(dyn, q, u, Q) -> bool:
    """Every lane of a vector call equals the scalar kernel's run of that row, bit for bit."""
    ones = np.ones(q.shape[0] * u.shape[1])
    lanes = dyn.core.forward_dynamics_lanes(q, u.ravel(), Q.ravel(), dyn.gravity, ones)
    return all(np.array_equal(lanes[i], dyn.core.forward_dynamics(
        q[i], u[i], Q[i], dyn.gravity, np.ones(u.shape[1]))) for i in range(q.shape[0]))


def clock_ghz() -> float:
    """The clock /proc/cpuinfo reports, GHz (a virtual machine may report its nominal one)."""
    try:
        with open("/proc/cpuinfo") as handle:
            found = re.search(r"cpu MHz\s*:\s*([\d.]+)", handle.read())
        return float(found.group(1)) / 1e3 if found else math.nan
    except OSError:
        return math.nan


def peak_flops_per_ns(width: int, target: float) -> float:
    """Flops per ns of the core's mul + add loop: 12 vector operations of `width` a round."""
    seconds = loops.per_call(time_multiply_add, target=target)
    return 12 * width / (seconds * 1e9)


def measure(progress, quick: bool = False) -> LanesResult:
    target = 0.02 if quick else 0.1
    result = LanesResult(width=build_info()["lane_width"])
    W = result.width
    dyn, q, u, Q = paper_runs(RUNS_A_CALL)
    core, g, nu = dyn.core, dyn.gravity, u.shape[1]
    result.bits_equal = bits_equal(dyn, q, u, Q)
    result.flops, counted_ud = core.count_forward_dynamics(q[0], u[0], Q[0], g)
    result.counted_same = bool(np.array_equal(counted_ud, core.forward_dynamics(
        q[0], u[0], Q[0], g, np.ones(nu))))
    progress(f"one evaluation: {result.total_flops} flops counted ({result.flops})")
    result.scalar_ns = loops.per_call(lambda calls: core.time_forward_dynamics(
        q[0], u[0], Q[0], g, np.ones(nu), calls), target=target) * 1e9
    result.lanes_ns = loops.per_call(lambda calls: core.time_forward_dynamics_lanes(
        q[:W].ravel(), u[:W].ravel(), Q[:W].ravel(), g, np.ones(W * nu), calls),
        target=target) * 1e9
    result.call_ns = loops.per_python_call(
        core.forward_dynamics_lanes, q, u.ravel(), Q.ravel(), g, np.ones(q.shape[0] * nu),
        target=target) * 1e9 / q.shape[0]
    result.peak_per_ns = peak_flops_per_ns(W, target)
    result.ghz = clock_ghz()
    progress(f"scalar {result.scalar_ns:.0f} ns, lanes ({W} wide) {result.lanes_ns:.0f} ns per "
             f"lane (×{result.scalar_ns / result.lanes_ns:.2f}), {RUNS_A_CALL} runs a call from "
             f"Python {result.call_ns:.0f} ns per run; mul + add loop "
             f"{result.peak_per_ns:.1f} flops/ns; lanes equal their scalar runs bit for bit: "
             f"{result.bits_equal}")
    return result


def section(result: LanesResult, number: int = 10) -> str:
    flops, counts, W = result.total_flops, result.flops, result.width
    rate = {"scalar": flops / result.scalar_ns, "lanes": flops / result.lanes_ns}   # per ns
    below = result.peak_per_ns / rate["lanes"]
    rows = [("flops of one evaluation (counted)",
             f"{flops}: + {counts.get('add', 0)}, − {counts.get('sub', 0)}, "
             f"× {counts.get('mul', 0)}, ÷ {counts.get('div', 0)} (besides: "
             f"{counts.get('neg', 0)} negations, {counts.get('sqrt', 0)} square roots, "
             f"{counts.get('sin', 0)} sin, {counts.get('cos', 0)} cos)", ""),
            ("scalar kernel, one run",
             f"{result.scalar_ns:.0f} ns: {rate['scalar']:.2f} flops/ns "
             f"({rate['scalar'] / result.peak_per_ns * 100:.0f} % of the vector peak)",
             verdict(result.scalar_ns <= SCALAR_GOAL * 1e9,
                     f"goal ≤ {SCALAR_GOAL * 1e9:.0f} ns")),
            (f"vector lanes, {W} runs a block, per run",
             f"{result.lanes_ns:.0f} ns: {rate['lanes']:.2f} flops/ns "
             f"({rate['lanes'] / result.peak_per_ns * 100:.0f} % of the vector peak; "
             f"×{result.scalar_ns / result.lanes_ns:.2f} the scalar kernel)",
             verdict(below <= GOAL, f"{below:.1f}× below the vector peak; goal within "
                                    f"{GOAL:g}×")),
            (f"{RUNS_A_CALL} runs in one call from Python (`forward_dynamics_lanes`), per run",
             f"{result.call_ns:.0f} ns", ""),
            (f"independent {W}-wide multiplies and adds (the vector peak, measured)",
             f"{result.peak_per_ns:.1f} flops/ns (/proc/cpuinfo says {result.ghz:.2f} GHz: "
             f"{result.peak_per_ns / result.ghz:.1f} flops per cycle at that clock)", ""),
            ("every lane = its scalar run, bit for bit", "yes" if result.bits_equal else "NO",
             ""),
            ("the counted run's u̇ = the scalar kernel's, bit for bit (the same operations)",
             "yes" if result.counted_same else "NO", "")]
    lines = [f"## {number}. One forward-dynamics evaluation per lane: vector lanes", "",
             "The paper robot's frames and articulated forward dynamics in the compiled core, "
             f"instantiated for one run (double) and for {W} runs side by side in vector "
             f"registers (this build's lane width: {W} doubles, from the CPU it was built on); "
             "the runs of a block have different states and efforts. CPU time of the core's own "
             "loops; flops counted by running the same kernels on numbers that count their "
             "arithmetic; the peak is the core's loop of independent vector multiplies and "
             "additions, so each ratio to the peak is a ratio of two measurements.", "",
             table(("", "measured", "verdict"), rows), "",
             "The lanes use no fused multiply-adds (the build has -ffp-contract=off): one rounds "
             "once where the scalar kernel rounds twice, and a lane would no longer equal its own "
             "run. Each sine and cosine is the C library's, lane by lane, for the same reason; "
             "the peak loop has no fused multiply-adds either.", ""]
    return "\n".join(lines)
