#!/usr/bin/env bash
# Create .venv beside this repository and install the package with everything its tests need,
# all from PyPI (ROS 2 Jazzy's rclpy and message packages come as wheels). Safe to run again.
# It says what it does before each phase, and never stays silent for more than 10 s.
set -euo pipefail
cd "$(dirname "$0")/.."

# talking WHAT COMMAND...: run COMMAND, saying "still WHAT" every 10 s while it runs
# (`pip install --quiet` prints nothing for minutes). Ctrl-C stops it too.
talking() {
  local what=$1 waited=0 pid
  shift
  "$@" &
  pid=$!
  trap 'kill "$pid" 2>/dev/null; exit 130' INT TERM
  while kill -0 "$pid" 2>/dev/null; do
    sleep 1
    waited=$((waited + 1))
    if ((waited % 10 == 0)) && kill -0 "$pid" 2>/dev/null; then
      echo "bootstrap: still $what ($waited s)"
    fi
  done
  trap - INT TERM
  wait "$pid"
}

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
# Compile every numba kernel now, so that no run — the node above all — compiles at run time;
# the warm-up says how long it takes and names each kernel as it starts.
echo "bootstrap: compiling the numba kernels"
.venv/bin/python -m mobile_manip_sim.programs.warmup
echo "bootstrap: done"
