"""The real `simulate` executable when things go wrong: special files, full disks,
work beyond the limits, signals — always one line (status 2) or a prompt, clean stop, never a
traceback, a hang or a half-written file. Bags are read back with rosbags (an independent reader).
"""
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from rosbags.rosbag2 import Reader as RosbagsReader

from executables import executable
from hostile_yaml import ALIAS_BOMB
from waiting import wait_for

SIMULATE = executable("simulate")
CONFIG = Path(__file__).resolve().parents[2] / "config"
LONG_RUN = ["--method", "rk4", "--dt", "1e-4", "--duration", "1000", "--sample-rate", "100"]


def simulate(*args, timeout=60, cwd=None):
    return subprocess.run([SIMULATE, *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd)


def assert_one_line(result, key):
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    assert f"error: {key}" in lines[0], lines[0]


@pytest.mark.parametrize("flags, key", [
    (["--duration", "1e308"], "--duration"), (["--duration", "1e9"], "--duration"),
    (["--sample-rate", "1e9"], "--sample-rate"), (["--duration", "1e5", "--sample-rate", "1e3"],
                                                  "--sample-rate"),
    (["--method", "rk4", "--dt", "1e-12"], "--dt"), (["--method", "rk4", "--dt", "1e-300"], "--dt"),
    (["--method", "rk4", "--dt", "1e308"], "--dt"), (["--method", "rk4", "--dt", "0.05"], "--dt"),
    (["--method", "rk4", "--dt", "1e-8", "--duration", "1"], "--dt"),
    (["--rtol", "1e-300"], "--rtol"), (["--sample-rate", "nan"], "--sample-rate"),
    (["--record", ""], "simulate: argument --record: an empty path"),
    (["--scene", ""], "simulate: argument --scene: an empty path"),
], ids=lambda value: " ".join(value) if isinstance(value, list) else value)
def test_work_beyond_the_limits_is_one_line_naming_the_flag_at_once(tmp_path, flags, key):
    result = simulate("--out", tmp_path / "run.csv", *flags, timeout=30)   # at once: no work
    assert_one_line(result, key)
    assert not (tmp_path / "run.csv").exists()


def test_special_files_as_a_scene_are_one_line_without_reading(tmp_path):
    fifo = tmp_path / "scene.yaml"
    os.mkfifo(fifo)
    for scene in ("/dev/zero", fifo, tmp_path):
        result = simulate("--scene", scene, "--out", tmp_path / "run.csv", timeout=30)
        assert_one_line(result, str(scene))
        assert "not a regular file" in result.stderr


def test_the_alias_bomb_scene_is_refused_fast(tmp_path):
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text(ALIAS_BOMB)
    assert bomb.stat().st_size < 600
    result = simulate("--scene", bomb, "--out", tmp_path / "run.csv", timeout=30)
    assert_one_line(result, "bomb")


def test_dev_full_is_one_line():
    result = simulate("--out", "/dev/full", "--duration", "0.2")
    assert_one_line(result, "/dev/full")
    assert "No space left" in result.stderr


def test_a_failed_out_leaves_the_recorded_bag_closed_and_whole(tmp_path):
    """The CSV fails (/dev/full), the bag beside it is closed, not left half-written: its summary
    and metadata.yaml are there and it re-simulates bit for bit up to the failure."""
    result = simulate("--out", "/dev/full", "--duration", "0.2", "--record", tmp_path / "bag")
    assert_one_line(result, "/dev/full")
    assert (tmp_path / "bag" / "metadata.yaml").is_file()
    replayed = subprocess.run([executable("replay"), str(tmp_path / "bag"), "--resimulate"],
                              capture_output=True, text=True, timeout=120)
    assert replayed.returncode == 0 and "IDENTICAL" in replayed.stdout, (replayed.stdout
                                                                         + replayed.stderr)
    assert "no summary" not in replayed.stderr


def test_dev_null_gets_no_impacts_file_beside_it_and_rows_end_in_lf(tmp_path):
    scene = CONFIG / "hard_impacts.yaml"
    result = simulate("--scene", scene, "--out", "/dev/null", "--duration", "0.5")
    assert result.returncode == 0, result.stderr
    assert "0 impacts" not in result.stdout  # the run did have impacts …
    assert not Path("/dev/null.impacts.csv").exists()  # … and wrote them nowhere
    out = tmp_path / "run.csv"
    assert simulate("--scene", scene, "--out", out, "--duration", "0.5").returncode == 0
    for path in (out, out.with_suffix(".impacts.csv")):
        data = path.read_bytes()
        assert b"\r" not in data and data.count(b"\n") >= 2


@pytest.mark.skipif(shutil.which("unshare") is None or os.geteuid() != 0,
                    reason="needs root and unshare for a private tmpfs")
def test_a_full_disk_is_one_line_and_leaves_no_partial_csv(tmp_path):
    disk = tmp_path / "disk"
    disk.mkdir()
    script = (f"mount -t tmpfs -o size=64k tmpfs {disk} && "
              f"{SIMULATE} --out {disk}/run.csv --duration 20 --sample-rate 1000; "
              f"echo status=$?; ls {disk}")
    result = subprocess.run(["unshare", "-m", "sh", "-c", script], capture_output=True,
                            text=True, timeout=120)
    assert "status=2" in result.stdout, (result.stdout, result.stderr)
    assert "run.csv" not in result.stdout.split("status=2")[1]
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "No space left on device" in lines[0], result.stderr


def _started(tmp_path, *extra):
    process = subprocess.Popen([SIMULATE, "--out", str(tmp_path / "run.csv"), *LONG_RUN, *extra],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    csv = tmp_path / "run.csv"
    wait_for(lambda: process.poll() is not None or (csv.exists() and csv.stat().st_size >= 20_000),
             "the run to write 20 kB of rows", 60.0)
    assert process.poll() is None, process.communicate()
    return process


@pytest.mark.parametrize("sig, status, method",
                         [(signal.SIGINT, 130, []), (signal.SIGTERM, 143, []),
                          (signal.SIGINT, 130, ["--method", "radau"])])
def test_a_signal_stops_promptly_and_closes_the_bag(tmp_path, sig, status, method):
    process = _started(tmp_path, "--record", tmp_path / "bag", *method)
    process.send_signal(sig)
    _, stderr = process.communicate(timeout=30)   # a net: a stop that hangs fails here
    assert process.returncode == status, stderr
    assert "Traceback" not in stderr
    rows = (tmp_path / "run.csv").read_text().splitlines()
    assert len(rows) > 10 and rows[-1].count(",") == rows[0].count(",")  # whole rows only
    assert (tmp_path / "bag" / "metadata.yaml").is_file()
    with RosbagsReader(tmp_path / "bag") as reader:
        assert reader.message_count > 10
        assert sum(1 for _ in reader.messages()) == reader.message_count


def test_real_time_factor_leaves_out_start_up(tmp_path):
    result = simulate("--out", tmp_path / "run.csv", "--duration", "0.3")
    assert result.returncode == 0, result.stderr
    wall = float(result.stdout.split(" s in ")[1].split(" s wall")[0])
    rtf = float(result.stdout.split("real-time factor ")[1].split(")")[0])
    # the first sample interval (compiling) is left out
    assert rtf * wall < 0.3 - 0.005, result.stdout


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("unshare") is None or os.geteuid() != 0,
                    reason="needs root and unshare for a read-only bind mount")
def test_a_read_only_install_runs_with_a_warning_at_most(tmp_path):
    package = Path(__file__).resolve().parents[2] / "mobile_manip_sim"
    root = tmp_path / "ro"
    shutil.copytree(package, root / "mobile_manip_sim", symlinks=False,
                    ignore=shutil.ignore_patterns("__pycache__"))
    (root / "home").mkdir()
    script = (f"mount -o bind,ro {root} {root} && cd {root} && HOME={root}/home "
              f"XDG_CACHE_HOME={root}/home/.cache PYTHONDONTWRITEBYTECODE=1 PYTHONPATH={root} "
              f"{sys.executable} -m mobile_manip_sim.programs.simulate "
              "--out /dev/null --duration 0.1")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    result = subprocess.run(["unshare", "-m", "sh", "-c", script], capture_output=True, text=True,
                            timeout=600, env=env)
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    assert "simulated 0.1 s" in result.stdout
