"""Sweeps through the batch: a chunk run as one `Batch` gives the rows, Parquet table and CSV files
that the runs give one by one (`run_chunk_one_by_one`, the path before the batch), bit for bit —
through `sweep --local` (no Dask) and through a Dask task's `run_chunk`."""
import csv
import subprocess
from pathlib import Path

import pyarrow.parquet as pq

from executables import executable
from mobile_manip_sim.scene.loading import load_scene
from mobile_manip_sim.sweep import runner
from mobile_manip_sim.sweep.runner import run_chunk, run_chunk_one_by_one
from mobile_manip_sim.sweep.spec import load_spec

CONFIG = Path(__file__).resolve().parents[2] / "config"
# 18 runs: the three fixed-step methods (compiled lanes), two masses
# of which one is refused, random initial rates of rod 2.
SPEC = """\
duration: 0.6
sample_rate: 50
chunk: 7
grid:
  integrator.method: [rk4, semi_implicit_euler, euler]
  robot.arm.links[0].mass_per_length: [-1.0, 1.1]
random:
  count: 3
  seed: 5
  vary:
    initial.velocity[3]: {normal: [0.0, 2.0]}
"""
NOT_COMPARED = ("cpu_s", "worker")   # the chunk's CPU time per run; where it ran


def comparable(rows, columns=None) -> list[dict]:
    """The rows by run, without the columns that may differ (`columns`: those of a table, a
    row's missing ones as the table stores them: None)."""
    columns = columns or sorted({k for row in rows for k in row})
    return [{k: row.get(k) for k in columns if k not in NOT_COMPARED}
            for row in sorted(rows, key=lambda row: row["run"])]


def csv_files(directory: Path) -> dict:
    return {path.name: path.read_text() for path in sorted(directory.glob("run-*.csv"))}


def test_sweep_local_gives_the_rows_and_csv_files_of_the_runs_one_by_one(tmp_path):
    spec_path = tmp_path / "spec.yaml"
    spec_path.write_text(SPEC)
    out = tmp_path / "out"
    result = subprocess.run([executable("sweep"), str(spec_path), "--out", str(out), "--local",
                             "--workers", "2"], capture_output=True, text=True, timeout=3000)
    assert result.returncode == 0, result.stderr
    assert "this process (no Dask), 2 threads" in result.stdout
    assert "18 runs, 9 ok, 9 failed" in result.stdout
    spec = load_spec(spec_path)
    runs = spec.runs()
    reference_csv = tmp_path / "one_by_one"
    expected = run_chunk_one_by_one(spec.document, list(enumerate(runs)), spec.duration,
                                     spec.sample_rate, None, str(reference_csv))
    table = pq.read_table(out / "runs.parquet").to_pylist()
    for row in expected:
        row.update(runs[row["run"]])
    assert comparable(table) == comparable(expected, list(table[0]))
    assert any((row["impacts"] or 0) > 0 for row in table)
    assert csv_files(out / "runs") == csv_files(reference_csv)
    assert len(csv_files(reference_csv)) == 9


def test_a_dask_task_is_one_batch_with_the_rows_of_the_runs_one_by_one(tmp_path):
    """A chunk with a controller-driven arm (its tracking figures), a failing run and a time
    limit: run_chunk (the batch) and run_chunk_one_by_one agree row for row."""
    document = load_scene(CONFIG / "arm_trajectory.yaml").document
    runs = list(enumerate([
        {"integrator.method": "rk4", "integrator.dt": 0.002, "controller.feedforward": "none"},
        {"integrator.method": "rk4", "integrator.dt": 0.002, "effects.payload": 0.5},
        {"integrator.method": "semi_implicit_euler", "integrator.dt": 0.001},
        {"integrator.method": "rk4", "integrator.dt": 0.0},
    ]))
    batch = run_chunk(document, runs, 1.0, None, 600.0, None, 2)
    one_by_one = run_chunk_one_by_one(document, runs, 1.0, None, 600.0, None)
    assert comparable(batch) == comparable(one_by_one)
    assert [row["status"] for row in batch] == ["ok", "ok", "ok", "failed"]
    assert all(row["arm_tracking_rms"] > 0 for row in batch[:3])
    assert batch[3]["error"].startswith("integrator.dt")


def test_csv_rows_of_a_batch_are_the_ones_simulate_writes(tmp_path):
    """The CSV of one run of the sweep against `simulate --out` of the same overrides."""
    spec_path = tmp_path / "spec.yaml"
    spec_path.write_text(SPEC.replace("chunk: 7", "chunk: 18"))
    out = tmp_path / "out"
    subprocess.run([executable("sweep"), str(spec_path), "--out", str(out), "--local"],
                   check=True, capture_output=True, timeout=3000)
    row = next(row for row in pq.read_table(out / "runs.parquet").to_pylist()
               if row["status"] == "ok" and row["impacts"] > 0)
    settings = [f"--set=integrator.method={row['integrator.method']}",
                f"--set=robot.arm.links[0].mass_per_length={row['robot.arm.links[0].mass_per_length']!r}",
                f"--set=initial.velocity[3]={row['initial.velocity[3]']!r}"]
    simulated = tmp_path / "simulate.csv"
    subprocess.run([executable("simulate"), "--duration", "0.6", "--sample-rate", "50", "--out",
                    str(simulated), *settings], check=True, capture_output=True, timeout=600)
    with simulated.open() as a, (out / "runs" / f"run-{row['run']:06d}.csv").open() as b:
        assert list(csv.reader(a)) == list(csv.reader(b))


def test_a_block_in_pieces_stepped_beside_its_python_work_gives_the_rows_one_by_one(monkeypatch):
    """run_block with pieces of 3 lanes (one stepped in a helper thread while the next is built
    and the last one's figures are read) and lanes copied from templates (only numbers vary):
    the rows of the runs one by one."""
    document = load_scene().document
    runs = list(enumerate({"integrator.method": "rk4", "integrator.dt": 0.002,
                           "robot.arm.links[0].mass_per_length": 0.8 + 0.05 * i,
                           "efforts.joints[0]": 4.0 + 0.1 * i} for i in range(8)))
    runs[5][1]["robot.arm.links[0].mass_per_length"] = -1.0   # refused: its row says why
    monkeypatch.setattr(runner, "PIECE", 3)
    stats = {}
    rows = runner.run_block(document, runs, 0.6, None, None, None, 2, stats)
    one_by_one = run_chunk_one_by_one(document, runs, 0.6, None, None, None)
    assert comparable(rows) == comparable(one_by_one)
    assert [row["status"] for row in rows].count("ok") == 7
    assert any(row["impacts"] > 0 for row in rows if row["status"] == "ok")
    assert 0.0 < stats["compiled_cpu"]
