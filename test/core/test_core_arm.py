"""The arm controller on the compiled engine (core/include/mms/arm_control.hpp: the reference, the
PID with its conditional integration and saturation, the gravity and computed-torque
feed-forwards with and without a model error, the sampled update) against the numba kernels it
replaces (engine/arm_control.py, engine/arm_reference.py, engine/sampling.py), bit for bit: every
mode and feed-forward × the five methods × continuous, 100 Hz and 1 kHz, on the paper scene and
on random robots whose rods hit, rest and leave their stops under the controller, with commands
changed mid-run. Compared as test_core_stepping.py compares (every sampled state with its
energy, the clock and its ledger, the counters, the impacts, the rests), plus what the
controller's last evaluation left, the efforts held, and the Python calls that evaluate the
controller between steps (`arm_reference`, `joint_efforts_applied`).
"""
import numpy as np
import pytest

import robots
from engine_cases import paper_doc
from mobile_manip_sim.scene.arm_controller import ArmController, ModelError
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.loading import parse_scene
from test_core_stepping import METHODS, assert_identical, event_counts, outcome

RATES = [0.0, 100.0, 1000.0]
ERROR = ModelError(mass=0.2, inertia=-0.1, payload=0.3)
# (mode, feed-forward, model error): each mode once, then every feed-forward on a trajectory
CONTROLLERS = [("position", "gravity", None), ("velocity", "computed_torque", ERROR),
               ("joint_trajectory", "none", None), ("joint_trajectory", "gravity", None),
               ("joint_trajectory", "computed_torque", None),
               ("joint_trajectory", "gravity", ERROR),
               ("joint_trajectory", "computed_torque", ERROR)]
IDS = [f"{mode}-{ff}" + ("-error" if error else "") for mode, ff, error in CONTROLLERS]


def controller(mode, feedforward, error, gains=None):
    return ArmController(mode, feedforward=feedforward, model_error=error or ModelError(),
                         **(gains or {}))


def command(mode: str, n_arm: int, rng, scale: float = 1.0):
    """A command of `mode` for an arm of n_arm joints: targets within ±`scale` rad on the
    revolute joints, on the rods' current length ± 0.1 m (a trajectory of three points)."""
    turns = rng.uniform(-scale, scale, n_arm // 2)
    slides = rng.uniform(-0.1, 0.1, n_arm // 2)

    def apply(sim):
        q = sim.q[5:].copy()
        target = q.copy()
        target[0::2] = turns
        target[1::2] = np.clip(q[1::2] + slides, *np.asarray(sim.stroke).T)
        if mode == "position":
            sim.set_arm_positions(target)
        elif mode == "velocity":
            sim.set_arm_velocities(np.concatenate([turns, slides]).reshape(2, -1).T.ravel())
        else:
            times = [0.1, 0.25, 0.4]
            points = [q + (target - q) * f for f in (0.3, 0.8, 1.0)]
            sim.set_arm_trajectory(times, points, [(target - q) * 2.0] * 2 + [np.zeros(n_arm)])
    return apply


def evaluations(sim) -> dict:
    """What Python reads of the controller between steps."""
    return dict(reference=np.array(sim.arm_reference(0.05)), efforts=sim.joint_efforts_applied())


def both_cores(scene, method, rate, arm, commands, monkeypatch, t_end):
    """The run on the C++ core and on the numba kernels (the reference): (cpp, numba)."""
    return tuple(outcome(scene, method, core, monkeypatch, commands, t_end, rate, arm)
                 for core in ("cpp", "numba"))


@pytest.mark.parametrize("rate", RATES)
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("arm", CONTROLLERS, ids=IDS)
def test_the_paper_arm_under_its_controller_runs_bit_for_bit(arm, method, rate, monkeypatch):
    """The paper scene, its arm driven from t = 0, a second command at 0.2 s and cmd_vel on the
    base at 0.3 s (computed torque reads the base's forces: the wheel loop's)."""
    scene = parse_scene(paper_doc())
    rng = np.random.default_rng(7)
    n_arm = scene.robot.n_u - 2
    commands = ((0.0, command(arm[0], n_arm, rng)), (0.2, command(arm[0], n_arm, rng)),
                (0.3, lambda sim: sim.set_base_velocity(0.5, 0.4)))
    run, reference = both_cores(scene, method, rate, controller(*arm), commands, monkeypatch, 0.5)
    assert_identical(run, reference)
    assert run["counters"][5] > 0   # ARM_CONTROL_STAGE: the controller ran


def random_controlled_scene(seed: int):
    """A random robot of 1–3 links with end stops that rebound or stop dead, its arm driven by a
    stiff controller with effort limits (the PID saturates), rods started near their stops."""
    rng = np.random.default_rng(100 + seed)
    n = 1 + seed % 3
    doc = robots.random_robot_document(rng, n)
    doc["initial"]["velocity"] = (rng.normal(size=2 * n + 2) * 0.5).tolist()
    doc["effects"]["stroke_limits"] = {"restitution": float(rng.uniform(0.0, 0.9)),
                                       "rest_speed": float(rng.uniform(0.0, 0.2))}
    doc["effects"]["effort_limits"] = {"joints": float(rng.uniform(20.0, 80.0))}
    doc["efforts"] = {"wheels": rng.normal(size=2).tolist()}
    if seed % 2 == 0:
        doc["effects"]["joint_damping"] = float(rng.uniform(0.1, 2.0))
    return parse_scene(doc), rng


def push_rods(seed: int, side: int):
    """A position set-point that presses every rod into one of its stops (side −1: the lower,
    +1: the upper), the turns anywhere within ±1 rad; a pose the effort limits cannot hold
    against gravity is refused (a UserError) on both cores alike: the arm is held instead."""
    turns = np.random.default_rng(10 * seed + side + 1).uniform(-1.0, 1.0, 3)

    def apply(sim):
        stroke = np.asarray(sim.stroke)
        target = sim.q[5:].copy()
        target[0::2] = turns[:target.size // 2]
        target[1::2] = stroke[:, 1] if side > 0 else stroke[:, 0]
        try:
            sim.set_arm_positions(target)
        except UserError:
            sim.hold_arm()
    return apply


@pytest.mark.parametrize("rate", RATES)
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("seed", range(6))
def test_random_robots_driven_into_their_stops_run_bit_for_bit(seed, method, rate, monkeypatch):
    """The controller pushes the rods onto their stops (impacts, rests) and then pulls them off
    (releases), its feed-forward one of the three, with and without a model error."""
    scene, _ = random_controlled_scene(seed)
    feedforward = ("none", "gravity", "computed_torque")[seed % 3]
    error = ERROR if seed % 2 else None
    arm = controller("position", feedforward, error, dict(kp=(400.0,), kd=(20.0,), ki=(50.0,)))
    commands = ((0.0, push_rods(seed, -1)), (0.3, push_rods(seed, +1)),
                (0.45, lambda sim: sim.set_base_velocity(0.3, -0.5)),
                (0.6, push_rods(seed, -1)))
    run, reference = both_cores(scene, method, rate, arm, commands, monkeypatch, 0.8)
    assert_identical(run, reference)


def test_the_random_controlled_cases_hit_rest_and_leave(monkeypatch):
    """The random cases are worth their time: the controller drives rods into their stops, some
    rest there and leave again, and its efforts saturate."""
    impacts = rests = leaves = 0
    for seed in range(6):
        scene, _ = random_controlled_scene(seed)
        arm = controller("position", "gravity", None, dict(kp=(400.0,), kd=(20.0,), ki=(50.0,)))
        commands = ((0.0, push_rods(seed, -1)), (0.3, push_rods(seed, +1)),
                    (0.6, push_rods(seed, -1)))
        run = outcome(scene, "rk4", "cpp", monkeypatch, commands, 0.8, 100.0, arm)
        impacts, rests, leaves = np.add((impacts, rests, leaves), event_counts(run["impacts"]))
    assert impacts > 10 and rests > 2 and leaves > 0, (impacts, rests, leaves)


@pytest.mark.parametrize("rate", RATES)
def test_the_python_calls_between_steps_read_the_core(rate, monkeypatch):
    """`arm_reference` (ahead of now) and `joint_efforts_applied` equal the numba kernels', and
    the sampled update made from Python (at a reset) equals theirs."""
    scene = parse_scene(paper_doc())
    arm = controller("joint_trajectory", "computed_torque", ERROR)
    seen = {}
    for core in ("numba", "cpp"):
        rng = np.random.default_rng(3)
        run = outcome(scene, "rk4", core, monkeypatch,
                      ((0.0, command("joint_trajectory", 4, rng)),
                       (0.1, lambda sim, core=core: seen.setdefault(core, evaluations(sim)))),
                      0.2, rate, arm)
        seen[core + "-run"] = run
    for key in ("reference", "efforts"):
        assert np.array_equal(seen["cpp"][key], seen["numba"][key]), key
    assert_identical(seen["cpp-run"], seen["numba-run"])
