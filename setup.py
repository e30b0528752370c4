"""ament_python package: `colcon build` on a ROS 2 Jazzy install, or plain `pip install .`."""
from glob import glob

from setuptools import find_packages, setup

package_name = "mobile_manip_sim"

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
    python_requires=">=3.10",
    install_requires=[
        "setuptools", "numpy", "scipy", "pyyaml", "mcap", "zstandard", "numba", "matplotlib",
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
        # the browser view's tests drive chromium over its DevTools websocket, read screenshots
        "websockets", "pillow",
    ]},
    zip_safe=True,
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
            "warmup = mobile_manip_sim.programs.warmup:main",
        ],
    },
)
