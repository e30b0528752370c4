"""`sweep` on real Dask: a LocalCluster, and a real `dask scheduler` with two `dask worker`
processes on loopback of which one is killed mid-sweep; failed runs recorded with the key;
rows identical to what the `simulate` executable gives with the same overrides; resume after a
SIGINT without redoing a run; bad specs as one line and status 2."""
import contextlib
import csv
import os
import signal
import socket
import subprocess
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from executables import executable
from hostile_yaml import ALIAS_BOMB
from mobile_manip_sim.scene.errors import EXIT_USER_ERROR, UserError
from mobile_manip_sim.scene.loading import load_scene
from mobile_manip_sim.scene.overrides import parse_assignments
from mobile_manip_sim.sweep.runner import run_one
from waiting import no_hang, wait_for

# 24 runs: a negative mass (8 runs fail, naming the key), two integrators, four random draws.
SMALL = """\
duration: 0.5
chunk: 2
grid:
  robot.arm.links[0].mass_per_length: [-1.0, 0.9, 1.1]
  integrator.method: [rk4, dop853]
random:
  count: 4
  seed: 3
  vary:
    initial.velocity[2]: {normal: [0.0, 0.1]}
"""
# 40 runs of about 40 ms each, one per task: long enough to kill a worker or interrupt mid-sweep.
LONG = """\
duration: 1.0
chunk: 1
grid:
  robot.arm.links[1].mass_per_length: [0.8, 1.2]
random:
  count: 20
  seed: 11
  vary:
    initial.velocity[3]: {uniform: [-0.2, 0.2]}
"""
DETERMINISTIC = ["run", "status", "error", "t", "x", "y", "yaw", "q1", "l1", "q2", "l2", "v",
                 "omega", "qd1", "ld1", "qd2", "ld2", "energy", "energy_error", "impacts", "steps",
                 "rhs_evaluations"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start(command, **kwargs) -> subprocess.Popen:
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, **kwargs)


def stop(process: subprocess.Popen) -> None:
    """End a process this test started, and the children of its session (a LocalCluster)."""
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=15)
    try:
        os.killpg(process.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def act_on_first_run(command: list, out: Path, act) -> tuple[subprocess.Popen, str]:
    """Start the sweep `command` (writing to `out`); once its first run is on disk, `act(driver)`;
    the driver and its stderr once it has ended (stopped, whatever happens)."""
    driver = start(command)
    try:
        wait_for(lambda: parts(out), "the first finished run", 180)
        act(driver)
        _, stderr = driver.communicate(timeout=120)
    finally:
        stop(driver)
    return driver, stderr


def sweep(spec: Path, out: Path, *extra, timeout=120) -> subprocess.CompletedProcess:
    return subprocess.run([executable("sweep"), str(spec), "--out", str(out), *extra],
                          capture_output=True, text=True, timeout=timeout)




def parts(out: Path) -> list:
    """Rows of the chunks written so far (each part file is renamed into place whole)."""
    rows = []
    for path in sorted((out / "parts").glob("part-*.parquet")):
        try:
            rows += pq.read_table(path).to_pylist()
        except OSError:
            pass
    return rows


def table(out: Path) -> list[dict]:
    return pq.read_table(out / "runs.parquet").to_pylist()


def deterministic(rows) -> list[tuple]:
    return [tuple(row[name] for name in DETERMINISTIC) for row in rows]


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    directory = tmp_path_factory.mktemp("small")
    spec = directory / "small.yaml"
    spec.write_text(SMALL)
    result = sweep(spec, directory / "out", "--workers", "1")
    assert result.returncode == 0, result.stderr
    return directory / "out", result


@pytest.fixture(scope="module")
def long_spec(tmp_path_factory):
    spec = tmp_path_factory.mktemp("long") / "long.yaml"
    spec.write_text(LONG)
    return spec


@pytest.fixture(scope="module")
def killed_worker_table(long_spec, tmp_path_factory):
    """LONG through a real scheduler and two workers, worker B SIGKILLed after it has finished a
    run and while runs remain. Nothing is left to timing: the sweep starts once the scheduler has
    both workers and worker A's one thread is held by a task of this test (waiting on a Dask
    Event), so only B can finish a run, and the sweep task queued behind the held one on A (work
    stealing is off) cannot finish before A is released, after B is dead."""
    from distributed import Client, Event

    out = tmp_path_factory.mktemp("cluster") / "out"
    no_stealing = {"DASK_DISTRIBUTED__SCHEDULER__WORK_STEALING": "False"}
    with dask_cluster([{}, {}], no_stealing) as (address, _, workers, addresses):
        worker_a, victim, victim_address = addresses[0], workers[1], addresses[1]
        with Client(address, timeout=90) as client:
            release = Event("release-worker-a", client=client)

            def hold_worker_a():   # nested: pickled by value, the workers cannot import this file
                Event("release-worker-a").wait(timeout=300)

            held = client.submit(hold_worker_a, workers=[worker_a], pure=False, key="hold-worker-a")
            wait_for(lambda: client.processing([worker_a])[worker_a], "worker A to hold its task",
                     90)
            driver = start([executable("sweep"), str(long_spec), "--out", str(out),
                            "--scheduler", address])
            try:
                def sweep_task_on_a():
                    return any(str(key).startswith("runs-")
                               for key in client.processing([worker_a])[worker_a])
                wait_for(sweep_task_on_a, "a sweep task queued on worker A", 90)
                rows = wait_for(lambda: [r for r in parts(out) if r["worker"] == victim_address],
                                "a run finished by worker B", 90)
                assert len(parts(out)) < 40
                victim.send_signal(signal.SIGKILL)
                victim.wait(timeout=10)
                release.set()
                held.result(timeout=90)
                _, stderr = driver.communicate(timeout=90)
            finally:
                stop(driver)
        assert driver.returncode == 0, stderr
        assert "Traceback" not in stderr, stderr   # the lost worker is no news
        return table(out), len(rows), victim_address


@contextlib.contextmanager
def dask_cluster(worker_envs: list[dict], scheduler_env: dict | None = None):
    """A real `dask scheduler` and one `dask worker` per env (no nanny, one thread) on loopback,
    every worker connected: (address, scheduler process, worker processes, worker addresses);
    everything stopped after."""
    from distributed import Client

    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    scheduler = start([executable("dask"), "scheduler", "--host", "127.0.0.1", "--port",
                       str(port), "--no-dashboard"], env={**os.environ, **(scheduler_env or {})})
    processes, addresses = [scheduler], []
    try:
        for env in worker_envs:
            worker_port = free_port()
            addresses.append(f"tcp://127.0.0.1:{worker_port}")
            processes.append(start([executable("dask"), "worker", address, "--nthreads", "1",
                                    "--no-nanny", "--host", "127.0.0.1", "--worker-port",
                                    str(worker_port), "--no-dashboard"],
                                   env={**os.environ, **env}))
        with Client(address, timeout=90) as client:
            client.wait_for_workers(len(worker_envs), timeout=90)
            assert set(client.scheduler_info()["workers"]) == set(addresses)
        yield address, scheduler, processes[1:], addresses
    finally:
        for process in reversed(processes):
            stop(process)


def test_a_killed_worker_has_its_runs_redone_and_every_run_is_present_once(killed_worker_table):
    rows, _, victim = killed_worker_table
    assert [row["run"] for row in rows] == list(range(40))
    assert all(row["status"] == "ok" for row in rows), [row["error"] for row in rows
                                                        if row["error"]]
    workers = {row["worker"] for row in rows}
    assert victim in workers and len(workers) == 2


def test_failed_runs_are_recorded_with_the_key_and_the_others_are_ok(small):
    out, result = small
    rows = table(out)
    assert [row["run"] for row in rows] == list(range(24))
    for row in rows:
        if row["robot.arm.links[0].mass_per_length"] < 0:
            assert row["status"] == "failed"
            assert row["error"].startswith("robot.arm.links[0].mass_per_length: must be in [")
            assert row["x"] is None
        else:
            assert row["status"] == "ok" and row["error"] is None
            assert row["t"] == 0.5 and row["steps"] > 0 and abs(row["energy_error"]) < 1e-6
    assert "24 runs, 16 ok, 8 failed" in result.stdout
    assert "Traceback" not in result.stderr and "Error" not in result.stderr, result.stderr
    report = (out / "REPORT.md").read_text()
    for picture in ("atlas.png", "work_precision.png", "final_state.png"):
        assert f"]({picture})" in report and (out / picture).stat().st_size > 1000


def test_sweep_rows_are_bit_for_bit_what_simulate_gives(small, tmp_path):
    out, _ = small
    ok = [row for row in table(out) if row["status"] == "ok"]
    chosen = [ok[0], ok[5], ok[-1]]
    assert {row["integrator.method"] for row in chosen} == {"rk4", "dop853"}
    varied = ["robot.arm.links[0].mass_per_length", "integrator.method", "initial.velocity[2]"]
    processes = []
    for row in chosen:
        settings = [f"--set={path}={row[path]!r}" if isinstance(row[path], float)
                    else f"--set={path}={row[path]}" for path in varied]
        csv_path = tmp_path / f"run{row['run']}.csv"
        processes.append((row, csv_path, start([executable("simulate"), "--duration", "0.5",
                                                "--out", str(csv_path), *settings])))
    try:
        for row, csv_path, process in processes:
            _, stderr = process.communicate(timeout=120)
            assert process.returncode == 0, stderr
            with csv_path.open() as handle:
                last = list(csv.DictReader(handle))[-1]
            assert {name: float(value) for name, value in last.items()} == \
                {name: row[name] for name in last}, row["run"]
    finally:
        for _, _, process in processes:
            stop(process)


def test_resume_after_sigint_gives_the_same_table_without_redoing_a_run(long_spec,
                                                                        killed_worker_table,
                                                                        tmp_path):
    out = tmp_path / "out"
    driver, stderr = act_on_first_run([executable("sweep"), str(long_spec), "--out", str(out),
                                       "--workers", "1"], out,
                                      lambda driver: driver.send_signal(signal.SIGINT))
    assert driver.returncode == 130, stderr
    assert "interrupted" in stderr
    before = {row["run"]: row for row in table(out)}
    assert 0 < len(before) < 40
    result = sweep(long_spec, out, "--workers", "1")
    assert result.returncode == 0, result.stderr
    assert f"40 runs, {len(before)} already in" in result.stdout
    after = table(out)
    assert deterministic(after) == deterministic(killed_worker_table[0])
    for row in after:
        if row["run"] in before:   # CPU time to the nanosecond: the very row of the first session
            assert row["cpu_s"] == before[row["run"]]["cpu_s"]


@pytest.mark.parametrize("text, key", [
    ("grid:\n  robot.arm.linkz[0].mass: [1.0]\n", "grid.robot.arm.linkz[0].mass: unknown key path"),
    ("grid:\n  robot.arm.links[0].mas: [1.0]\n", "grid.robot.arm.links[0].mas: unknown key"),
    ("grid:\n  initial.velocity[9]: [1.0]\n", "grid.initial.velocity[9]: unknown key path"),
    ("grid:\n  integrator.dt: []\n", "grid.integrator.dt: expected a non-empty list"),
    ("random:\n  count: 3\n  vary:\n    initial.velocity[2]: {gauss: [0, 1]}\n",
     "random.vary.initial.velocity[2]: unknown distribution 'gauss'"),
    ("random:\n  count: 3\n  vary:\n    initial.velocity[2]: {uniform: [1.0]}\n",
     "random.vary.initial.velocity[2].uniform: expected [low, high]"),
    ("random:\n  count: 0\n  vary:\n    initial.velocity[2]: {normal: [0, 1]}\n",
     "random.count: expected a whole number"),
    ("duration: 1\n", "grid: nothing to sweep"),
    # simulate's bounds and work limits
    ("duration: 1e300\ngrid: {integrator.method: [rk4]}\n", "duration: must be in (0, 1e+06]"),
    ("sample_rate: 1e9\ngrid: {integrator.method: [rk4]}\n",
     "sample_rate: must be in [1e-06, 1e+06]"),
    ("duration: 100000\nsample_rate: 100\ngrid: {integrator.method: [dop853]}\n",
     "sample_rate: 100000 s × 100 Hz is more than 1000000 samples"),
    ("duration: 100000\ngrid: {integrator.method: [dop853]}\n",
     "sample_rate: 100000 s × 100 Hz is more than 1000000 samples"),
    ("random:\n  count: 1000000000\n  vary:\n    initial.velocity[2]: {normal: [0, 1]}\n",
     "random.count: expected a whole number from 1 to 1000000"),
    ("grid:\n" + "".join(f"  initial.{name}: [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]\n" for name in (
        "velocity[0]", "velocity[1]", "velocity[2]", "velocity[3]", "velocity[4]", "velocity[5]",
        "pose[0]", "pose[1]", "pose[2]", "wheels[0]")), "grid: 1e+10 runs (grid points × draws)"),
    ("grid:\n  initial.velocity[2]: [0, 1]\nrandom:\n  count: 1000000\n  vary:\n"
     "    initial.velocity[3]: {normal: [0, 1]}\n", "grid: 2e+06 runs (grid points × draws)"),
    ("random:\n  count: 3\n  vary:\n    initial.velocity[2]: {uniform: [-1.7e308, 1.7e308]}\n",
     "random.vary.initial.velocity[2].uniform: the range [-1.7e+308, 1.7e+308] is wider"),
    ("grid: {integrator.method: [rk4, rk4]}\n", "grid.integrator.method[1]: 'rk4' is listed twice"),
    ("grid:\n  initial.velocity[2]: [0, 1]\nrandom:\n  count: 2\n  vary:\n"
     "    initial.velocity[02]: {normal: [0, 1]}\n", "random.vary.initial.velocity[02]: varies "
     "initial.velocity[2] again (already in grid.initial.velocity[2])"),
    ("chunk: 10000000\ngrid: {integrator.method: [rk4]}\n", "chunk: expected a whole number"),
])
def test_bad_specs_are_one_line_naming_the_key(tmp_path, text, key):
    spec = tmp_path / "bad.yaml"
    spec.write_text(text)
    result = sweep(spec, tmp_path / "out", timeout=60)
    assert result.returncode == EXIT_USER_ERROR
    assert result.stderr.strip().startswith(f"sweep: error: {key}"), result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("content, problem", [
    (ALIAS_BOMB, "expands to more than 100000 YAML nodes"),
    ("grid: {integrator.method: [rk4]}\ngrid: {integrator.method: [euler]}\n",
     "grid: duplicate key"),
    ("grid: " + "[" * 3000 + "]" * 3000, "nested deeper than 64 levels"),
    (b"grid: \xff\n", "not UTF-8"), ("#" * (2 << 20), "larger than"),
    ("fifo", "not a regular file"), ("/dev/zero", "not a regular file"),
    ("grid: !!python/object:os.system {}\n", "not valid YAML"),
    ("duration: !!float abc\ngrid: {integrator.method: [rk4]}\n",
     "line 1: !!float 'abc' is not a YAML 1.2 float"),
    ("%YAML 1.1\n---\ngrid: {integrator.method: [rk4]}\n", "a %YAML 1.1 directive"),
])
def test_hostile_spec_files_are_one_line_without_reading_on(tmp_path, content, problem):
    """Spec files go through the scene's loader: its limits, refused in one line at once."""
    from mobile_manip_sim.sweep.spec import load_spec

    path = tmp_path / "spec.yaml"
    if content == "fifo":
        os.mkfifo(path)
    elif content == "/dev/zero":
        path = Path(content)
    else:
        (path.write_bytes if isinstance(content, bytes) else path.write_text)(content)
    with no_hang(f"refusing the spec {content!r:.40}"), pytest.raises(UserError) as caught:
        load_spec(str(path))
    assert problem in str(caught.value) and "\n" not in str(caught.value)


def test_simulate_set_values_are_read_by_the_same_loader():
    with pytest.raises(UserError) as caught:
        parse_assignments(["robot.base.mass=[*a]"])
    assert str(caught.value).startswith("--set robot.base.mass: not valid YAML")
    assert parse_assignments(["integrator.rtol=1e-10", "name=yes"]) == {
        "integrator.rtol": 1e-10, "name": "yes"}


def test_an_unreachable_scheduler_is_one_line(tmp_path):
    spec = tmp_path / "ok.yaml"
    spec.write_text("duration: 0.1\ngrid: {integrator.method: [rk4]}\n")
    address = f"tcp://127.0.0.1:{free_port()}"
    result = sweep(spec, tmp_path / "out", "--scheduler", address, "--connect-timeout", "1",
                   timeout=60)
    assert result.returncode == EXIT_USER_ERROR
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith(f"sweep: error: --scheduler: cannot reach {address}"), result.stderr


def test_a_run_past_its_time_limit_is_failed():
    document = load_scene(None).document
    row = run_one(document, {"integrator.method": "dop853"}, 1.0, time_limit=1e-6)
    assert row["status"] == "failed" and row["error"].startswith("time_limit: stopped after")


def test_simulate_set_names_a_bad_key(tmp_path):
    result = subprocess.run([executable("simulate"), "--set", "robot.arm.linkz=1", "--out",
                             str(tmp_path / "x.csv")],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == EXIT_USER_ERROR
    assert result.stderr.strip().startswith("simulate: error: robot.arm.linkz: unknown key"), \
        result.stderr


def test_a_finished_sweep_run_again_starts_no_cluster(small, tmp_path):
    """Every run already in DIR: the same command writes the report again and starts nothing
    (here a `distributed` whose Client and LocalCluster fail on use comes first)."""
    out, _ = small
    spec = tmp_path / "small.yaml"
    spec.write_text(SMALL)
    fake = tmp_path / "no_dask" / "distributed"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text(
        "class WorkerPlugin:\n    pass\n\n\n"
        "def _started(*args, **kwargs):\n"
        "    raise RuntimeError('a finished sweep started Dask')\n\n\n"
        "Client = LocalCluster = as_completed = _started\n")
    before = table(out)
    path = os.pathsep.join([str(fake.parent), os.environ.get("PYTHONPATH", "")])
    result = subprocess.run([executable("sweep"), str(spec), "--out", str(out)],
                            capture_output=True, text=True, timeout=120,
                            env={**os.environ, "PYTHONPATH": path})
    assert result.returncode == 0, result.stderr
    assert "all already in" in result.stdout and "nothing to run" in result.stdout
    assert "LocalCluster" not in result.stdout + result.stderr
    assert table(out) == before


def test_grid_points_a_method_ignores_are_dropped_with_one_line():
    """dop853 × dt: the adaptive method ignores dt, so its second dt would repeat the first;
    rk4 × rtol likewise. Each distinct run once; the sweep says how many it dropped."""
    from mobile_manip_sim.scene import schema
    from mobile_manip_sim.sweep.spec import parse_spec
    text = "grid: {integrator.method: [dop853, rk4], integrator.dt: [0.001, 0.002]}\n"
    spec = parse_spec(schema.load_yaml(text, what="test"))
    assert spec.runs() == [{"integrator.method": "dop853", "integrator.dt": 0.001},
                           {"integrator.method": "rk4", "integrator.dt": 0.001},
                           {"integrator.method": "rk4", "integrator.dt": 0.002}]
    assert "1 grid point dropped" in spec.duplicates() and "integrator.dt" in spec.duplicates()
    text = "grid: {integrator.rtol: [1.0e-6, 1.0e-8], integrator.method: [rk4, rk45]}\n"
    spec = parse_spec(schema.load_yaml(text, what="test"))
    assert [tuple(run.values()) for run in spec.runs()] == [
        (1e-6, "rk4"), (1e-6, "rk45"), (1e-8, "rk45")]
    text = "grid: {integrator.method: [rk4, euler], integrator.dt: [0.001, 0.002]}\n"
    spec = parse_spec(schema.load_yaml(text, what="test"))
    assert len(spec.runs()) == 4 and spec.duplicates() is None
