"""The compiled engine (core/include/mms/stepping.hpp and adaptive_stepping.hpp: steps, crossing
checks, event location on the step or its dense output, impacts, rests, releases, the Zeno guard
and the energy ledger) against the numba kernels it replaces (engine/stepping.py,
engine/adaptive_stepping.py), bit for bit while both exist: on every scene the package ships
and on random robots whose rods hit, rest, are pulled off their stops and are held by the Zeno
guard, each with its commands changed mid-run, for each fixed-step method, rk45 and dop853, and
SciPy's radau and bdf (their steps handed into the compiled stepper's step in hand).
Compared: every sampled state and its energy, the clock (steps, the ledger of the law's losses
and the holds), the stage counters, every impact with its details, and which rods rest and are
watched.
"""
import copy
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import robots
from engine_cases import one_link_doc, paper_doc
from mobile_manip_sim.engine import core_stepping
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.scene.loading import load_scene, parse_scene

CONFIG = Path(__file__).resolve().parents[2] / "mobile_manip_sim" / "config"
SCENES = sorted(p for p in CONFIG.glob("*.yaml") if p.name != "simulator.params.yaml")
PAPER = paper_doc()
METHODS = ["euler", "semi_implicit_euler", "rk4", "rk45", "dop853", "radau", "bdf"]
# each method's settings: the fixed steps at 1 kHz, the adaptive ones at tolerances of use
SETTINGS = {"euler": dict(dt=1e-3), "semi_implicit_euler": dict(dt=1e-3), "rk4": dict(dt=1e-3),
            "rk45": dict(rtol=1e-7, atol=1e-10), "dop853": dict(rtol=1e-9, atol=1e-12),
            "radau": dict(rtol=1e-6, atol=1e-9), "bdf": dict(rtol=1e-6, atol=1e-9)}


def outcome(scene, method: str, core: str, monkeypatch, commands=(), t_end=1.0, rate=None,
            arm_controller=None):
    """A run of `scene` by `core` ("numba" or "cpp"), sampled at 100 Hz; `commands` are
    (t, function of the simulation) applied when the run reaches t. A small step budget makes
    each compiled call return often, as a node's do. With an arm controller, also what its last
    evaluation left (the reference, feed-forward and efforts) and the efforts held."""
    monkeypatch.setattr(core_stepping, "CORE", core)
    sim = Simulation(scene, replace(scene.integrator, method=method, **SETTINGS[method]),
                     arm_controller, rate)
    assert (sim._stepper is not None) == (core == "cpp")
    sim._step_budget = 97
    times = np.arange(1, int(round(t_end / 0.01)) + 1) * 0.01
    rows, start = [], 0
    for at, command in (*commands, (t_end, None)):
        part = times[(times > start - 1e-12) & (times <= at + 1e-12)]
        try:
            rows.append(sim.sample(part))
        except Exception as error:   # a failed run fails the same way on both
            rows.append(str(error))
            break
        if command is not None:
            command(sim)
        start = at
    return dict(rows=rows, clock=sim._clock.copy(), counters=sim.system.counters.copy(),
                impacts=sim.impacts, details=sim.impact_details, resting=sim.resting.copy(),
                watched=sim.watched.copy(), s=sim.s.copy(), arm_ref=sim.system.arm_ref.copy(),
                held=sim.system.held.copy())


def assert_identical(a, b):
    assert len(a["rows"]) == len(b["rows"])
    for x, y in zip(a["rows"], b["rows"], strict=True):
        assert type(x) is type(y)
        assert x == y if isinstance(x, str) else np.array_equal(x, y, equal_nan=True)
    for key in ("clock", "counters", "resting", "watched", "s", "arm_ref", "held"):
        assert np.array_equal(a[key], b[key], equal_nan=True), key
    assert a["impacts"] == b["impacts"]
    for x, y in zip(a["details"], b["details"], strict=True):
        for field in x._fields:
            assert np.array_equal(getattr(x, field), getattr(y, field)), field


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_every_shipped_scene_runs_bit_for_bit_as_on_the_numba_kernels(path, method,
                                                                        monkeypatch):
    scene = load_scene(path)
    reference = outcome(scene, method, "numba", monkeypatch)
    assert_identical(outcome(scene, method, "cpp", monkeypatch), reference)


def random_scene(seed: int):
    """A random robot of 1–4 links with end stops that rebound or stop dead (rest_speed), under
    gravity and random efforts, its rods started near their stops."""
    rng = np.random.default_rng(seed)
    n = 1 + seed % 4
    doc = robots.random_robot_document(rng, n)
    doc["initial"]["velocity"] = (rng.normal(size=2 * n + 2) * 0.5).tolist()
    doc["efforts"] = {"wheels": rng.normal(size=2).tolist(),
                      "joints": (rng.normal(size=2 * n) * 3.0).tolist()}
    doc["effects"]["stroke_limits"] = {"restitution": float(rng.uniform(0.0, 0.9)),
                                       "rest_speed": float(rng.uniform(0.0, 0.2))}
    if seed % 3 == 0:
        doc["effects"]["joint_damping"] = float(rng.uniform(0.1, 2.0))
    return parse_scene(doc), rng


def flip_efforts(rng, n: int):
    joints = (rng.normal(size=2 * n) * 6.0).tolist()
    return lambda sim: sim.set_efforts(joints=joints)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("seed", range(12))
def test_random_robots_hitting_resting_and_leaving_run_bit_for_bit(seed, method, monkeypatch):
    scene, rng = random_scene(seed)
    n = scene.robot.n_links
    commands = ((0.3, flip_efforts(rng, n)),
                (0.6, lambda sim: sim.set_base_velocity(0.4, -0.3)),
                (0.8, flip_efforts(rng, n)))
    reference = outcome(scene, method, "numba", monkeypatch, commands)
    assert_identical(outcome(scene, method, "cpp", monkeypatch, commands), reference)


def bouncing_rod_scene(restitution: float):
    """One rod straight up falling onto its lower stop under gravity: a geometric run of bounces
    with an accumulation point, which the Zeno guard holds (rest_speed 0)."""
    doc = one_link_doc(joints=(1.5707963267948966, 0.5), stroke=(0.0, 1.0),
                       effects={"gravity": 10.0, "stroke_limits": {"restitution": restitution,
                                                                   "rest_speed": 0.0}})
    return parse_scene(doc)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("restitution", [0.3, 0.5])
def test_a_zeno_run_of_bounces_is_held_bit_for_bit(restitution, method, monkeypatch):
    """(Explicit Euler gains energy at every flight: its rod chatters on, some 400 impacts, and
    is compared as it is.)"""
    scene = bouncing_rod_scene(restitution)
    reference = outcome(scene, method, "numba", monkeypatch, t_end=2.0)
    if method != "euler":
        assert reference["clock"][6] >= 1, "the case must reach a Zeno hold"   # CLOCK_HOLDS
    assert_identical(outcome(scene, method, "cpp", monkeypatch, t_end=2.0), reference)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("rate", [0.0, 100.0, 1000.0])
def test_the_wheel_speed_loop_continuous_or_sampled_runs_bit_for_bit(rate, method, monkeypatch):
    """The paper scene driven by cmd_vel through wheels limited to 0.3 N·m (the loop saturates
    and holds its integrals), the loop continuous or updated at 100 Hz and 1 kHz (its torques
    held between updates, each update a step boundary), a new command mid-run."""
    doc = copy.deepcopy(PAPER)
    doc["effects"] = {**doc.get("effects", {}), "effort_limits": {"wheels": 0.3}}
    scene = parse_scene(doc)
    commands = ((0.05, lambda sim: sim.set_base_velocity(1.0, 0.0)),
                (0.5, lambda sim: sim.set_base_velocity(0.2, 0.8)))
    reference = outcome(scene, method, "numba", monkeypatch, commands, rate=rate)
    assert_identical(outcome(scene, method, "cpp", monkeypatch, commands, rate=rate), reference)


@pytest.mark.parametrize("method", ["rk4", "radau", "bdf"])
def test_the_random_cases_reach_every_kind_of_event(method, monkeypatch):
    """The random cases are worth their time: impacts, rests, and rods that leave their stops
    again all occur among them (SciPy's steps included: a step handed in while a rod rests has
    its end derivative evaluated, and a release located on its power series)."""
    impacts = rests = leaves = 0
    for seed in range(12):
        scene, rng = random_scene(seed)
        n = scene.robot.n_links
        run = outcome(scene, method, "cpp", monkeypatch, ((0.3, flip_efforts(rng, n)),))
        impacts, rests, leaves = np.add((impacts, rests, leaves), event_counts(run["impacts"]))
    assert impacts > 50 and rests > 3 and leaves > 0, (impacts, rests, leaves)


def event_counts(impacts) -> tuple[int, int, int]:
    """A run's impacts, those that left a rod resting, and the impacts of rods that had rested
    before (they left their stop in between)."""
    rests = leaves = 0
    rested = set()
    for i in impacts:
        leaves += i.link in rested and not i.resting
        if i.resting:
            rests += 1
            rested.add(i.link)
    return len(impacts), rests, leaves


def test_scipy_steps_are_handed_in_to_a_radau_or_bdf_stepper_only():
    """A step handed in to another method's stepper, a radau stepper asked to advance itself, or
    a power series of the wrong shape: one line naming the call or the argument."""
    scene = load_scene(SCENES[0])
    rk4 = Simulation(scene, replace(scene.integrator, method="rk4", dt=1e-3))
    with pytest.raises(ValueError, match="^hand_in_step: only for radau and bdf"):
        rk4._stepper.hand_in_step(1e-3, rk4.s, np.zeros((3, rk4.s.size)))
    radau = Simulation(scene, replace(scene.integrator, method="radau"))
    with pytest.raises(ValueError, match="^advance: radau and bdf are stepped from Python"):
        radau._stepper.advance(radau.s, radau._clock, 1.0, 10)
    with pytest.raises(ValueError, match=r"^series: expected \(rows ≤ 7, "):
        radau._stepper.hand_in_step(1e-3, radau.s, np.zeros((8, radau.s.size)))
