"""Many runs in one call (`mobile_manip_sim.batch`): the paper sweep of 10,000 runs (rk4, dt 2 ms,
1.5 s, rod 1's mass and joint 1's effort varied) as one block on 1 core and 2, beside MuJoCo's
`rollout` with 2 threads on the equivalent model doing the same runs, in the same process; the
issue's sweep (10,000 runs, rod 1's mass varied) through the `sweep` command, with `--local` and
on its own LocalCluster of 2 workers, each a fresh process timed from its start to its exit
(cluster start included); the cost per lane against the number of lanes; and the lanes'
arithmetic rate against this CPU's peaks.

The machine may be shared: every figure is CPU time of this process (all its threads,
`time.process_time`) beside wall time, and the comparisons are ratios measured in this run.
"""
from __future__ import annotations

import contextlib
import math
import os
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..runtime.timeline import sample_times
from .scenes import paper_document
from .start import warm_environment
from .tables import table, verdict

RUNS, QUICK_RUNS = 10_000, 1_000
DT, DURATION, RATE = 0.002, 1.5, 100.0
LANES = (1, 8, 64, 1024)
@dataclass
class Timing:
    wall: float
    cpu: float


@dataclass
class BatchResult:
    runs: int
    one_thread: Timing = None
    two_threads: Timing = None
    alone_lanes: Timing = None              # 2 threads, each lane alone (no vector blocks)
    compiled_share: float = math.nan        # of the 2-thread CPU time, inside the compiled call
    lane_steps: tuple = (0, 0)              # grid steps in vector blocks, and alone
    mujoco: Timing | None = None
    sweep_local: Timing | None = None       # `sweep --local --workers 2`, the whole command
    sweep_cluster: Timing | None = None     # `sweep --workers 2` (its LocalCluster)
    sweep_runs: int = 0
    per_lane: dict = field(default_factory=dict)   # N → CPU s per lane (batch.sample only)
    alone: float = math.nan                  # CPU s of one Simulation.sample of the same run
    fd_ns: float = math.nan                  # ns per rhs evaluation per lane in the batch
    fd_flops: int = 0                        # counted flops of one forward dynamics
    peak_per_ns: float = math.nan            # flops per ns of the core's mul + add loop
    rows_equal: bool = False                 # every lane's final state = its run alone (sampled)
    load: float = math.nan                   # the machine's 1-minute load average before
    others: float = math.nan                 # … and CPUs busy with other processes meanwhile


def paper_runs(count: int, seed: int = 28) -> list[dict]:
    """`count` runs of the paper scene: rk4 at 2 ms, rod 1's mass per length in [0.8, 1.2] kg/m
    and joint 1's effort in [4.0, 5.0] N·m, drawn uniformly."""
    rng = np.random.default_rng(seed)
    masses, efforts = rng.uniform(0.8, 1.2, count), rng.uniform(4.0, 5.0, count)
    return [{"integrator.method": "rk4", "integrator.dt": DT, "duration": DURATION,
             "robot.arm.links[0].mass_per_length": float(m), "efforts.joints[0]": float(e)}
            for m, e in zip(masses, efforts, strict=True)]


@contextmanager
def on_cores(count: int):
    """Every thread of this process (and those it starts meanwhile) on `count` of its CPUs: the
    batch's Python work and its compiled calls then share them (one core: one after the other)."""
    allowed = sorted(os.sched_getaffinity(0))
    threads = [int(tid) for tid in os.listdir("/proc/self/task")]
    for tid in threads:
        os.sched_setaffinity(tid, set(allowed[:count]))
    try:
        yield
    finally:
        for tid in os.listdir("/proc/self/task"):
            try:
                os.sched_setaffinity(int(tid), set(allowed))
            except OSError:   # a thread that ended meanwhile
                pass


def _busy_cpu() -> float:
    """CPU s the whole machine has spent busy (all processes), from /proc/stat."""
    try:
        with open("/proc/stat") as handle:
            fields = [float(x) for x in handle.readline().split()[1:]]
        return (sum(fields[:8]) - fields[3] - fields[4]) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return math.nan


def _timed(work) -> tuple[Timing, object]:
    cpu0, wall0 = time.process_time(), time.perf_counter()
    result = work()
    return Timing(time.perf_counter() - wall0, time.process_time() - cpu0), result


def sweep_block(runs: list[dict], threads: int, stats: dict | None = None,
                vector: bool = True):
    """The sweep's work for these runs (`runner.run_block`: scenes, batch, figures); `vector`
    False: each lane stepped alone, without the vector blocks."""
    from ..sweep.runner import run_block
    return run_block(paper_document(), list(enumerate(runs)), DURATION, None, None, None, threads,
                     stats, vector)


def mujoco_rollout(runs: list[dict], threads: int = 2) -> Timing | None:
    """MuJoCo's rollout of the same runs (RK4, 2 ms, 750 steps, the mass and effort of each run)
    on `threads` threads: one model per distinct mass bucket (100), the effort as its control."""
    from . import mujoco_peer
    if not mujoco_peer.available():
        return None
    from mujoco import rollout

    from ..scene.loading import load_scene
    from ..scene.overrides import scene_with
    mujoco = mujoco_peer.mujoco
    document = paper_document()
    nstep = int(round(DURATION / DT))
    buckets = np.linspace(0.8, 1.2, 100)
    peers = [mujoco_peer.for_scene(scene_with(document, {
        "robot.arm.links[0].mass_per_length": float(m)}), "RK4", DT) for m in buckets]
    scene = load_scene()
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    peers[0].set_state(scene.initial_q, scene.initial_u)
    initial = np.zeros(mujoco.mj_stateSize(peers[0].model, spec))
    mujoco.mj_getState(peers[0].model, peers[0].data, initial, spec)
    models, controls = [], []
    for run in runs:
        peer = peers[int(np.argmin(np.abs(buckets - run["robot.arm.links[0].mass_per_length"])))]
        models.append(peer.model)
        joints = list(scene.joint_efforts)
        joints[0] = run["efforts.joints[0]"]
        controls.append(peer.control(scene.wheel_efforts, joints))
    controls = np.array(controls)[:, None, :]   # constant over the run: tiled by rollout
    datas = [mujoco.MjData(peers[0].model) for _ in range(threads)]
    chunk = 250   # runs per rollout call: its state output (every step) stays ~50 MB
    state = np.zeros((chunk, nstep, initial.size))

    def work():
        for first in range(0, len(runs), chunk):
            last = min(len(runs), first + chunk)
            rollout.rollout(models[first:last], datas,
                            np.repeat(initial[None, :], last - first, axis=0),
                            np.repeat(controls[first:last], nstep, axis=1),
                            state=state[:last - first], persistent_pool=True)
    timing, _ = _timed(work)
    return timing


def sweep_spec(count: int, path) -> None:
    """The issue's sweep as a spec file: `count` paper runs, rk4 at 2 ms, 1.5 s, rod 1's mass
    per length drawn uniformly in [0.8, 1.2] kg/m."""
    import yaml

    from .scenes import CONFIG
    path.write_text(yaml.safe_dump({
        "scene": str(CONFIG / "paper_two_link.yaml"), "duration": DURATION,
        "grid": {"integrator.method": ["rk4"], "integrator.dt": [DT]},
        "random": {"count": count, "seed": 28, "vary": {
            "robot.arm.links[0].mass_per_length": {"uniform": [0.8, 1.2]}}}}))


def sweep_command(count: int, local: bool, workers: int = 2) -> Timing:
    """Wall and CPU (the command and its children: the cluster's workers) of one `sweep` of
    the issue's runs, a fresh process from its start to its exit, into a fresh directory."""
    with tempfile.TemporaryDirectory() as tmp:
        spec = os.path.join(tmp, "sweep.yaml")
        sweep_spec(count, Path(spec))
        command = [sys.executable, "-m", "mobile_manip_sim.sweep.cli", spec, "--out",
                   os.path.join(tmp, "out"), "--workers", str(workers)] + (
            ["--local"] if local else [])
        before = os.times()
        wall0 = time.perf_counter()
        done = subprocess.run(command, capture_output=True, text=True, timeout=1800,
                              env=warm_environment())
        wall = time.perf_counter() - wall0
        after = os.times()
    if done.returncode != 0:
        raise RuntimeError(f"sweep exited {done.returncode}: "
                           f"{(done.stderr.strip().splitlines() or [''])[-1]}")
    return Timing(wall, (after.children_user - before.children_user)
                  + (after.children_system - before.children_system))


def per_lane_cost(runs: list[dict], threads: int = 2) -> dict:
    """CPU s per lane of `Batch.sample` alone (scenes and simulations built before) for N lanes."""
    from ..batch import Batch
    times = np.fromiter(sample_times(DURATION, RATE), float)
    costs = {}
    for n in LANES:
        batch = Batch(paper_document(), runs[:n], threads=threads)
        timing, _ = _timed(lambda b=batch: b.sample(times))
        costs[n] = timing.cpu / n
    return costs


def alone(run: dict) -> tuple[float, int]:
    """(CPU s, rhs evaluations) of one Simulation.sample of the run."""
    from ..engine.simulation import Simulation
    from ..scene.overrides import scene_with
    sim = Simulation(scene_with(paper_document(), run))
    times = np.fromiter(sample_times(DURATION, RATE), float)
    best = math.inf
    for _ in range(3):
        sim.reset()
        cpu0 = time.thread_time()
        sim.sample(times)
        best = min(best, time.thread_time() - cpu0)
    return best, sim.rhs_evaluations


def lanes_fd_rate(runs: list[dict], threads: int = 1) -> float:
    """ns of one rhs evaluation in one lane: a 64-lane batch on one thread, CPU over the lanes'
    rhs evaluations (the step arithmetic around them included)."""
    from ..batch import Batch
    batch = Batch(paper_document(), runs[:64], threads=threads)
    times = np.fromiter(sample_times(DURATION, RATE), float)
    timing, _ = _timed(lambda: batch.sample(times))
    evaluations = sum(batch.lane(i).rhs_evaluations for i in range(64))
    return timing.cpu / evaluations * 1e9


def measure(progress, quick: bool = False) -> BatchResult:
    runs = paper_runs(QUICK_RUNS if quick else RUNS)
    result = BatchResult(len(runs))
    result.load = os.getloadavg()[0]
    busy0, wall0, own0 = _busy_cpu(), time.perf_counter(), time.process_time()
    sweep_block(runs[:16], 2)   # compile or load the kernels
    stats = {}
    result.two_threads, rows = _timed(lambda: sweep_block(runs, 2, stats))
    result.compiled_share = stats["compiled_cpu"] / result.two_threads.cpu
    result.lane_steps = stats.get("lane_steps", (0, 0))
    progress(f"{len(runs)} paper runs as one block, 2 threads: {result.two_threads.wall:.2f} s "
             f"wall, {result.two_threads.cpu:.2f} s CPU, {result.compiled_share * 100:.0f} % "
             f"compiled; grid steps in vector blocks / alone: {result.lane_steps[0]} / "
             f"{result.lane_steps[1]}")
    result.alone_lanes, _ = _timed(lambda: sweep_block(runs, 2, vector=False))
    progress(f"… each lane alone (no vector blocks), 2 threads: {result.alone_lanes.wall:.2f} s "
             f"wall, {result.alone_lanes.cpu:.2f} s CPU")
    with on_cores(1):
        result.one_thread, _ = _timed(lambda: sweep_block(runs, 1))
    result.others = ((_busy_cpu() - busy0) - (time.process_time() - own0)) / (
        time.perf_counter() - wall0)
    progress(f"… 1 core: {result.one_thread.wall:.2f} s wall, {result.one_thread.cpu:.2f} s CPU "
             f"(×{result.one_thread.wall / result.two_threads.wall:.2f} from 1 to 2 cores)")
    checked = [0, len(runs) // 2, len(runs) - 1]
    from ..sweep.runner import run_one
    result.rows_equal = all(
        {k: v for k, v in run_one(paper_document(), runs[i], DURATION).items() if k != "cpu_s"}
        == {k: v for k, v in rows[i].items() if k not in ("cpu_s", "run")} for i in checked)
    result.mujoco = mujoco_rollout(runs, 2)
    if result.mujoco:
        progress(f"MuJoCo rollout, 2 threads, the same runs: {result.mujoco.wall:.2f} s wall, "
                 f"{result.mujoco.cpu:.2f} s CPU")
    result.sweep_runs = len(runs)
    for local in (True, False):   # a small sweep of each kind first: the bytecode caches warm
        with contextlib.suppress(RuntimeError, OSError, subprocess.TimeoutExpired):
            sweep_command(20, local)
    for local in (True, False):
        name = "sweep --local" if local else "sweep (LocalCluster)"
        try:
            timing = sweep_command(len(runs), local)
        except (RuntimeError, OSError, subprocess.TimeoutExpired) as error:   # said in the report
            progress(f"{name}: {error}".splitlines()[0])
            continue
        if local:
            result.sweep_local = timing
        else:
            result.sweep_cluster = timing
        progress(f"{name}, 2 workers, {len(runs)} runs, the whole command: {timing.wall:.2f} s "
                 f"wall, {timing.cpu:.2f} s CPU")
    result.per_lane = per_lane_cost(runs)
    result.alone, _ = alone(runs[0])
    progress("CPU per lane: " + ", ".join(f"N={n} {c * 1e3:.2f} ms"
                                          for n, c in result.per_lane.items())
             + f"; one Simulation alone {result.alone * 1e3:.2f} ms")
    result.fd_ns = lanes_fd_rate(runs)
    from . import lanes_fd
    dyn, q, u, Q = lanes_fd.paper_runs(1)
    counts, _ = dyn.core.count_forward_dynamics(q[0], u[0], Q[0], dyn.gravity)
    result.fd_flops = sum(counts[k] for k in ("add", "sub", "mul", "div"))
    result.peak_per_ns = lanes_fd.peak_flops_per_ns(lanes_fd.build_info()["lane_width"],
                                                    0.02 if quick else 0.1)
    progress(f"one rhs evaluation per lane: {result.fd_ns:.0f} ns; vector peak "
             f"{result.peak_per_ns:.1f} flops/ns")
    return result


def _blocks_text() -> str:
    """What the plain grid steps run on."""
    from ..core import build_info
    return (f"Plain grid steps run in vector blocks of {build_info()['lane_width']} lanes "
            "(the C++ core's `lanes.hpp`: the engine's step instantiated on its lane "
            "type, built with -ffp-contract=off).")


def _piece() -> int:
    from ..sweep.runner import PIECE
    return PIECE


def section(result: BatchResult, number: int = 9) -> str:
    two, one = result.two_threads, result.one_thread
    speedup = one.wall / two.wall
    budget = 5.0 * result.runs / RUNS   # the 5 s for 10,000 runs, scaled to these
    rate = result.fd_flops / result.fd_ns if result.fd_ns else math.nan   # flops per ns
    rows = [("runs", f"{result.runs}", "")]
    local, cluster = result.sweep_local, result.sweep_cluster
    if local:
        rows.append(("`sweep --local --workers 2`, the whole command: wall / CPU",
                     f"{local.wall:.2f} s / {local.cpu:.2f} s",
                     verdict(local.wall <= budget, f"target ≤ {budget:g} s")))
    else:
        rows.append(("`sweep --local --workers 2`", "did not run (see the bench's log)",
                     "**MISS** (not measured)"))
    if cluster and local:
        over = cluster.wall / local.wall - 1.0
        rows.append(("`sweep --workers 2` (its LocalCluster), the whole command: wall / CPU",
                     f"{cluster.wall:.2f} s / {cluster.cpu:.2f} s",
                     verdict(over <= 0.15, f"{over * 100:+.0f} % over `--local` (target ≤ "
                                           "15 %, cluster start included)")))
    else:
        rows.append(("`sweep --workers 2` (its LocalCluster)", "did not run (see the bench's log)"
                     if not cluster else f"{cluster.wall:.2f} s wall", "**MISS** (not measured)"))
    rows += [("the sweep's work in this process (`run_block`), 2 threads: wall / CPU",
              f"{two.wall:.2f} s / {two.cpu:.2f} s", ""),
             ("the same, each lane alone (no vector blocks): wall / CPU",
              f"{result.alone_lanes.wall:.2f} s / {result.alone_lanes.cpu:.2f} s",
              f"vector blocks ×{result.alone_lanes.cpu / two.cpu:.2f} less CPU"),
             ("the same, 1 core (process pinned to one CPU): wall", f"{one.wall:.2f} s",
              verdict(speedup >= 1.8, f"×{speedup:.2f} from 1 to 2 cores (target ≥ 1.8)")),
             ("CPU inside the compiled call", f"{result.compiled_share * 100:.0f} %",
              verdict(result.compiled_share >= 0.75, "target ≥ 75 %")),
             ("grid steps in vector blocks / alone",
              f"{result.lane_steps[0]} / {result.lane_steps[1]}",
              f"{result.lane_steps[0] / max(sum(result.lane_steps), 1) * 100:.0f} % vector"),
             ("rows: a lane = its run alone", "yes" if result.rows_equal else "NO", "")]
    if result.mujoco:
        ratio = result.mujoco.wall / two.wall
        rows.append(("MuJoCo rollout, 2 threads: wall / CPU",
                     f"{result.mujoco.wall:.2f} s / {result.mujoco.cpu:.2f} s",
                     verdict(ratio >= 3.0, f"batch ×{ratio:.2f} faster (target ≥ 3)")))
    lines = [f"## {number}. Many runs in one call (batch)", "",
             f"The issue's sweep: {result.runs} runs of the paper scene (rk4, dt 2 ms, 1.5 s, "
             "rod 1's mass varied) through the `sweep` command on 2 cores, with `--local` (no "
             "Dask) and on its own LocalCluster of 2 workers: each a fresh process timed from "
             "its start to its exit (Python's start, imports, the cluster's start, the Parquet "
             "file and the sweep's report included); CPU of the command and its children. Then "
             "the sweep's work in this process (`sweep.runner.run_block`: scene, simulation, "
             "stepping, figures; joint 1's effort varied too), in batches of "
             f"{_piece()} lanes, one stepped while the next is built and the last one's figures "
             "are read, beside MuJoCo's `rollout` of the same runs. CPU: all threads of the "
             "process; inside the compiled calls: the process's CPU but that of its Python work.",
             "", table(("", "measured", "verdict"), rows), "",
             "Cost per lane (`Batch.sample` alone, 2 threads, CPU per lane):", "",
             table(("lanes N", "CPU per lane"),
                   [(str(n), f"{c * 1e3:.3f} ms") for n, c in result.per_lane.items()]
                   + [("1 Simulation alone", f"{result.alone * 1e3:.3f} ms")]), "",
             f"One rhs evaluation in a lane: {result.fd_ns:.0f} ns for about "
             f"{result.fd_flops} flops (the forward dynamics' count, §10): {rate:.2f} flops/ns, "
             f"{rate / result.peak_per_ns * 100:.0f} % of the vector peak the core's mul + add "
             f"loop measures ({result.peak_per_ns:.1f} flops/ns), the step arithmetic, events "
             "and the lanes' steps taken alone included. " + _blocks_text(), ""]
    missed = local.wall if local else two.wall
    if missed > budget:
        per_run = two.cpu / result.runs * 1e3
        compiled = per_run * result.compiled_share
        start = f"; the command's own start and end: {local.wall - two.wall:.2f} s" if local \
            else ""
        lines += [f"Where the ≤ {budget:g} s target is missed (×{missed / budget:.2f} over it): "
                  f"a run costs {per_run:.2f} ms of CPU, {compiled:.2f} ms of it in the compiled "
                  f"calls and {per_run - compiled:.2f} ms in Python (its scene and records "
                  "built from the template, its figures read), and the two cores were busy "
                  f"{two.cpu / two.wall / 2 * 100:.0f} % of the wall time{start}; 10,000 runs "
                  "in 5 s on 2 cores leave at most 1 ms of CPU a run, all of it used.", ""]
    if os.cpu_count():
        lines.append(f"This machine: {os.cpu_count()} cores; load average {result.load:.2f} "
                     f"before the section, and other processes kept {result.others:.2f} CPUs "
                     "busy on average while the batch ran on 1 and 2 cores (wall times and the "
                     "1-to-2-core ratio are those of a quiet machine only when this is near 0).")
    return "\n".join(lines) + "\n"
