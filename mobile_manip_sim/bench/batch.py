"""Many runs in one call (`mobile_manip_sim.batch`): the paper sweep of 10,000 runs (rk4, dt 2 ms,
1.5 s, rod 1's mass and joint 1's effort varied) as one block on 1 core and 2, beside MuJoCo's
`rollout` with 2 threads on the equivalent model doing the same runs, in the same process; the
same runs through Dask (a LocalCluster of 2 workers, one batch per task); the cost per lane
against the number of lanes; and the lanes' arithmetic rate against this CPU's peaks.

The machine may be shared: every figure is CPU time of this process (all its threads,
`time.process_time`) beside wall time, and the comparisons are ratios measured in this run.
"""
from __future__ import annotations

import math
import os
import re
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from ..runtime.timeline import sample_times
from .scenes import paper_document
from .tables import table, verdict

RUNS, QUICK_RUNS = 10_000, 1_000
DT, DURATION, RATE = 0.002, 1.5, 100.0
LANES = (1, 8, 64, 1024)
# Floating-point operations of one forward-dynamics evaluation of the paper robot (the FD body's
# additions, multiplications, divisions and square roots, its 6 sin/cos aside), counted once.
FLOPS_PER_FD = 2017
VECTOR_PEAK, SCALAR_PEAK = 16.0, 4.0   # double flops per cycle: 2 × 256-bit FMA pipes; scalar FMA


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
    dask: Timing | None = None
    per_lane: dict = field(default_factory=dict)   # N → CPU s per lane (batch.sample only)
    alone: float = math.nan                  # CPU s of one Simulation.sample of the same run
    fd_ns: float = math.nan                  # ns per rhs evaluation per lane in the batch
    ghz: float = math.nan
    instructions: dict = field(default_factory=dict)
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


def dask_sweep(runs: list[dict], workers: int = 2) -> Timing | None:
    """The same runs through a LocalCluster of `workers` (one thread each), one batch per task of
    at most 500 runs, as `sweep` submits them; timed from the first submit to the last row, the
    cluster started and its kernels loaded before."""
    import logging

    from distributed import Client, LocalCluster, wait

    from ..sweep.runner import WarmKernels, run_chunk
    document = paper_document()
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                      dashboard_address=None, silence_logs=logging.CRITICAL) as cluster, \
            Client(cluster) as client:
        client.register_plugin(WarmKernels())
        warm = client.map(run_chunk, [document] * workers, [list(enumerate(runs[:8]))] * workers,
                          [DURATION] * workers, [None] * workers, [None] * workers,
                          [None] * workers, pure=False)
        wait(warm)   # each worker has compiled or loaded the lanes' kernel
        chunk = min(500, math.ceil(len(runs) / (8 * workers)))
        blocks = [list(enumerate(runs))[i:i + chunk] for i in range(0, len(runs), chunk)]

        def work():
            futures = [client.submit(run_chunk, document, block, DURATION, None, None, None,
                                     pure=False) for block in blocks]
            return sum(len(f.result()) for f in futures)
        wall0 = time.perf_counter()
        done = work()
        wall = time.perf_counter() - wall0
    assert done == len(runs)
    return Timing(wall, math.nan)


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


def instruction_mix() -> dict:
    """Counts of packed (4-wide) and scalar double arithmetic in the machine code of the forward
    dynamics every lane runs (`articulated_forward_dynamics`, compiled afresh here: the cached
    copy keeps no assembly), on the paper robot's records."""
    from ..dynamics.jit import ENABLED
    from ..engine.core_stepping import CORE
    if not ENABLED or CORE == "cpp":   # the lanes run on the C++ core, not on this kernel
        return {}
    import numba

    from ..dynamics.articulated import articulated_forward_dynamics
    from ..engine.simulation import Simulation
    from ..scene.loading import load_scene
    sim = Simulation(load_scene())
    data, nq, nu = sim.system.data, sim.nq, sim.nu
    fresh = numba.njit(_nrt=False, error_model="numpy")(articulated_forward_dynamics.py_func)
    fresh(data.model, sim.s[:nq], sim.s[nq:nq + nu], data.Q, data.gravity, data.free, data.ws,
          np.zeros(nu))
    asm = "\n".join(fresh.inspect_asm().values())
    names = ("vmulpd", "vaddpd", "vsubpd", "vdivpd", "vfmadd", "vmulsd", "vaddsd", "vsubsd",
             "vdivsd")
    return {name: len(re.findall(rf"\b{name}\w*", asm)) for name in names}


def clock_ghz() -> float:
    try:
        with open("/proc/cpuinfo") as handle:
            found = re.search(r"cpu MHz\s*:\s*([\d.]+)", handle.read())
        return float(found.group(1)) / 1e3 if found else math.nan
    except OSError:
        return math.nan


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
    try:
        result.dask = dask_sweep(runs, 2)
        progress(f"through Dask (LocalCluster, 2 workers): {result.dask.wall:.2f} s wall")
    except Exception as error:   # no cluster on this machine: said in the report
        progress(f"Dask: {type(error).__name__}: {error}".splitlines()[0])
    result.per_lane = per_lane_cost(runs)
    result.alone, _ = alone(runs[0])
    progress("CPU per lane: " + ", ".join(f"N={n} {c * 1e3:.2f} ms"
                                          for n, c in result.per_lane.items())
             + f"; one Simulation alone {result.alone * 1e3:.2f} ms")
    result.fd_ns = lanes_fd_rate(runs)
    result.ghz = clock_ghz()
    result.instructions = instruction_mix()
    progress(f"one rhs evaluation per lane: {result.fd_ns:.0f} ns; machine code "
             f"{result.instructions}")
    return result


def _blocks_text(mix: dict, scalar: int, packed: int) -> str:
    """What the plain grid steps run on: the C++ core's vector blocks, or numba's."""
    if not mix:
        from ..core import build_info
        return (f"Plain grid steps run in vector blocks of {build_info()['lane_width']} lanes "
                "(the C++ core's `lanes.hpp`: the engine's step instantiated on its lane "
                "type, built with -ffp-contract=off).")
    return ("Plain grid steps run in numba's blocks of four lanes, the dynamics in 4-wide vector "
            "instructions (`batch/blocks.py`); the scalar forward dynamics every lane runs alone "
            f"holds {scalar} scalar and {packed} packed double arithmetic instructions ({mix}).")


def _piece() -> int:
    from ..sweep.runner import PIECE
    return PIECE


def section(result: BatchResult, number: int = 9) -> str:
    two, one = result.two_threads, result.one_thread
    speedup = one.wall / two.wall
    cycles = result.fd_ns * result.ghz
    rate = FLOPS_PER_FD / cycles if cycles else math.nan
    mix = result.instructions
    packed = sum(v for k, v in mix.items() if k.endswith("pd") or k == "vfmadd")
    scalar = sum(v for k, v in mix.items() if k.endswith("sd"))
    rows = [("runs", f"{result.runs}", ""),
            ("batch, 2 threads: wall / CPU", f"{two.wall:.2f} s / {two.cpu:.2f} s",
             verdict(two.wall <= 5.0 * result.runs / RUNS, "≤ 5 s for 10,000 runs")),
            ("the same, each lane alone (no vector blocks): wall / CPU",
             f"{result.alone_lanes.wall:.2f} s / {result.alone_lanes.cpu:.2f} s",
             f"vector blocks ×{result.alone_lanes.cpu / two.cpu:.2f} less CPU"),
            ("batch, 1 core (process pinned to one CPU): wall", f"{one.wall:.2f} s",
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
    if result.dask:
        over = result.dask.wall / two.wall - 1.0
        rows.append(("through Dask, 2 workers: wall", f"{result.dask.wall:.2f} s",
                     verdict(over <= 0.15, f"{over * 100:+.0f} % over the batch (target ≤ 15 %)")))
    lines = [f"## {number}. Many runs in one call (batch)", "",
             f"{result.runs} runs of the paper scene (rk4, dt 2 ms, 1.5 s, 100 Hz samples; rod "
             "1's mass and joint 1's effort varied), the sweep's whole work per run (scene, "
             "simulation, stepping, figures), in this process: batches of "
             f"{_piece()} lanes, one stepped while the next is built and the last one's figures "
             "are read. CPU: all threads of the process; inside the compiled calls: the "
             "process's CPU but that of its Python work.",
             "", table(("", "measured", "verdict"), rows), "",
             "Cost per lane (`Batch.sample` alone, 2 threads, CPU per lane):", "",
             table(("lanes N", "CPU per lane"),
                   [(str(n), f"{c * 1e3:.3f} ms") for n, c in result.per_lane.items()]
                   + [("1 Simulation alone", f"{result.alone * 1e3:.3f} ms")]), "",
             f"One rhs evaluation in a lane: {result.fd_ns:.0f} ns at {result.ghz:.2f} GHz ≈ "
             f"{cycles:.0f} cycles for about {FLOPS_PER_FD} flops: {rate:.2f} flops/cycle, "
             f"{rate / SCALAR_PEAK * 100:.0f} % of the scalar peak ({SCALAR_PEAK:g}) and "
             f"{rate / VECTOR_PEAK * 100:.0f} % of the vector peak ({VECTOR_PEAK:g}; target: "
             f"within 3×, i.e. ≥ {VECTOR_PEAK / 3:.1f}), the step arithmetic, events and "
             "the lanes' steps taken alone included. " + _blocks_text(mix, scalar, packed), ""]
    if two.wall > 5.0 * result.runs / RUNS:
        per_run = two.cpu / result.runs * 1e3
        compiled = per_run * result.compiled_share
        lines += [f"Where the ≤ 5 s target is missed (×{two.wall / (5.0 * result.runs / RUNS):.2f}"
                  f" over it): a run costs {per_run:.2f} ms of CPU, {compiled:.2f} ms of it in "
                  f"the compiled calls and {per_run - compiled:.2f} ms in Python (its scene and "
                  "records built from the template, its figures read), and the two cores were "
                  f"busy {two.cpu / two.wall / 2 * 100:.0f} % of the wall time; 10,000 runs in "
                  "5 s on 2 cores leave at most 1 ms of CPU a run, all of it used.", ""]
    if os.cpu_count():
        lines.append(f"This machine: {os.cpu_count()} cores; load average {result.load:.2f} "
                     f"before the section, and other processes kept {result.others:.2f} CPUs "
                     "busy on average while the batch ran on 1 and 2 cores (wall times and the "
                     "1-to-2-core ratio are those of a quiet machine only when this is near 0).")
    return "\n".join(lines) + "\n"
