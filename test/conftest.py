"""What the test modules share: the import path (test/helpers/, the helper modules in one place
for all folders, then the test folders), and session fixtures (ros_harness.py holds the ROS
harness itself; waiting.py the one `wait_for`).

Where a file goes: a test of a module of ``mobile_manip_sim/<folder>/`` in ``test/<folder>/``;
facts about the repository as a whole in ``test/package/`` (packaging, colcon, the layer and
owner checks), ``test/docs/`` (every docs block run) and ``test/fuzz/``; anything that is not a
``test_*.py`` (helper modules, scripts run as processes, the Node.js client) in ``test/helpers/``.
Test file names stay unique across folders (the folders have no ``__init__.py``)."""
import os
import sys
from pathlib import Path

import pytest

TEST = Path(__file__).resolve().parent
# helpers first; then every folder, so a test module imports another's shared pieces by name
# (pytest's default import mode already needs test module names unique across folders)
sys.path[:0] = [str(TEST / "helpers")] + sorted(
    str(p) for p in TEST.iterdir() if p.is_dir() and p.name not in ("helpers", "__pycache__"))


def pytest_xdist_auto_num_workers(config):
    """`-n auto` (pytest.ini): one worker per core, at most four. Each test file runs whole in
    one worker (--dist loadfile), so a module's fixtures are built once; ROS tests pick a random
    domain per module (ros_harness.py), so workers' nodes never hear each other."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(cores or 1, 4))


@pytest.fixture(scope="session")
def interfaces_prefix():
    """tf2_msgs and control_msgs, built into the venv by tools/bootstrap.sh: checked to import
    in a fresh process (interfaces_build.py); the venv's prefix, where they are installed."""
    import interfaces_build
    return interfaces_build.installed()
