"""`colcon build` of the package, as on a ROS 2 Jazzy install, and the built executables run."""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from executables import executable

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """A colcon workspace with this package in src/, built once for the module."""
    root = tmp_path_factory.mktemp("ws")
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=REPO,
                           capture_output=True, text=True, check=True).stdout.split("\n")
    for name in filter(None, files):
        source = REPO / name
        target = root / "src" / "mobile_manip_sim" / name
        target.parent.mkdir(parents=True, exist_ok=True)
        if source.is_symlink():  # mobile_manip_sim/config → ../config: the package's scenes
            target.symlink_to(os.readlink(source))
        elif source.is_file():
            shutil.copy2(source, target)
    colcon = executable("colcon")
    result = subprocess.run([colcon, "build", "--event-handlers", "console_direct-"], cwd=root,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    return root


def run_built(workspace, command, **kwargs):
    """Run a command the way a user does after `. install/setup.sh`."""
    script = f". install/setup.sh && {command}"
    env = dict(os.environ, PATH=f"{BIN}:{os.environ['PATH']}")
    return subprocess.run(["bash", "-c", script], cwd=workspace, env=env, capture_output=True,
                          text=True, timeout=300, **kwargs)


def test_colcon_build_installs_every_executable_under_lib(workspace):
    lib = workspace / "install" / "mobile_manip_sim" / "lib" / "mobile_manip_sim"
    for exe in ("simulate", "describe"):
        assert (lib / exe).is_file() and os.access(lib / exe, os.X_OK), exe
    share = workspace / "install" / "mobile_manip_sim" / "share" / "mobile_manip_sim"
    assert (share / "package.xml").is_file()
    assert (share / "config" / "paper_two_link.yaml").is_file()
    assert (workspace / "install" / "share" / "ament_index" / "resource_index" / "packages"
            / "mobile_manip_sim").exists() or (share.parent / "ament_index" / "resource_index"
                                               / "packages" / "mobile_manip_sim").exists()


def test_built_simulate_runs_the_embedded_default_scene(workspace):
    result = run_built(workspace, "install/mobile_manip_sim/lib/mobile_manip_sim/simulate "
                                  "--duration 0.05 --out built.csv")
    assert result.returncode == 0, result.stderr
    assert "simulated 0.05 s" in result.stdout
    header, *rows = (workspace / "built.csv").read_text().splitlines()
    assert header.startswith("t,x,y,yaw,theta_R,theta_L,q1,l1,q2,l2,v,omega")
    assert len(rows) == 6
