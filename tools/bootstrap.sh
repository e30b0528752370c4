#!/usr/bin/env bash
# Create .venv beside this repository and install the package with everything its tests need,
# all from PyPI (ROS 2 Jazzy's rclpy and message packages come as wheels). Safe to run again.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x .venv/bin/python ]; then
  python3 -m venv .venv
fi
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet -e '.[test]'
# Compile every numba kernel now (about a minute), so that no run — the node above all —
# compiles at run time.
.venv/bin/python -m mobile_manip_sim.warmup
