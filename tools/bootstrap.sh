#!/usr/bin/env bash
# Create .venv beside this repository and install the package with everything its tests need,
# all from PyPI (ROS 2 Jazzy's rclpy and message packages come as wheels). Safe to run again.
# It says what it does before each phase, and never stays silent for more than 10 s.
set -euo pipefail
cd "$(dirname "$0")/.."

# talking WHAT COMMAND...: a line every 10 s while COMMAND is silent (tools/talking.sh)
. tools/talking.sh
TALKING_AS=bootstrap

if [ ! -x .venv/bin/python ]; then
  echo "bootstrap: creating .venv"
  talking "creating .venv" python3 -m venv .venv
fi
echo "bootstrap: upgrading pip"
talking "upgrading pip" .venv/bin/python -m pip install --quiet --upgrade pip
echo "bootstrap: installing the package and its test dependencies, and building its compiled C++ core (a few minutes the first time)"
# --no-compile: no byte-compiling of every installed module up front (tens of seconds); Python
# writes the .pyc of what it imports on first use.
talking "installing" .venv/bin/python -m pip install --quiet --no-compile -e '.[test]'
# tf2_msgs (/tf) and control_msgs (the arm's trajectory action) have no PyPI wheels: built from
# the definitions in tools/interfaces/ into .venv, beside the ROS 2 wheels (nothing to source).
# A second run finds them built and says so. If the build fails, the set-up goes on: the node
# runs without /tf and the trajectory action, and says so when it starts.
echo "bootstrap: building tf2_msgs and control_msgs into .venv (PyPI has no wheels of them)"
interfaces=built
bash tools/build_interfaces.sh .venv tf2_msgs control_msgs || {
  status=$?
  if ((status > 128)); then exit "$status"; fi   # stopped (Ctrl-C), not failed
  interfaces=failed
}
if [ "$interfaces" = built ]; then
  echo "bootstrap: done"
else
  echo "bootstrap: done, without tf2_msgs and control_msgs (their build failed: the lines above" \
    "say where): the node runs without /tf and the trajectory action"
fi
