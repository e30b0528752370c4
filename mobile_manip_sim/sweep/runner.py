"""One run of a sweep, as `simulate` runs it, and the task that runs a chunk of them.

A run is `headless.run(scene, duration, sample_rate)` on the scene document with the run's
overrides, parsed by the scene parser: the final state is bit for bit what
``simulate --set PATH=VALUE …`` prints in its last CSV row. Any failure (a bad value, a
non-finite state, the time limit) becomes the row's ``error``; the sweep goes on.

A chunk (a Dask task, or a block of a sweep without Dask) runs as one `Batch` (`run_block`): its
runs are the batch's lanes, stepped together in compiled calls, each lane bit for bit its run
alone, so its row is the row `run_one` gives (but ``cpu_s``, the chunk's CPU time shared out
among its runs). `run_chunk_one_by_one` is the path without the batch, kept to compare.
"""
from __future__ import annotations

import csv
import functools
import time
from pathlib import Path

import numpy as np
from distributed import WorkerPlugin

from ..batch import Batch, TimeLimit, error_line, overlapped
from ..dynamics import constraint_residuals
from ..runtime import headless
from ..runtime.memory import collector_paused
from ..runtime.timeline import sample_times
from ..scene.coordinates import arm_width
from ..scene.errors import UserError
from ..scene.loading import check_work
from ..scene.overrides import scene_with
from .spec import DEFAULT_SAMPLE_RATE

# Lanes per batch of a block: one batch is stepped (its compiled calls on the threads) while
# the next one is built and the last one's figures are read, in Python, beside it.
PIECE = 256


@functools.cache
def _state_columns(n_links: int) -> tuple:
    return tuple(headless.csv_columns(n_links))


def state_columns(n_links: int) -> list[str]:
    return list(_state_columns(n_links))


def run_one(document: dict, overrides: dict, duration: float, sample_rate: float | None = None,
            time_limit: float | None = None, csv_path: str | None = None) -> dict:
    """The row of one run: status, error, final state (CSV names), checks and costs."""
    n_links = _links(document)
    rate = sample_rate or DEFAULT_SAMPLE_RATE
    row = {"status": "failed", "error": None}
    samples, csv_rows = [], []
    start_cpu, start_wall = time.thread_time(), time.perf_counter()

    def on_sample(sim):
        samples.append(sim.s.copy())
        if csv_path:
            csv_rows.append(headless.csv_row(sim))
        if time_limit is not None and time.perf_counter() - start_wall > time_limit:
            raise TimeLimit(f"time_limit: stopped after {time_limit:g} s wall at t = {sim.t:.6g} s")

    try:
        scene = scene_with(document, overrides)
        check_run(scene, n_links, duration, rate)
        sim = headless.run(scene, duration, rate, None, on_sample)
    except Exception as error:   # recorded as one line (`error_line`): the sweep goes on
        row["error"] = error_line(error)
    else:
        row.update(_figures(sim, scene, np.array(samples)))
        row["status"] = "ok"
        if csv_path:
            _write_csv(csv_path, state_columns(n_links), csv_rows)
    row["cpu_s"] = time.thread_time() - start_cpu
    return row


def check_run(scene, n_links: int, duration: float, rate: float) -> None:
    """A run's scene checked as a sweep checks it: its number of links, its work (UserError
    naming the key)."""
    if scene.robot.n_links != n_links:
        raise UserError("robot.arm.links", "a sweep cannot change the number of links")
    check_work(duration, scene.integrator, "duration", "integrator.dt", rate, "sample_rate")


def _links(document: dict) -> int:
    return len(document["robot"].get("arm", {}).get("links", []))


def run_block(document: dict, runs: list, duration: float, sample_rate: float | None = None,
              time_limit: float | None = None, csv_dir: str | None = None,
              threads: int | None = None, stats: dict | None = None,
              vector: bool = True) -> list[dict]:
    """The rows of ``runs`` [(run id, overrides)], run as the lanes of batches of up to PIECE
    lanes on `threads` threads, one batch stepped while the next is built and the last one's
    figures are read (`batch.overlapped`): each row is `run_one`'s for that run (``cpu_s``: the
    block's CPU time per run). `stats`, if given, receives the CPU s of the compiled calls
    (``compiled_cpu``: the process's CPU but that of its Python work, in either thread) and the
    grid steps taken in vector blocks and alone (``lane_steps``, `Batch.lane_steps`). `vector`:
    as `Batch`'s (False: every lane stepped alone; the same rows)."""
    rate = sample_rate or DEFAULT_SAMPLE_RATE
    start_cpu, start_python = time.process_time(), time.thread_time()
    n_links = _links(document)
    times = np.fromiter(sample_times(duration, rate), dtype=float)
    pieces = [runs[i:i + PIECE] for i in range(0, len(runs), PIECE)]

    def build(piece):
        batch = Batch(document, [overrides for _, overrides in piece], threads=threads,
                      time_limit=time_limit, vector=vector,
                      check=lambda scene: check_run(scene, n_links, duration, rate))
        batch.prepare()   # here, beside the last batch's compiled calls
        return batch

    calls = {"block": 1}   # samples per compiled call: each batch starts where the last ended

    def step(batch):
        batch.block = calls["block"]
        samples = batch.sample(times, collect=False)   # impacts read by `_rows`, beside the next
        calls["block"] = batch.block
        return samples

    rows, stepping_python, lane_steps = [], 0.0, np.zeros(2, dtype=np.int64)
    with collector_paused():
        for piece, batch, samples in overlapped(pieces, build, step):
            batch.collect()
            rows += _rows(piece, batch, samples, csv_dir)
            stepping_python += batch.python_cpu
            lane_steps += batch.lane_steps
    if stats is not None:
        python = time.thread_time() - start_python + stepping_python
        stats["compiled_cpu"] = time.process_time() - start_cpu - python
        stats["lane_steps"] = tuple(int(v) for v in lane_steps)
    cpu = (time.process_time() - start_cpu) / max(len(runs), 1)
    for row in rows:
        row["cpu_s"] = cpu
    return rows


def _rows(runs: list, batch, samples: np.ndarray, csv_dir: str | None) -> list[dict]:
    """The rows of a batch's runs [(run id, overrides)] from its samples (`_figures`)."""
    rows = []
    for i, (run_id, _) in enumerate(runs):
        row = {"run": run_id, "status": "failed", "error": batch.errors[i]}
        sim = batch.lane(i)
        if row["error"] is None:
            try:
                states = samples[i, :, :-1]
                sim.tracking = _tracking(sim, states)
                row.update(_figures(sim, sim.scene, states, residual_of_samples))
                row["status"] = "ok"
                if csv_dir:
                    _write_csv(f"{csv_dir}/run-{run_id:06d}.csv", state_columns(sim.model.n_links),
                               _csv_rows(batch.sample_t[i], samples[i], sim.nq + sim.nu))
            except Exception as error:
                row.update(status="failed", error=error_line(error))
        rows.append(row)
    return rows


def _tracking(sim, states: np.ndarray):
    """The arm's `headless.Tracking` over the samples, as `headless.run` measures it, or None."""
    if not sim.arm_controller.active:
        return None
    tracking = headless.Tracking(arm_width(sim.nu))
    now = sim.s
    try:
        for s in states:
            sim.s = s   # read at each sample (q and the reference clock), as the run read it
            tracking.sample(sim)
    finally:
        sim.s = now
    return tracking


def _csv_rows(t: np.ndarray, samples: np.ndarray, size: int) -> list:
    """`headless.csv_row` of each sample: t, q, u (its first `size` entries), T + V."""
    return [[float(t[k]), *row[:size].tolist(), float(row[-1])]
            for k, row in enumerate(samples)]


def residual_per_sample(sim, samples: np.ndarray) -> float:
    """The largest constraint residual over the samples, one sample at a time (`run_one`)."""
    nq, nu = sim.nq, sim.nu
    residual = 0.0
    for s in samples:
        residual = max(residual, *map(abs, constraint_residuals(
            sim.model, s[:nq], sim.dynamics.configuration_rate(s[:nq], s[nq:nq + nu]))))
    return residual


def residual_of_samples(sim, samples: np.ndarray) -> float:
    """The same figure for all samples at once (`run_block`): q̇ of every sample in one compiled
    call, the residuals as arrays (the same operations, element by element)."""
    rates = sim.dynamics.core.configuration_rates(np.ascontiguousarray(samples, dtype=float))
    nq = sim.nq
    pair = constraint_residuals(sim.model, samples[:, :nq].T, rates.T)
    return max(0.0, *(float(np.max(np.abs(r), initial=0.0)) for r in pair))


def _figures(sim, scene, samples: np.ndarray, residual=residual_per_sample) -> dict:
    names = state_columns(scene.robot.n_links)
    figures = dict(zip(names, map(float, headless.csv_row(sim)), strict=True))
    nq = sim.nq
    residual = residual(sim, samples)
    stroke = np.array(scene.robot.stroke).reshape(-1, 2)
    violation = 0.0
    if scene.robot.n_links and scene.effects.stroke_limits is not None:
        l = samples[:, 6:nq:2]
        violation = max(0.0, float(np.max(np.maximum(stroke[:, 0] - l, l - stroke[:, 1]))))
    figures.update(energy_error=float(sim.energy_error()), impacts=len(sim.impacts),
                   steps=int(sim.steps),
                   rhs_evaluations=int(sim.rhs_evaluations), stroke_violation=violation,
                   constraint_residual=float(residual))
    if sim.tracking is not None:   # q − q_ref at the samples, over every arm joint (rad, m)
        figures.update(arm_tracking_rms=float(np.sqrt(np.mean(sim.tracking.rms ** 2))),
                       arm_tracking_max=float(sim.tracking.max.max()))
    return figures


def _write_csv(path: str, columns: list[str], rows: list) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(columns)
        writer.writerows([map(repr, row) for row in rows])


def run_chunk(document: dict, runs: list, duration: float, sample_rate: float | None,
              time_limit: float | None, csv_dir: str | None, threads: int = 1) -> list[dict]:
    """The Dask task: the rows of ``runs`` [(run id, overrides)] as one batch (`run_block`, one
    thread: a worker is one core), each tagged with its worker."""
    worker = _worker_address()
    rows = run_block(document, runs, duration, sample_rate, time_limit, csv_dir, threads)
    return [{**row, "worker": worker} for row in rows]


def run_chunk_one_by_one(document: dict, runs: list, duration: float, sample_rate: float | None,
                         time_limit: float | None, csv_dir: str | None) -> list[dict]:
    """`run_chunk` without the batch: `run_one` after `run_one`."""
    worker = _worker_address()
    rows = []
    for run_id, overrides in runs:
        csv_path = f"{csv_dir}/run-{run_id:06d}.csv" if csv_dir else None
        row = run_one(document, overrides, duration, sample_rate, time_limit, csv_path)
        rows.append({"run": run_id, **row, "worker": worker})
    return rows


def _worker_address() -> str:
    try:
        from distributed import get_worker
        return get_worker().address
    except (ImportError, ValueError):
        return "local"


class IgnoreInterrupts(WorkerPlugin):
    """A worker of the sweep's own LocalCluster: Ctrl-C on the terminal reaches the whole
    process group, and the sweep answers it (keeps every finished run, closes the cluster); its
    workers ignore it rather than each dying with a traceback. Workers of a scheduler given
    with --scheduler are the user's, and keep their Ctrl-C."""

    name = "mobile_manip_sim-ignore-interrupts"

    def setup(self, worker):
        import signal
        import threading
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)
