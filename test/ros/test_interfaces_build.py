"""tools/build_interfaces.sh: tf2_msgs and control_msgs built from the definitions the project
carries (tools/interfaces/), imported in a child process through the two exports the script
prints, and the script's one-line refusal of a package it has no definitions of."""
import subprocess
import sys

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


def test_the_exports_it_prints_make_both_packages_import(interfaces_prefix):
    exports = (interfaces_prefix.parent / interfaces_build.EXPORTS).read_text().splitlines()
    assert [line.split("=")[0] for line in exports] == ["export PYTHONPATH",
                                                        "export LD_LIBRARY_PATH"]
    script = "\n".join(exports) + f"\nexec {sys.executable} -c \"$CHECK\""
    result = subprocess.run(["bash", "-c", script], capture_output=True, text=True, timeout=120,
                            env={"PATH": "/usr/bin:/bin", "CHECK": CHECK})
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


def test_the_built_definitions_are_the_carried_ones(interfaces_prefix):
    for package in interfaces_build.PACKAGES:
        carried = interfaces_build.DEFINITIONS / package
        files = [p for p in carried.rglob("*") if p.suffix in (".msg", ".action")]
        assert files
        for path in files:
            built = interfaces_prefix / "share" / package / path.relative_to(carried)
            assert built.read_bytes() == path.read_bytes(), path


def test_a_package_without_definitions_is_one_line_and_status_2(tmp_path):
    result = subprocess.run(["bash", str(interfaces_build.SCRIPT), str(tmp_path), "tf2_msgs",
                             "nav2_msgs"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.splitlines() == [
        "build_interfaces.sh: no definitions of 'nav2_msgs' in tools/interfaces (there are: "
        "control_msgs tf2_msgs)"]
    assert not (tmp_path / "venv").exists()   # refused before anything was installed
