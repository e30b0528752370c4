"""tf2_msgs and control_msgs for the tests. tools/bootstrap.sh builds them into the venv
(tools/build_interfaces.sh, docs/interfaces.md), beside the ROS 2 wheels, where every process of
the venv's Python imports them with nothing to source: a test needs them there (`installed`), or
runs a process that must do without them (`without`)."""
import os
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "tools" / "build_interfaces.sh"
DEFINITIONS = ROOT / "tools" / "interfaces"
PACKAGES = ("tf2_msgs", "control_msgs")
IMPORTS = ("from tf2_msgs.msg import TFMessage; "
           "from control_msgs.action import FollowJointTrajectory")
HIDING = pathlib.Path(__file__).resolve().parent / "without_interfaces"


def installed() -> pathlib.Path:
    """The venv's prefix, where both packages are installed: checked by importing them in a fresh
    process of this Python, else one line saying how to build them."""
    result = subprocess.run([sys.executable, "-c", IMPORTS], capture_output=True, text=True,
                            timeout=120)
    if result.returncode != 0:
        last = (result.stderr.strip().splitlines() or ["?"])[-1]
        raise RuntimeError(f"tf2_msgs and control_msgs do not import in {sys.prefix} ({last}): "
                           f"tools/bootstrap.sh builds them (or tools/build_interfaces.sh "
                           f"{sys.prefix} {' '.join(PACKAGES)})")
    return pathlib.Path(sys.prefix)


def without(env: dict) -> dict:
    """`env` in which tf2_msgs and control_msgs do not import, as on a venv where they were never
    built: first on PYTHONPATH, a folder whose packages of those names raise
    ModuleNotFoundError."""
    return dict(env, PYTHONPATH=os.pathsep.join(filter(None, [str(HIDING),
                                                               env.get("PYTHONPATH", "")])))
