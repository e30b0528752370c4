"""Bad input, as a user meets it: `python -m mobile_manip_sim.programs.simulate` on a broken scene
file or with a bad flag exits with status 2 and exactly one stderr line
naming the key path.

Every case is one change to the valid paper scene, so the change alone is what fails. One case of
each kind runs as a real process (a few at a time: each pays the interpreter's start-up); the
variants call the same entry point, `simulate.main`, in this process.
"""
import json
import math
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import yaml

from engine_cases import paper_doc, simulation
from huge_commands import COMMANDS, check_huge_command
from huge_commands import apply as apply_command
from mobile_manip_sim.programs import simulate
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.methods import METHODS
from waiting import no_hang


def edit(path, value):
    """A change to the paper scene: set (or, with value DELETE, remove) the key at `path`."""
    def apply(doc):
        *parents, last = path
        node = doc
        for key in parents:
            node = node[key]
        if value is DELETE:
            del node[last]
        else:
            node[last] = value
    return apply


DELETE = object()
NAN, INF = float("nan"), float("inf")

# id: (change to the scene or raw file text or None, extra flags, key path expected on stderr)
CASES = {
    # the engine's own settings
    "unknown method in the scene": (edit(["integrator", "method"], "rk5"), [], "integrator.method"),
    "unknown method flag": (None, ["--method", "rk5"], "--method"),
    "unknown effect": (edit(["effects", "magnetism"], 1.0), [], "effects.magnetism"),
    "zero dt": (edit(["integrator", "dt"], 0.0), [], "integrator.dt"),
    "negative dt": (edit(["integrator", "dt"], -1e-3), [], "integrator.dt"),
    "zero dt flag": (None, ["--method", "rk4", "--dt", "0"], "--dt"),
    "negative dt flag": (None, ["--dt", "-0.001"], "--dt"),
    "nan dt flag": (None, ["--dt", "nan"], "--dt"),
    "zero rtol": (edit(["integrator", "rtol"], 0.0), [], "integrator.rtol"),
    "negative rtol flag": (None, ["--rtol", "-1e-6"], "--rtol"),
    "restitution above 1": (edit(["effects", "stroke_limits", "restitution"], 1.5), [],
                            "effects.stroke_limits.restitution"),
    "restitution below 0": (edit(["effects", "stroke_limits", "restitution"], -0.1), [],
                            "effects.stroke_limits.restitution"),
    "unknown impact law": (edit(["effects", "stroke_limits", "law"], "bounce"), [],
                           "effects.stroke_limits.law"),
    "negative rest speed": (edit(["effects", "stroke_limits", "rest_speed"], -1.0), [],
                            "effects.stroke_limits.rest_speed"),
    "locked joint that does not exist": (edit(["effects", "locked_joints"], ["arm_revolute_3"]), [],
                                         "effects.locked_joints[0]"),
    "joint efforts of the wrong length": (edit(["efforts", "joints"], [4.5, 7.0, 0.0]), [],
                                          "efforts.joints"),
    "wheel efforts of the wrong length": (edit(["efforts", "wheels"], [0.1]), [], "efforts.wheels"),
    "joint damping of the wrong length": (edit(["effects", "joint_damping"], [1.0, 2.0, 3.0]), [],
                                          "effects.joint_damping"),
    "negative joint damping": (edit(["effects", "joint_damping"], [-1.0, 0.0, 0.0, 0.0]), [],
                               "effects.joint_damping[0]"),
    "effort limits of the wrong length": (edit(["effects", "effort_limits"],
                                               {"joints": [1.0, 2.0]}),
                                          [], "effects.effort_limits.joints"),
    "zero effort limit": (edit(["effects", "effort_limits"], {"wheels": 0.0}), [],
                          "effects.effort_limits.wheels"),
    "zero duration flag": (None, ["--duration", "0"], "--duration"),
    # the scene file itself
    "unreadable file": ("missing", [], "does-not-exist.yaml"),
    "a directory for a file": ("directory", [], "scene_dir"),
    "not UTF-8": (b"name: \xff\xfe\n", [], "scene.yaml"),
    "not YAML": ("robot: [unclosed\n", [], "scene"),
    "empty file": ("", [], "scene"),
    "missing robot": (edit(["robot"], DELETE), [], "robot"),
    "missing base mass": (edit(["robot", "base", "mass"], DELETE), [], "robot.base.mass"),
    "unknown top-level key": (edit(["integrater"], {"method": "rk4"}), [], "integrater"),
    "unknown base key": (edit(["robot", "base", "colour"], "red"), [], "robot.base.colour"),
    "unknown link key": (edit(["robot", "arm", "links", 1, "mass"], 1.0), [],
                         "robot.arm.links[1].mass"),
    "zero base mass": (edit(["robot", "base", "mass"], 0.0), [], "robot.base.mass"),
    "negative rod density": (edit(["robot", "arm", "links", 1, "mass_per_length"], -1.0), [],
                             "robot.arm.links[1].mass_per_length"),
    "zero rod length": (edit(["robot", "arm", "links", 0, "length"], 0.0), [],
                        "robot.arm.links[0].length"),
    "zero wheel radius": (edit(["robot", "base", "wheel_radius"], 0.0), [],
                          "robot.base.wheel_radius"),
    "nan base mass": (edit(["robot", "base", "mass"], NAN), [], "robot.base.mass"),
    "infinite gravity": (edit(["effects", "gravity"], INF), [], "effects.gravity"),
    "nan initial joint": (edit(["initial", "joints"], [0.3, NAN, -0.2, 0.5]), [],
                          "initial.joints[1]"),
    "a string for a number": (edit(["robot", "base", "half_track"], "wide"), [],
                              "robot.base.half_track"),
    "stroke beyond the rod": (edit(["robot", "arm", "links", 0, "stroke"], [0.0, 1.5]), [],
                              "robot.arm.links[0].stroke[1]"),
    "stroke below zero": (edit(["robot", "arm", "links", 1, "stroke"], [-0.1, 1.0]), [],
                          "robot.arm.links[1].stroke[0]"),
    "stroke reversed": (edit(["robot", "arm", "links", 0, "stroke"], [0.8, 0.2]), [],
                        "robot.arm.links[0].stroke"),
    "initial l outside its stroke": (edit(["initial", "joints"], [0.3, 1.2, -0.2, 0.5]), [],
                                     "initial.joints[1]"),
    "initial joints of the wrong length": (edit(["initial", "joints"], [0.3, 0.5, -0.2]), [],
                                           "initial.joints"),
    "initial velocity of the wrong length": (edit(["initial", "velocity"], [0.0] * 5), [],
                                             "initial.velocity"),
    "mount of the wrong length": (edit(["robot", "arm", "mount"], [0.0, 0.2]), [],
                                  "robot.arm.mount"),
    "pose of the wrong length": (edit(["initial", "pose"], [0.0, 0.0]), [], "initial.pose"),
}


# One of each kind, run as `python -m mobile_manip_sim.programs.simulate`.
AS_PROCESS = [
    "unknown method in the scene", "unknown method flag", "unknown effect", "zero dt",
    "negative dt flag", "zero rtol", "restitution above 1", "locked joint that does not exist",
    "joint efforts of the wrong length", "unreadable file", "missing base mass",
    "unknown base key", "zero base mass", "nan base mass", "stroke beyond the rod",
    "initial l outside its stroke", "initial joints of the wrong length",
]


def scene_file(case_id, tmp_dir):
    change = CASES[case_id][0]
    scene = tmp_dir / f"{abs(hash(case_id))}" / "scene.yaml"
    scene.parent.mkdir()
    if change == "missing":
        scene = tmp_dir / "does-not-exist.yaml"
    elif change == "directory":
        scene = tmp_dir / "scene_dir"
        scene.mkdir(exist_ok=True)
    elif isinstance(change, bytes):
        scene.write_bytes(change)
    elif isinstance(change, str):
        scene.write_text(change)
    else:
        doc = paper_doc()
        doc["effects"]["joint_damping"] = 0.1      # present, so that cases can break it
        doc["effects"]["stroke_limits"]["rest_speed"] = 1e-3
        if change:
            change(doc)
        text = yaml.safe_dump(doc, sort_keys=False)
        assert ".nan" in text or ".inf" in text or not any(
            isinstance(v, float) and not math.isfinite(v) for v in _leaves(doc))
        scene.write_text(text)
    return scene


def arguments(case_id, tmp_dir):
    scene = scene_file(case_id, tmp_dir)
    return ["--scene", str(scene), "--duration", "0.01",
            "--out", str(tmp_dir / f"{abs(hash(case_id))}.csv"), *CASES[case_id][1]]


def run_case(case_id, tmp_dir):
    return subprocess.run([sys.executable, "-m", "mobile_manip_sim.programs.simulate",
                           *arguments(case_id, tmp_dir)],
                          capture_output=True, text=True, timeout=120)


def _leaves(node):
    if isinstance(node, dict):
        for value in node.values():
            yield from _leaves(value)
    elif isinstance(node, list):
        for value in node:
            yield from _leaves(value)
    else:
        yield node


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    tmp_dir = tmp_path_factory.mktemp("bad_input")
    ids = ["valid scene"] + AS_PROCESS
    CASES["valid scene"] = (None, [], None)
    try:
        with ThreadPoolExecutor(max_workers=4) as pool:
            outcomes = list(pool.map(lambda case_id: run_case(case_id, tmp_dir), ids))
    finally:
        del CASES["valid scene"]
    return dict(zip(ids, outcomes, strict=True))


def test_the_unbroken_scene_runs(results):
    result = results["valid scene"]
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""


def assert_one_line_naming(key, status, stdout, stderr):
    lines = stderr.strip().splitlines()
    assert status == 2, stderr
    assert len(lines) == 1, stderr
    assert "Traceback" not in stderr
    assert f"error: {key}" in lines[0] or f"{key}:" in lines[0], lines[0]
    assert stdout == ""


@pytest.mark.parametrize("case_id", AS_PROCESS)
def test_bad_input_is_one_line_naming_the_key_and_status_2(results, case_id):
    result = results[case_id]
    assert_one_line_naming(CASES[case_id][2], result.returncode, result.stdout, result.stderr)


@pytest.mark.parametrize("case_id", [case for case in CASES if case not in AS_PROCESS])
def test_every_variant_is_one_line_naming_the_key_and_status_2(case_id, tmp_path, capsys):
    status = simulate.main(arguments(case_id, tmp_path))
    captured = capsys.readouterr()
    assert_one_line_naming(CASES[case_id][2], status, captured.out, captured.err)


# --- the same checks at the engine's interface ---------------------------------------------

@pytest.mark.parametrize("wheels, joints, key", [
    ([0.1, 0.2, 0.3], None, "efforts.wheels"),
    (None, [1.0, 2.0], "efforts.joints"),
    (None, [1.0, math.nan, 0.0, 0.0], "efforts.joints"),
    ([math.inf, 0.0], None, "efforts.wheels"),
    ("fast", None, "efforts.wheels"),
])
def test_a_bad_command_is_rejected_and_the_last_one_kept(wheels, joints, key):
    sim = simulation(paper_doc(), "rk4")
    before = (sim.wheel_efforts.copy(), sim.joint_efforts.copy(), sim.system.Q_cmd.copy())
    with pytest.raises(UserError) as error:
        sim.set_efforts(wheels=wheels, joints=joints)
    assert error.value.key == key
    assert np.array_equal(sim.wheel_efforts, before[0])
    assert np.array_equal(sim.joint_efforts, before[1])
    assert np.array_equal(sim.system.Q_cmd, before[2])


def test_a_numerical_blow_up_says_when_and_exits_1(tmp_path):
    """Not a user error: euler with a huge step on a stiff scene diverges; status 1, one line."""
    doc = paper_doc(effects={"gravity": 10.0, "joint_damping": [1e6, 1e6, 1e6, 1e6]})
    doc["integrator"] = {"method": "euler", "dt": 0.01}
    scene = tmp_path / "stiff.yaml"
    scene.write_text(yaml.safe_dump(doc))
    result = subprocess.run([sys.executable, "-m", "mobile_manip_sim.programs.simulate",
                             "--scene", str(scene), "--duration", "1.0",
                             "--out", str(tmp_path / "out.csv")],
                            capture_output=True, text=True, timeout=120)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 1 and len(lines) == 1, result.stderr
    assert "non-finite" in lines[0] and "t = " in lines[0]


# --- radau/bdf that cannot follow the solution: step floor and step budget (step_watch) ---------

def featherweight_rods_doc() -> dict:
    """In bounds but extreme: rods of 1e-9 kg/m pushed with 1e6 N·m and N at the tightest
    tolerances; radau and bdf used to crawl at steps of 1e-8 to 1e-12 s, minutes per 10 ms."""
    doc = paper_doc(efforts={"wheels": [0.1, 0.2], "joints": [1e6, 1e6, 1e6, 1e6]})
    for link in doc["robot"]["arm"]["links"]:
        link["mass_per_length"] = 1e-9
    return doc


def huge_command_after_reset(method):
    sim = simulation(paper_doc(), method)
    sim.reset()
    sim.set_efforts(wheels=[1e30, 1e30], joints=[1e30] * 4)   # finite, so accepted
    return sim


CRAWLS = {"a huge command after a reset": huge_command_after_reset,
          "featherweight rods": lambda method: simulation(featherweight_rods_doc(), method,
                                                           rtol=1e-14, atol=1e-20)}


@pytest.mark.parametrize("method, case",
                         [(method, case) for method in ("radau", "bdf") for case in CRAWLS]
                         + [(method, "a huge command after a reset")
                            for method in ("rk45", "dop853")])
def test_an_adaptive_solver_that_cannot_follow_stops_promptly_in_one_line(case, method):
    from mobile_manip_sim.engine.simulation import StepLimitError

    sim = CRAWLS[case](method)
    with no_hang("a solver that cannot follow"), pytest.raises(StepLimitError) as caught:
        sim.advance_to(0.01)   # it crawled for minutes (or for ever) before: a step count below
    message = str(caught.value)
    assert caught.value.key == "integrator.rtol" and "\n" not in message and len(message) < 300
    assert message.startswith("integrator.rtol: t = ") and f"{method} cannot follow" in message
    assert sim.steps < 10_000


def test_simulate_exits_2_with_one_line_when_bdf_cannot_follow(tmp_path):
    scene = tmp_path / "featherweight.yaml"
    scene.write_text(yaml.safe_dump({**featherweight_rods_doc(), "integrator": {
        "method": "bdf", "rtol": 1e-14, "atol": 1e-20}}))
    result = subprocess.run([sys.executable, "-m", "mobile_manip_sim.programs.simulate",
                             "--scene", str(scene), "--duration", "1.0",
                             "--out", str(tmp_path / "out.csv")],
                            capture_output=True, text=True, timeout=120)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1, result.stderr
    assert ": error: integrator.rtol: t = " in lines[0], lines[0]
    assert "bdf cannot follow" in lines[0], lines[0]


def test_the_step_watch_tells_a_crawl_from_a_restart():
    """The core's count (the one every adaptive method's steps go through), on steps handed to a
    radau stepper's watch."""
    from mobile_manip_sim.engine.step_watch import (
        BUDGET_SPAN,
        BUDGET_STEPS,
        FLOOR_STEPS,
        clear,
        describe,
    )
    sim = simulation(paper_doc(), "radau")
    watch = sim._solve.watch

    def first_problem(steps, t=0.0):
        clear(watch)
        for i, h in enumerate(steps):
            if sim._stepper.watch_step(t, h):
                return i + 1, describe(watch, t, h)
            t += h
        return None

    # A solver restarted with a tiny step grows it tenfold per step: no crawl.
    assert first_problem([1e-20 * 10 ** i for i in range(18)] + [1e-3] * 100) is None
    # Below the floor for FLOOR_STEPS steps in a row is one; an interruption starts the count anew.
    assert first_problem([1e-18] * FLOOR_STEPS)[0] == FLOOR_STEPS
    assert first_problem(([1e-18] * (FLOOR_STEPS - 1) + [1e-6]) * 3) is None
    # The floor is relative to t beyond 1 s: a step of 1e-7 s at t = 1e6 s is below it.
    assert "floor of 1e-06 s" in first_problem([1e-7] * FLOOR_STEPS, t=1e6)[1]
    # The budget: BUDGET_STEPS steps must cover BUDGET_SPAN; window after window.
    slow = BUDGET_SPAN / BUDGET_STEPS
    assert first_problem([0.9 * slow] * BUDGET_STEPS)[0] == BUDGET_STEPS
    assert first_problem([1.1 * slow] * (3 * BUDGET_STEPS)) is None
    slow_then_fast = [1.1 * slow] * BUDGET_STEPS + [0.9 * slow] * BUDGET_STEPS
    assert first_problem(slow_then_fast)[0] == 2 * BUDGET_STEPS


# --- huge finite commands right after a reset, every method -------------------------------

@pytest.fixture(scope="module")
def huge_commands():
    """test/helpers/huge_commands.py's cases, run in their own process: the timeout is only a
    safety net (a regression that loops would otherwise hang the test run); what bounds each case
    is the step watch, asserted below as a step count."""
    result = subprocess.run([sys.executable, "huge_commands.py"], capture_output=True, text=True,
                            timeout=600, cwd=Path(__file__).parents[1] / "helpers")
    assert result.returncode == 0, result.stderr
    return [json.loads(line) for line in result.stdout.splitlines()]


def test_huge_commands_after_a_reset_fail_in_one_line_for_every_method(huge_commands):
    assert [(c["method"], c["command"], c["values"]) for c in huge_commands] == [
        (method, group, values) for method in METHODS for group, values in COMMANDS]
    for case in huge_commands:
        check_huge_command(case)
    # both ways of failing are met: refused at the command, and failed by the integrator
    kinds = {(c["method"], c["error"]) for c in huge_commands}
    assert {(m, "UserError") for m in METHODS} <= kinds
    assert {(m, "StepLimitError") for m in METHODS if not METHODS[m].fixed_step} <= kinds


@pytest.mark.parametrize("group, values", [("wheels", [1e308, 1e308]), ("wheels", [-1e308, 1e308]),
                                           ("cmd_vel", [1e308, 0.0]), ("cmd_vel", [0.0, 1e308])])
def test_a_command_whose_forces_overflow_is_refused_and_the_last_one_kept(group, values):
    sim = simulation(paper_doc(), "rk4")
    sim.set_efforts(wheels=[0.1, 0.2])
    before = (sim.wheel_efforts.copy(), sim.system.Q_cmd.copy(), sim.system.control.copy())
    with pytest.raises(UserError) as error:
        apply_command(sim, group, values)
    assert error.value.key == f"efforts.{group}" and "overflows" in str(error.value)
    assert np.array_equal(sim.wheel_efforts, before[0])
    assert np.array_equal(sim.system.Q_cmd, before[1])
    assert np.array_equal(sim.system.control, before[2])
    sim.advance_to(0.01)   # still the last valid command
    assert np.all(np.isfinite(sim.s))


def resimulated_with_a_huge_command(method, values, tmp_dir):
    """`replay --resimulate` of a headless bag of `method` whose wheel command at t = 0 is
    rewritten to `values` (scene efforts are bounded by 1e6: a bag is how such a command comes)."""
    from bag_rewrite import rewrite_bag
    from executables import executable
    from mobile_manip_sim.ros.cdr import exact_cdr
    from mobile_manip_sim.ros.messages import float64_array
    from mobile_manip_sim.ros.topics import WHEEL_TOPIC

    scene = tmp_dir / f"{method}.yaml"
    scene.write_text(yaml.safe_dump({**paper_doc(), "integrator": {"method": method}}))
    recorded, altered = tmp_dir / f"{method}_bag", tmp_dir / f"{method}_huge"
    result = subprocess.run([executable("simulate"), "--scene", str(scene), "--duration", "0.1",
                             "--out", str(tmp_dir / f"{method}.csv"), "--record", str(recorded)],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    rewrite_bag(recorded, altered, lambda topic, data, index: exact_cdr(float64_array(values))
                if topic == WHEEL_TOPIC else data)
    return subprocess.run([executable("replay"), str(altered), "--resimulate"],
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("method, values, key", [
    ("dop853", [1e308, 1e308], "efforts.wheels"),   # spun for ever, deaf to SIGINT
    ("rk45", [1e300, 1e300], "integrator.rtol"),
    ("radau", [1e300, 1e300], "integrator.rtol"),   # a 50-line traceback of lu_factor
    ("bdf", [1e300, -1e300], "integrator.rtol")])
def test_resimulating_a_bag_of_huge_commands_is_one_line_and_status_2(method, values, key,
                                                                       tmp_path):
    result = resimulated_with_a_huge_command(method, values, tmp_path)
    assert_one_line_naming(key, result.returncode, "", result.stderr)
    assert result.stderr.startswith(f"replay: error: {key}: "), result.stderr
