"""`colcon build` of the package, as on a ROS 2 Jazzy install, and the built executables run."""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from executables import executable

REPO = Path(__file__).resolve().parents[2]
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
    result = subprocess.run([colcon, "build"], cwd=root,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    (root / "build_output.txt").write_text(result.stdout + result.stderr)
    return root


def run_built(workspace, command, **kwargs):
    """Run a command the way a user does after `. install/setup.sh`."""
    script = f". install/setup.sh && {command}"
    env = dict(os.environ, PATH=f"{BIN}:{os.environ['PATH']}")
    return subprocess.run(["bash", "-c", script], cwd=workspace, env=env, capture_output=True,
                          text=True, timeout=600, **kwargs)


def test_colcon_build_installs_every_executable_under_lib(workspace):
    lib = workspace / "install" / "mobile_manip_sim" / "lib" / "mobile_manip_sim"
    for exe in ("simulate", "describe", "simulator", "replay", "plot", "sweep", "bench"):
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


def test_built_simulator_starts_publishes_and_stops_cleanly(workspace):
    """The built node comes up (its first /clock reaches a subscriber) and exits 0 on SIGINT
    (the wait is a hang guard, not a timing)."""
    import signal

    from ros_harness import private_domain
    domain = str(private_domain(200, 229))
    env = dict(os.environ, PATH=f"{BIN}:{os.environ['PATH']}", ROS_DOMAIN_ID=domain,
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    node = subprocess.Popen(["bash", "-c",
                             ". install/setup.sh && exec install/mobile_manip_sim/lib/"
                             "mobile_manip_sim/simulator --ros-args -p real_time_factor:=2.0"],
                            cwd=workspace, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE,
                            text=True)
    listener = ("import rclpy, sys\n"
                "from rosgraph_msgs.msg import Clock\n"
                "rclpy.init(); n = rclpy.create_node('listener'); got = []\n"
                "n.create_subscription(Clock, '/clock', got.append, 10)\n"
                "import time; end = time.time() + 600\n"
                "while not got and time.time() < end: rclpy.spin_once(n, timeout_sec=0.2)\n"
                "sys.exit(0 if got else 1)\n")
    try:
        heard = subprocess.run([sys.executable, "-c", listener], env=env, timeout=660)
        assert heard.returncode == 0, "no /clock from the built simulator"
    finally:
        node.send_signal(signal.SIGINT)
        try:
            _, err = node.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            node.kill()
            _, err = node.communicate()
    assert node.returncode == 0, err
    assert "Traceback" not in err


def test_colcon_build_prints_no_setuptools_warning_wall(workspace):
    """config/ is declared as packages of data: setuptools' ~45-line deprecation warning about
    'mobile_manip_sim.config' installed as data no longer greets every build."""
    output = (workspace / "build_output.txt").read_text()   # colcon shows each package's stderr
    assert "Finished <<< mobile_manip_sim" in output, output[:2000]
    assert "SetuptoolsDeprecationWarning" not in output and "as data is deprecated" not in output
