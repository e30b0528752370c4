"""What the bench measures with the compiled core alone: the flops it counts are those of the
kernel it times, the sweep it times is the issue's, and its verdicts say where a target is missed.
(No timing is asserted: speed is measured by `bench`, never in a test.)"""
import math

import numpy as np
import pytest

from mobile_manip_sim.bench import batch, lanes_fd, start
from mobile_manip_sim.bench.scenes import random_robot_document
from mobile_manip_sim.dynamics import Dynamics
from mobile_manip_sim.scene.loading import load_scene, parse_scene
from mobile_manip_sim.sweep.spec import load_spec
from robots import random_state


def robots():
    paper = load_scene()
    yield "paper", paper.robot
    for n in (1, 5):
        yield f"random_{n}", parse_scene(random_robot_document(n, seed=40 + n), f"r{n}").robot


@pytest.mark.parametrize("label, robot", list(robots()), ids=lambda v: v if isinstance(v, str)
                         else "")
def test_the_counted_forward_dynamics_is_the_timed_kernel_bit_for_bit(label, robot):
    """The counting instantiation computes u̇ with the very operations the double kernel does
    (bitwise equal), and one sine and one cosine per angle (the yaw and each joint's turn)."""
    dyn = Dynamics(robot, gravity=9.81, tip_mass=0.3)
    rng = np.random.default_rng(len(label))
    q, u = random_state(rng, robot)
    Q = rng.normal(size=robot.n_u)
    counts, ud = dyn.core.count_forward_dynamics(q, u, Q, 9.81)
    assert np.array_equal(ud, dyn.core.forward_dynamics(q, u, Q, 9.81, np.ones(robot.n_u)))
    assert counts["sin"] == counts["cos"] == robot.n_links + 1
    assert counts["mul"] > 0 and counts["add"] > 0


def test_more_links_count_more_flops_in_proportion():
    """The articulated recursion is O(n): flops per link settle to a constant."""
    flops = []
    for n in (4, 8, 16):
        robot = parse_scene(random_robot_document(n, seed=7), f"r{n}").robot
        counts, _ = Dynamics(robot).core.count_forward_dynamics(
            np.zeros(robot.n_q), np.zeros(robot.n_u), np.zeros(robot.n_u), 0.0)
        flops.append(sum(counts[k] for k in ("add", "sub", "mul", "div")))
    assert flops[2] - flops[1] == 2 * (flops[1] - flops[0])


def test_an_unknown_algorithm_is_refused_by_name():
    robot = load_scene().robot
    core = Dynamics(robot).core
    z = np.zeros(robot.n_u)
    with pytest.raises(ValueError, match="what: expected inverse, .* got cholesky"):
        core.time_dynamics("cholesky", np.zeros(robot.n_q), z, z, 0.0, 10)


def test_the_timed_sweep_is_the_issues():
    """10,000 paper runs, rk4 at 2 ms for 1.5 s, rod 1's mass drawn in [0.8, 1.2] kg/m."""
    import tempfile
    from pathlib import Path
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "sweep.yaml"
        batch.sweep_spec(10_000, path)
        spec = load_spec(path)
        runs = spec.runs()
    assert len(runs) == 10_000 and spec.duration == 1.5
    assert {run["integrator.method"] for run in runs} == {"rk4"}
    assert {run["integrator.dt"] for run in runs} == {0.002}
    masses = np.array([run["robot.arm.links[0].mass_per_length"] for run in runs])
    assert masses.min() >= 0.8 and masses.max() <= 1.2 and len(set(masses)) == 10_000


def test_the_vector_peak_counts_the_builds_lane_width():
    """flops per ns = 12 operations × the lane width a round, over the loop's time."""
    width = lanes_fd.build_info()["lane_width"]
    assert width in (4, 8)
    assert math.isfinite(lanes_fd.peak_flops_per_ns(width, target=0.005))


def verdicts(rows):
    return [row[2].split(" ")[0] for row in rows]


def test_start_verdicts_say_plainly_where_a_target_is_missed():
    T = start.Timing
    slow = {"best": {"floor": T(0.31, 0.3), "import": T(1.9, 1.8), "simulate": T(2.1, 2.0)},
            "first_odom_error": "no /odom within 120 s of the node's start (compiling)"}
    rows = start.rows(slow)
    assert verdicts(rows) == ["**MISS**"] * 3
    assert "missed by 6.3×" in rows[0][2] and "missed by 1.590 s" in rows[1][2]
    assert "no /odom" in rows[2][1]
    fast = {"best": {"floor": T(0.31, 0.3), "import": T(0.12, 0.1), "simulate": T(0.45, 0.4)},
            "first_odom": [T(0.8, 0.5), T(0.7, 0.5)]}
    assert verdicts(start.rows(fast)) == ["**PASS**"] * 3
    # the edge: exactly on the target passes, a hair beyond misses
    edge = {"best": {"floor": T(0.3, 0.3), "import": T(0.3, 0.3), "simulate": T(0.5, 0.4)},
            "first_odom": [T(1.0, 0.5)]}
    assert verdicts(start.rows(edge)) == ["**PASS**"] * 3
    edge["first_odom"] = [T(1.001, 0.5)]
    assert verdicts(start.rows(edge))[2] == "**MISS**"
