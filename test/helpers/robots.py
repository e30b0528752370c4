"""Random robots and states for the tests: the one generator, reproducible from a numpy Generator.

`random_robot_document` is a scene document (validated by `parse_scene` like any scene file, so
the format is exercised too): a random base (mass, yaw inertia, centre-of-mass offset, wheel
radius, half track, wheel inertia), a random mount and n links with any joint rotation, length,
mass per length, a full cross-section inertia and a stroke; the initial state inside the strokes
and moving; no efforts. `random_robot` is its model. `random_configuration` / `random_state`
place the base anywhere near the origin, every angle anywhere, and each extension inside its
stroke or, with ``beyond``, up to that fraction of the rod's length past either end.

(The bench has its own generator, `mobile_manip_sim.bench.scenes.random_robot_document`: the
benchmark's fixed robots, with a fixed base geometry and MuJoCo-valid inertias.)
"""
from __future__ import annotations

import numpy as np

from mobile_manip_sim.scene.coordinates import (
    SLIDES_Q,
    TURNS_Q,
    WHEEL_L,
    WHEEL_R,
    YAW,
    X,
    Y,
    u_size,
)
from mobile_manip_sim.scene.loading import parse_scene
from mobile_manip_sim.scene.model import RobotModel


def random_inertia(rng, scale: float) -> np.ndarray:
    """A symmetric positive definite 3×3 of order scale² (a cross-section inertia, kg·m)."""
    A = rng.normal(size=(3, 3)) * scale
    return A @ A.T + scale ** 2 * rng.uniform(0.1, 1.0) * np.eye(3)


def random_robot_document(rng, n: int, gravity: float = 10.0) -> dict:
    """A scene document of a random robot with n links (see the module docstring)."""
    base = {"mass": rng.uniform(1.0, 20.0), "yaw_inertia": rng.uniform(0.01, 1.0),
            "com_offset": rng.uniform(-0.3, 0.3), "wheel_radius": rng.uniform(0.03, 0.2),
            "half_track": rng.uniform(0.1, 0.4), "wheel_inertia": rng.uniform(1e-4, 1e-2)}
    links = []
    for _ in range(n):
        length = float(rng.uniform(0.2, 2.0))
        links.append({"length": length, "mass_per_length": float(rng.uniform(0.2, 5.0)),
                      "inertia_per_length": random_inertia(rng, 0.03).tolist(),
                      "joint_rpy": rng.uniform(-np.pi, np.pi, 3).tolist(),
                      "stroke": [float(rng.uniform(0.0, 0.5)) * length, length]})
    joints = [float(value) for link in links
              for value in (rng.uniform(-1.0, 1.0), rng.uniform(*link["stroke"]))]
    return {
        "robot": {"base": {key: float(value) for key, value in base.items()},
                  "arm": {"mount": rng.uniform(-0.3, 0.3, 3).tolist(), "links": links}},
        "initial": {"joints": joints, "velocity": rng.normal(size=u_size(n)).tolist()},
        "effects": {"gravity": gravity, "wheel_inertia": True},
    }


def random_robot(rng, n: int) -> RobotModel:
    """The model of `random_robot_document`."""
    return parse_scene(random_robot_document(rng, n)).robot


def random_configuration(rng, robot: RobotModel, beyond: float = 0.0) -> np.ndarray:
    """q: x, y in [−5, 5] m, yaw, wheel and joint angles in [−π, π], extensions in their strokes
    widened by ``beyond`` × the rod's length at each end."""
    q = np.empty(robot.n_q)
    q[[X, Y]] = rng.uniform(-5.0, 5.0, 2)
    q[[YAW, WHEEL_R, WHEEL_L]] = rng.uniform(-np.pi, np.pi, 3)
    q[TURNS_Q] = rng.uniform(-np.pi, np.pi, robot.n_links)
    low, high = np.asarray(robot.stroke, dtype=float).reshape(-1, 2).T
    margin = beyond * np.asarray(robot.length, dtype=float)
    q[SLIDES_Q] = rng.uniform(low - margin, high + margin)
    return q


def random_state(rng, robot: RobotModel, beyond: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(q, u): `random_configuration` and standard normal pseudo-velocities."""
    return random_configuration(rng, robot, beyond), rng.normal(size=robot.n_u)
