"""`sweep` when things around it fail, with real processes: its output directory filling up,
turning read-only or removed mid-sweep (a small tmpfs where the test may mount one); Ctrl-C and
SIGTERM mid-sweep; a worker of a real `dask scheduler` lost while the workers get ready or while
the last rows come back; the scheduler itself lost. Each ends in one line (or none, when the
sweep survives), every finished run kept, no traceback, no process left."""
import contextlib
import errno
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from executables import executable
from test_sweep import LONG, act_on_first_run, dask_cluster, parts, start, stop, table
from waiting import TimedOut, wait_for

# 400 runs of about 40 ms, one per task: a sweep that is still running when the test acts.
MANY = LONG.replace("count: 20", "count: 200")
STOP_BOUND = 2.0   # s from the signal to the sweep's exit (the issue's)
NOISE = ("Traceback", "leaked semaphore", "CommClosedError", "Exception", "Task was destroyed")


@pytest.fixture
def many_spec(tmp_path):
    spec = tmp_path / "many.yaml"
    spec.write_text(MANY)
    return spec


@contextlib.contextmanager
def small_disk(path: Path, size: str = "8m"):
    """A tmpfs of `size` at `path` (None where this process may not mount), unmounted after."""
    path.mkdir(parents=True)
    try:
        mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs",
                                  str(path)], capture_output=True, timeout=30).returncode == 0
    except (FileNotFoundError, subprocess.TimeoutExpired):
        mounted = False
    try:
        yield path if mounted else None
    finally:
        if mounted:
            subprocess.run(["umount", "-l", str(path)], capture_output=True, timeout=30)


def fill(disk: Path) -> None:
    """Write a file until the disk is full."""
    block = b"\0" * (1 << 16)
    with open(disk / "filler", "wb", buffering=0) as handle:
        while True:
            try:
                handle.write(block)
            except OSError as error:
                assert error.errno == errno.ENOSPC, error
                return


def make_read_only(disk: Path | None, out: Path) -> None:
    """The tmpfs remounted read-only (it refuses while a file is open for writing: tried again),
    or, without a tmpfs, the parts directory without write permission (root ignores that)."""
    if disk is None:
        if os.geteuid() == 0:
            pytest.skip("root, and no tmpfs: nothing makes a directory read-only")
        (out / "parts").chmod(0o555)
        return

    def remounted():
        return subprocess.run(["mount", "-o", "remount,ro", str(disk)], capture_output=True,
                              timeout=30).returncode == 0
    wait_for(remounted, "the tmpfs remounted read-only", 30)


def session_processes(session: int) -> list[int]:
    """The processes left in a session (the sweep's, started with start_new_session)."""
    left = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[3]) == session and fields[0] != "Z":
                left.append(int(entry.name))
    return left


def assert_one_line(stderr: str, start_text: str) -> str:
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(start_text), stderr
    assert not any(noise in stderr for noise in NOISE), stderr
    return lines[0]


def rows_said(line: str) -> int:
    """N of "…; N of M runs are in …"."""
    return int(line.rsplit("; ", 1)[1].split(" of ")[0])


@pytest.mark.parametrize("failure, where", [("full", "--local"), ("full", "--workers=1"),
                                            ("read-only", "--local"), ("removed", "--local")])
def test_an_output_directory_that_fails_mid_sweep_is_one_line_and_keeps_the_rows(
        many_spec, tmp_path, failure, where):
    with small_disk(tmp_path / "disk") as disk:
        if failure == "full" and disk is None:
            pytest.skip("no tmpfs to fill (mount refused)")
        out = (disk or tmp_path) / "out"
        first = []

        def fail(_):
            first.extend(parts(out))
            if failure == "full":
                fill(disk)
            elif failure == "read-only":
                make_read_only(disk, out)
            else:   # at once, as the sweep sees it: rmtree alone raced with the parts it
                gone = out.with_name("removed")   # was writing (a part written between its
                out.rename(gone)                  # listing and its rmdir failed the rmdir;
                shutil.rmtree(gone)               # runs.parquet rebuilt in DIR before DIR went)
        driver, stderr = act_on_first_run([executable("sweep"), str(many_spec), "--out",
                                           str(out), where], out, fail)
        assert driver.returncode == 2, stderr
        reason = {"full": "No space left on device", "read-only": "Read-only file system"
                  if disk else "Permission denied", "removed": "No such file or directory"}
        # the file that failed, or the directory where the error names no file (pyarrow's)
        line = assert_one_line(stderr, f"sweep: error: {out}")
        assert line[len(f"sweep: error: {out}")] in "/:", line
        assert f"cannot write ({reason[failure]}); " in line, line
        # runs.parquet cannot be rebuilt either: the parts hold the rows
        assert line.endswith(f" of 400 runs are in {out}/parts (run the same command to finish)")
        if failure != "removed":   # every part written before the failure is whole and kept
            kept = parts(out)
            assert len(kept) == rows_said(line) >= len(first), line
            assert len({row["run"] for row in kept}) == len(kept)


@pytest.mark.parametrize("signum, status, word", [(signal.SIGINT, 130, "interrupted"),
                                                  (signal.SIGTERM, 143, "terminated")])
def test_a_stop_ends_a_dask_sweep_at_once_in_one_line_keeping_its_rows(many_spec, tmp_path,
                                                                        signum, status, word):
    """Ctrl-C (to the process group, as a terminal sends it) or SIGTERM (to the sweep, as
    `kill` sends it) while the LocalCluster's worker runs: the sweep ends at once (STOP_BOUND)
    with its one line, runs.parquet holds the rows it says, and no worker is left."""
    out = tmp_path / "out"
    driver = start([executable("sweep"), str(many_spec), "--out", str(out), "--workers", "1"])
    try:
        wait_for(lambda: parts(out), "the first finished run", 180)
        sent = time.monotonic()
        if signum == signal.SIGINT:
            os.killpg(driver.pid, signum)
        else:
            driver.send_signal(signum)
        driver.wait(timeout=60)
        took = time.monotonic() - sent
        _, stderr = driver.communicate(timeout=30)
        # a worker SIGKILLed by the sweep may still be tearing down (not yet a zombie) as the
        # sweep exits, on a loaded machine: wait for the session to empty, then look
        with contextlib.suppress(TimedOut):
            wait_for(lambda: not session_processes(driver.pid), "the sweep's session empty", 10)
        left = session_processes(driver.pid)
    finally:
        stop(driver)
    assert driver.returncode == status, stderr
    line = assert_one_line(stderr, f"sweep: {word}; ")
    # the 2 s: 0.2–0.5 s with two CPU hogs on a 2-core machine (the interpreter's own
    # teardown, skipped now, took 0.6–1.5 s of it; before that the close waited 13 s for the
    # worker, and Ctrl-C did not end it at all)
    assert took < STOP_BOUND, f"the sweep took {took:.1f} s to end"
    assert not left, f"processes left in the sweep's session: {left}"
    assert line.endswith(f"of 400 runs are in {out}/runs.parquet (run the same command to finish)")
    assert len(table(out)) == rows_said(line) > 0


def test_a_worker_lost_as_the_sweep_starts_costs_no_run(tmp_path):
    """Worker B is SIGKILLed while the sweep starts (its driver still loading, before any run is
    sent). The sweep goes on with worker A: every run ok, status 0, nothing on stderr but
    progress."""
    spec = tmp_path / "long.yaml"
    spec.write_text(LONG)
    out = tmp_path / "out"
    with dask_cluster([{}, {}]) as (address, _, processes, workers):
        driver = start([executable("sweep"), str(spec), "--out", str(out), "--scheduler",
                        address])
        try:
            processes[1].send_signal(signal.SIGKILL)
            processes[1].wait(timeout=10)
            _, stderr = driver.communicate(timeout=180)
        finally:
            stop(driver)
    assert driver.returncode == 0, stderr
    assert not any(noise in stderr for noise in NOISE), stderr
    rows = table(out)
    assert [row["run"] for row in rows] == list(range(40))
    assert {row["status"] for row in rows} == {"ok"}
    assert {row["worker"] for row in rows} == {workers[0]}


def test_a_worker_lost_while_the_last_rows_come_back_costs_no_run_and_says_nothing(tmp_path):
    """The sweep's end: every run finished, worker A holding half the rows, and A killed while
    the scheduler fetches one of them for the sweep. Nothing is left to timing: the sweep is
    stopped (SIGSTOP) until every run is finished, A is frozen (SIGSTOP) before the sweep goes
    on, and A is killed once the scheduler holds a connection to it (the fetch, waiting for
    A's answer). The rows A held run again on B: status 0, every row ok, nothing on stderr
    (distributed's "Couldn't gather 1 keys, rescheduling" line was printed before)."""
    import psutil  # distributed's own dependency
    from distributed import Client

    spec = tmp_path / "long.yaml"
    spec.write_text(LONG)
    out = tmp_path / "out"
    with dask_cluster([{}, {}]) as (address, scheduler, processes, workers), \
            Client(address, timeout=90) as client:
        victim, port = processes[0], int(workers[0].rsplit(":", 1)[1])
        driver = start([executable("sweep"), str(spec), "--out", str(out), "--scheduler",
                        address])
        try:
            wait_for(lambda: parts(out), "the first finished run", 180)
            driver.send_signal(signal.SIGSTOP)

            def states(dask_scheduler):   # nested: pickled by value for the scheduler
                return {str(key): (task.state, [w.address for w in task.who_has or ()])
                        for key, task in dask_scheduler.tasks.items()}

            def every_run_finished():
                tasks = {key: value for key, value in client.run_on_scheduler(states).items()
                         if key.startswith("runs-")}
                return (len(tasks) + len(parts(out)) >= 40
                        and all(state == "memory" for state, _ in tasks.values()) and tasks)
            tasks = wait_for(every_run_finished, "every run finished", 120)
            assert any(workers[0] in holders for _, holders in tasks.values())
            victim.send_signal(signal.SIGSTOP)
            driver.send_signal(signal.SIGCONT)
            wait_for(lambda: any(c.raddr and c.raddr.port == port and c.pid == scheduler.pid
                                 for c in psutil.net_connections("tcp")),
                     "the scheduler fetching rows from worker A", 60)
            victim.send_signal(signal.SIGKILL)
            victim.wait(timeout=10)
            _, stderr = driver.communicate(timeout=120)
        finally:
            driver.send_signal(signal.SIGCONT)
            stop(driver)
    assert driver.returncode == 0, stderr
    assert stderr == "", stderr
    rows = table(out)
    assert [row["run"] for row in rows] == list(range(40))
    assert {row["status"] for row in rows} == {"ok"}


def test_a_lost_scheduler_is_one_line_and_keeps_the_rows(many_spec, tmp_path):
    out = tmp_path / "out"
    with dask_cluster([{}]) as (address, scheduler, _, _):
        driver, stderr = act_on_first_run(
            [executable("sweep"), str(many_spec), "--out", str(out), "--scheduler", address,
             "--connect-timeout", "2"], out, lambda _: scheduler.send_signal(signal.SIGKILL))
    assert driver.returncode == 2, stderr
    line = assert_one_line(stderr, "sweep: error: --scheduler: lost the scheduler (")
    assert len(pq.read_table(out / "runs.parquet")) == rows_said(line) > 0
