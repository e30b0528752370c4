"""tools/build_interfaces.sh, as tools/bootstrap.sh runs it: tf2_msgs and control_msgs built from
the definitions the project carries (tools/interfaces/) into a fresh venv of their own, imported
by a fresh process of that venv's Python with nothing set; a second run that builds nothing and
says so; a build that fails, in one line naming the package and the step; the script's one-line
refusals. And the packages the suite itself uses, in its own venv, are the carried ones."""
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import interfaces_build

CHECK = r"""
from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointTolerance, JointTrajectoryControllerState
from tf2_msgs.msg import TFMessage
result = FollowJointTrajectory.Result
print(result.SUCCESSFUL, result.INVALID_GOAL, result.INVALID_JOINTS, result.OLD_HEADER_TIMESTAMP,
      result.PATH_TOLERANCE_VIOLATED, result.GOAL_TOLERANCE_VIOLATED)
print(sorted(FollowJointTrajectory.Feedback.get_fields_and_field_types()))
print(sorted(JointTrajectoryControllerState.get_fields_and_field_types())[:4])
print(JointTolerance.get_fields_and_field_types(), TFMessage.get_fields_and_field_types())
"""
BARE = {"PATH": "/usr/bin:/bin"}   # no PYTHONPATH, no LD_LIBRARY_PATH, nothing sourced
BUILD_TIMEOUT = 1800   # a hang guard: a few minutes of pip and compiler on a loaded machine


def run(venv: Path, *packages: str, script: Path = interfaces_build.SCRIPT):
    return subprocess.run(["bash", str(script), str(venv), *packages], capture_output=True,
                          text=True, timeout=BUILD_TIMEOUT)


@pytest.fixture(scope="module")
def fresh(tmp_path_factory):
    """A venv with nothing installed, then the script's first run on it: (venv, result)."""
    venv = tmp_path_factory.mktemp("fresh") / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    return venv, run(venv, *interfaces_build.PACKAGES)


def installed_files(venv: Path) -> dict:
    """Every file the build installed in ``venv`` (its own list), with its modification time."""
    names = (venv / "ros_interfaces" / "installed").read_text().split()
    return {name: (venv / name).stat().st_mtime_ns for name in names}


def test_a_fresh_venv_gets_both_packages_saying_each_step(fresh):
    venv, result = fresh
    assert result.returncode == 0, result.stdout + result.stderr
    steps = [line for line in result.stdout.splitlines() if " still " not in line]
    assert steps == [
        f"build_interfaces.sh: installing the build tools (rosidl generators, ament_cmake, CMake, "
        f"ninja) from PyPI into {venv}",
        "build_interfaces.sh: configuring tf2_msgs control_msgs (CMake)",
        "build_interfaces.sh: generating and compiling tf2_msgs control_msgs",
        f"build_interfaces.sh: installing tf2_msgs control_msgs into {venv}",
        steps[-1]]
    assert re.fullmatch(rf"build_interfaces.sh: built tf2_msgs control_msgs into {venv} in \d+ s",
                        steps[-1]), steps[-1]
    assert result.stderr == ""


def test_a_fresh_process_of_that_venvs_python_imports_both_with_nothing_set(fresh):
    venv, _ = fresh
    result = subprocess.run([str(venv / "bin" / "python"), "-c", CHECK], capture_output=True,
                            text=True, timeout=120, env=BARE)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == "0 -1 -2 -3 -4 -5"   # control_msgs' jazzy Result codes
    assert lines[1] == "['actual', 'desired', 'error', 'header', 'joint_names', " \
                       "'multi_dof_actual', 'multi_dof_desired', 'multi_dof_error', " \
                       "'multi_dof_joint_names']"
    assert lines[2] == "['error', 'feedback', 'header', 'joint_names']"
    assert lines[3] == ("{'name': 'string', 'position': 'double', 'velocity': 'double', "
                        "'acceleration': 'double'} {'transforms': "
                        "'sequence<geometry_msgs/TransformStamped>'}")


def test_a_second_run_builds_nothing_and_says_so(fresh):
    venv, _ = fresh
    before = installed_files(venv)
    key = (venv / "ros_interfaces" / "key").read_text()
    result = run(venv, *interfaces_build.PACKAGES)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout == (f"build_interfaces.sh: tf2_msgs control_msgs already built into "
                             f"{venv} (nothing changed): nothing to do\n")
    assert installed_files(venv) == before and len(before) > 100
    assert (venv / "ros_interfaces" / "key").read_text() == key


def test_a_build_that_fails_says_which_package_and_step_in_one_line(fresh, tmp_path):
    """A definition CMake's configure refuses, then one that fails at code generation: the last
    line of stderr names the package and the step; what was installed before stays, and
    imports."""
    venv, _ = fresh
    key = (venv / "ros_interfaces" / "key").read_text()
    tools = tmp_path / "tools"   # the script, its CMake project and the definitions, copied
    tools.mkdir()
    for name in ("build_interfaces.sh", "talking.sh"):
        shutil.copy(interfaces_build.SCRIPT.parent / name, tools / name)
    for name in ("build_interfaces", "interfaces"):
        shutil.copytree(interfaces_build.SCRIPT.parent / name, tools / name)
    tolerance = tools / "interfaces" / "control_msgs" / "msg" / "JointTolerance.msg"
    original = tolerance.read_text()
    for extra, step in (("float64 = 1\n", "configuring"),   # a constant without a name
                        ("geometry_msgs/NoSuchThing thing\n", "compiling")):   # no such type
        tolerance.write_text(original + extra)
        result = run(venv, *interfaces_build.PACKAGES, script=tools / "build_interfaces.sh")
        assert result.returncode == 1, result.stdout + result.stderr
        last = result.stderr.splitlines()[-1]
        assert last == (f"build_interfaces.sh: control_msgs: {step} failed (the lines above end "
                        f"{venv}/ros_interfaces/build.log)"), result.stderr
        assert all(line.startswith("    ") for line in result.stderr.splitlines()[:-1])
    assert (venv / "ros_interfaces" / "key").read_text() == key
    imported = subprocess.run([str(venv / "bin" / "python"), "-c", CHECK], capture_output=True,
                              text=True, timeout=120, env=BARE)
    assert imported.returncode == 0, imported.stderr


@pytest.mark.parametrize("venv", ["fresh", "suite"])
def test_the_built_definitions_are_the_carried_ones(venv, fresh, interfaces_prefix):
    """In the fresh venv above and in the venv the suite runs on (the node tests' packages)."""
    prefix = fresh[0] if venv == "fresh" else interfaces_prefix
    for package in interfaces_build.PACKAGES:
        carried = interfaces_build.DEFINITIONS / package
        files = [p for p in carried.rglob("*") if p.suffix in (".msg", ".action")]
        assert files
        for path in files:
            built = prefix / "share" / package / path.relative_to(carried)
            assert built.read_bytes() == path.read_bytes(), path


def test_a_package_without_definitions_or_a_folder_that_is_no_venv_is_one_line_and_status_2(
        tmp_path):
    for arguments, message in (
            ([str(tmp_path), "tf2_msgs", "nav2_msgs"],
             "build_interfaces.sh: no definitions of 'nav2_msgs' in tools/interfaces (there are: "
             "control_msgs tf2_msgs)"),
            ([str(tmp_path), "tf2_msgs"],
             f"build_interfaces.sh: {tmp_path} is not a venv (no bin/python): tools/bootstrap.sh "
             f"makes one"),
            ([str(tmp_path)],
             "usage: tools/build_interfaces.sh VENV PACKAGE...  (packages: tools/interfaces/*)")):
        result = subprocess.run(["bash", str(interfaces_build.SCRIPT), *arguments],
                                capture_output=True, text=True, timeout=60)
        assert result.returncode == 2 and result.stdout == ""
        assert result.stderr.splitlines() == [message]
    assert os.listdir(tmp_path) == []   # refused before anything was written

