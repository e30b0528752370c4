"""ament_python package: `colcon build` on a ROS 2 Jazzy install, or plain `pip install .`.

Either way the compiled core (mobile_manip_sim/core: C++ templates and their nanobind bindings)
is built here, by CMake, through setuptools' build_ext: one build glue for pip and colcon.
"""
import hashlib
import os
import re
import shutil
import subprocess
import sys
from glob import glob
from pathlib import Path

from setuptools import Extension, find_packages, setup
from setuptools.command.build_ext import build_ext

package_name = "mobile_manip_sim"
ROOT = Path(__file__).resolve().parent
CORE = ROOT / package_name / "core"
MINIMUM_CMAKE = (3, 18)


class CMakeExtension(Extension):
    """An extension module built by CMake from a source directory (no sources of its own)."""

    def __init__(self, name: str, source_dir: Path):
        super().__init__(name, sources=[])
        self.source_dir = source_dir


def _fail(message: str):
    """One line saying what is missing, then stop the build."""
    sys.stderr.write(f"mobile_manip_sim: {message}\n")
    raise SystemExit(1)


def _cmake() -> str:
    """The cmake to use (PyPI's, where installed, else PATH's), at least MINIMUM_CMAKE."""
    try:
        import cmake  # PyPI's cmake: the binary in its own bin/
        found = str(Path(cmake.CMAKE_BIN_DIR) / "cmake")
    except (ImportError, AttributeError):
        found = shutil.which("cmake")
    if not found:
        _fail("building the compiled core needs CMake >= 3.18: pip install cmake (or apt "
              "install cmake)")
    text = subprocess.run([found, "--version"], capture_output=True, text=True).stdout
    version = tuple(int(part) for part in re.findall(r"(\d+)\.(\d+)", text)[0])
    if version < MINIMUM_CMAKE:
        _fail(f"building the compiled core needs CMake >= 3.18, found {found} "
              f"{'.'.join(map(str, version))}: pip install cmake")
    return found


class CMakeBuild(build_ext):
    """Configure and build each CMakeExtension in a build directory kept between builds (an edit
    of one source rebuilds only what depends on it), then copy the module where setuptools
    expects it."""

    def build_extension(self, ext):
        if not isinstance(ext, CMakeExtension):
            return super().build_extension(ext)
        compiler = os.environ.get("CXX", "c++")
        if not shutil.which(compiler):
            _fail(f"building the compiled core needs a C++20 compiler ({compiler} not found): "
                  f"apt install g++ (or set CXX)")
        cmake = _cmake()
        try:
            import nanobind  # noqa: F401
        except ImportError:
            _fail("building the compiled core needs nanobind: pip install nanobind")
        # one build directory per set of tools: a CMake cache names its cmake and ninja, and pip's
        # isolated builds bring their own in a temporary directory (a second `pip install .`
        # reused the first one's cache and failed: its ninja was gone)
        tools = "\0".join([sys.executable, cmake, shutil.which("ninja") or ""])
        tag = hashlib.sha1(tools.encode()).hexdigest()[:8]
        build_dir = Path(self.build_temp).resolve() / f"core-{tag}"
        build_dir.mkdir(parents=True, exist_ok=True)
        configure = [cmake, str(ext.source_dir), f"-DPython_EXECUTABLE={sys.executable}",
                     "-DCMAKE_BUILD_TYPE=Release"]
        if shutil.which("ninja") and not (build_dir / "CMakeCache.txt").exists():
            configure += ["-G", "Ninja"]
        print(f"mobile_manip_sim: building the compiled core in {build_dir}", flush=True)
        for command in (configure, [cmake, "--build", str(build_dir), "--parallel"]):
            result = subprocess.run(command, cwd=build_dir)
            if result.returncode != 0:
                _fail(f"building the compiled core failed ({' '.join(command[:2])}…): see the "
                      f"compiler's messages above")
        built = next(build_dir.glob("_core*.so"), None) or next(build_dir.glob("_core*.pyd"))
        target = Path(self.get_ext_fullpath(ext.name))
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(built, target)

setup(
    name=package_name,
    version="0.1.0",
    # config/ (the scenes, the params file, sweep specs) as packages of data, so that setuptools
    # installs it without its ~45-line warning about importable directories left out of `packages`
    packages=find_packages(exclude=["test", "test.*"]) + [
        f"{package_name}.config", f"{package_name}.config.sweeps"],
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml") + glob("config/*.json")),
    ],
    package_data={f"{package_name}.config": ["*.yaml", "*.json"],
                  f"{package_name}.config.sweeps": ["*.yaml"]},
    include_package_data=True,
    ext_modules=[CMakeExtension(f"{package_name}.core._core", CORE)],
    cmdclass={"build_ext": CMakeBuild},
    python_requires=">=3.10",
    install_requires=[
        "setuptools", "numpy", "scipy", "pyyaml", "mcap", "zstandard", "matplotlib",
        "dask[distributed]", "pyarrow", "foxglove-sdk",
        # the browser view: a three.js page served with its client, scripts and assets
        "viser",
        # ROS 2 Jazzy from PyPI wheels; on a ROS install these are already there (colcon does
        # not pip-install them).
        "ros-jazzy-rclpy", "ros-jazzy-common-interfaces", "ros-jazzy-rosgraph-msgs",
        "ros-jazzy-std-srvs", "ros-jazzy-rmw-fastrtps-cpp",
    ],
    extras_require={"test": [
        "pytest", "pin", "mujoco", "rosbags", "mcap-ros2-support", "ros-jazzy-ament-package",
        "colcon-core", "colcon-ros", "colcon-python-setup-py", "colcon-package-information",
        "colcon-package-selection", "hypothesis", "ruff", "pytest-xdist",
        # what `colcon build` needs to build the compiled core (pip gets them from
        # pyproject.toml's build requirements in its own isolated build environment)
        "nanobind", "cmake", "ninja",
        # the browser view's tests drive chromium over its DevTools websocket, read screenshots
        "websockets", "pillow",
    ]},
    zip_safe=False,
    maintainer="mobile_manip_sim developers",
    maintainer_email="dev@example.invalid",
    description="Nonholonomic mobile manipulator with R-P arm joints: recursive Gibbs–Appell "
                "dynamics, ROS 2 simulator node, MCAP recording and replay.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "simulate = mobile_manip_sim.programs.simulate:main",
            "describe = mobile_manip_sim.programs.describe:main",
            "bench = mobile_manip_sim.bench.main:main",
            "plot = mobile_manip_sim.plot.cli:main",
            "simulator = mobile_manip_sim.node:main",
            "replay = mobile_manip_sim.replay.cli:main",
            "sweep = mobile_manip_sim.sweep.cli:main",
        ],
    },
)
