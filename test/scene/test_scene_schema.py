"""The scene schema and the safe YAML loader, in process: every bad input is one `UserError`
naming the key path, its message one short line; the good inputs still load.

The table `LEAF_CASES` puts each of a set of bad values at every leaf of the paper scene (one
change at a time); `YAML_CASES` are hand-written attacks on the loader itself.
"""
import copy
import math

import pytest
import yaml

from engine_cases import paper_doc
from hostile_yaml import ALIAS_BOMB
from mobile_manip_sim.recording.bag_format import checked_run_metadata
from mobile_manip_sim.scene import schema
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.loading import parse_scene, scene_from_text
from waiting import no_hang

MAX_MESSAGE = 300


def leaves(node, path=""):
    """(key path, value) of every scalar in a document, paths as the scene's errors spell them."""
    if isinstance(node, dict):
        for key, value in node.items():
            yield from leaves(value, f"{path}.{key}" if path else key)
    elif isinstance(node, list):
        for i, value in enumerate(node):
            yield from leaves(value, f"{path}[{i}]")
    else:
        yield path, node


def replaced(doc, path, value):
    doc = copy.deepcopy(doc)
    node, parts = doc, path.replace("[", ".[").split(".")
    for part in parts[:-1]:
        node = node[int(part[1:-1])] if part.startswith("[") else node[part]
    last = parts[-1]
    node[int(last[1:-1]) if last.startswith("[") else last] = value
    return doc


HUGE_INT = "9" * 400
BAD_VALUES = {  # YAML text of the value; each is out of bounds or of the wrong type everywhere
    "1e308": "1e308", "-1e308": "-1e308", "huge integer": HUGE_INT, "nan": ".nan", "inf": ".inf",
    "-inf": "-.inf", "null": "null", "list": "[1, 2]", "mapping": "{a: 1}", "date": "2001-12-14",
}
STRING_LEAVES = {"name", "effects.stroke_limits.law", "integrator.method"}
PAPER = paper_doc()


def _leaf_cases():
    for path, original in leaves(PAPER):
        for label, text in BAD_VALUES.items():
            if path == "name" and label == "date":
                continue  # YAML 1.2: a string, hence a valid name
            yield pytest.param(path, text, id=f"{path}={label}")
        if isinstance(original, bool):
            yield pytest.param(path, "1", id=f"{path}=1")
            yield pytest.param(path, "yes", id=f"{path}=yes (YAML 1.1 only)")
        elif not isinstance(original, str):
            yield pytest.param(path, "'1.0'", id=f"{path}=quoted")
            yield pytest.param(path, "true", id=f"{path}=true")


LEAF_CASES = list(_leaf_cases())


def assert_one_line(error: UserError, key: str) -> None:
    message = str(error)
    assert "\n" not in message and len(message) <= MAX_MESSAGE, message
    assert error.key == key or message.startswith(f"{key}:"), message


@pytest.mark.parametrize("path, text", LEAF_CASES)
def test_a_bad_value_at_any_key_is_one_line_naming_it(path, text):
    document = yaml.safe_dump(replaced(PAPER, path, "__BAD__"), sort_keys=False)
    document = document.replace("__BAD__", text)
    with pytest.raises(UserError) as caught:
        scene_from_text(document)
    assert_one_line(caught.value, path)


# --- bounds: physically implausible but well-typed values ------------------------------------

BOUND_CASES = {
    "robot.base.mass": [1e-300, 1e16, 0.0, -1.0],
    "robot.base.wheel_radius": [1e-300, 1e-5, 1e4],
    "robot.base.half_track": [1e-300, 0.0, 1e4],
    "robot.base.yaw_inertia": [0.0, 1e-300, 1e16],
    "robot.arm.links[0].length": [1e-300, 1e-7, 1e4],
    "robot.arm.links[0].mass_per_length": [1e-300, 1e9],
    "robot.arm.links[0].joint_rpy[0]": [7.0, -100.0],
    "initial.pose[0]": [1e7], "initial.velocity[2]": [1e5],
    "efforts.wheels[0]": [1e7], "efforts.joints[1]": [-1e7],
    "effects.gravity": [101.0, -1.0], "integrator.rtol": [1e-300, 2.0], "integrator.atol": [1e-300],
    "duration": [1e-300 * 0, 2e6, -1.0],
}


@pytest.mark.parametrize("path, value", [pytest.param(p, v, id=f"{p}={v}")
                                         for p, values in BOUND_CASES.items() for v in values])
def test_implausible_values_are_refused_naming_the_key(path, value):
    with pytest.raises(UserError) as caught:
        parse_scene(replaced(PAPER, path, value))
    assert_one_line(caught.value, path)


@pytest.mark.parametrize("dt, method", [(1e308, "rk4"), (1e-12, "rk4"), (1e-300, "euler"),
                                        (2.0, "rk4"), (1e-8, "rk4")])
def test_a_dt_out_of_bounds_or_beyond_the_step_budget_names_integrator_dt(dt, method):
    doc = replaced(PAPER, "integrator", {"method": method, "dt": dt})
    with pytest.raises(UserError) as caught:
        parse_scene(doc)
    assert_one_line(caught.value, "integrator.dt")


def test_a_long_run_beyond_the_step_budget_names_duration():
    doc = replaced(replaced(PAPER, "integrator", {"method": "rk4", "dt": 1e-3}), "duration", 5e5)
    with pytest.raises(UserError) as caught:
        parse_scene(doc)
    assert_one_line(caught.value, "duration")
    assert "steps" in str(caught.value)


@pytest.mark.parametrize("key", ["method", "dt", "rtol", "atol"])
def test_null_integrator_settings_are_refused_not_defaulted(key):
    with pytest.raises(UserError) as caught:
        scene_from_text(yaml.safe_dump(replaced(PAPER, "integrator", {key: None})))
    assert_one_line(caught.value, f"integrator.{key}")


def test_a_missing_arm_is_reported_as_such():
    doc = copy.deepcopy(PAPER)
    del doc["robot"]["arm"]
    with pytest.raises(UserError) as caught:
        parse_scene(doc)
    assert_one_line(caught.value, "robot.arm")
    assert "missing" in str(caught.value)


def test_too_many_links_are_refused_before_building_the_robot():
    doc = copy.deepcopy(PAPER)
    doc["robot"]["arm"]["links"] = [copy.deepcopy(doc["robot"]["arm"]["links"][1])] * 1000
    with pytest.raises(UserError) as caught:
        parse_scene(doc)
    assert_one_line(caught.value, "robot.arm.links")


def test_messages_shorten_huge_values():
    doc = replaced(PAPER, "name", list(range(100_000)))
    with pytest.raises(UserError) as caught:
        parse_scene(doc)
    assert_one_line(caught.value, "name")


# --- the loader -------------------------------------------------------------------------------

PAPER_TEXT = yaml.safe_dump(PAPER, sort_keys=False)

YAML_CASES = {
    "alias bomb": ALIAS_BOMB,
    "recursive alias": "a: &a [*a]\n",
    "merge-key bomb": "a: &a {x: 1}\nb: &b {<<: [*a, *a], y: 2}\n" + "".join(
        f"c{i}: &c{i} [" + ",".join(["*b"] * 50) + "]\n" for i in range(1)) + "d: [" + ",".join(
        ["*c0"] * 3000) + "]\n",
    "nested 3000 deep (flow)": "robot: " + "[" * 3000 + "]" * 3000 + "\n",
    "nested 3000 deep (block)": "".join(" " * i + "- \n" for i in range(3000)),
    "nested 3000 deep (mappings)": "".join(" " * i + "k:\n" for i in range(3000)),
    "duplicate top-level key": PAPER_TEXT + "duration: 2.0\n",
    "duplicate nested key": PAPER_TEXT.replace("integrator:\n", "integrator:\n  method: rk4\n", 1),
    "a mapping as a key": "? {a: 1}\n: 2\n",
    "a list as a key": "? [1]\n: 2\n",
    "bad indentation": "robot:\n  base: 1\n   arm: 2\n",
    "a tab": "robot:\n\tbase: 1\n",
    "unclosed flow": "robot: [1, 2\n",
    "unclosed quote": "name: 'abc\n",
    "binary": "\x00\x01\x02\x03",
    "control characters": "name: \x07\x08\n",
    "two documents": PAPER_TEXT + "---\n" + PAPER_TEXT,
    "an unknown tag": "robot: !!python/object:os.system echo\n",
    "a python tag": "robot: !!python/name:os.system\n",
    "a custom tag": "robot: !mine 1\n",
    "a float tag on a word": PAPER_TEXT.replace("duration: 1.5", "duration: !!float abc"),
    "an int tag on a fraction": PAPER_TEXT.replace("duration: 1.5", "duration: !!int 1.5"),
    "a bool tag on yes": "robot: !!bool yes\n",
    "a null tag on a word": "robot: !!null abc\n",
    "a timestamp tag": "duration: !!timestamp 2001-12-14\n",
    "a YAML 1.1 directive": "%YAML 1.1\n---\n" + PAPER_TEXT,
    "a top-level list": "- 1\n- 2\n",
    "a top-level scalar": "42\n",
    "a top-level string": "hello\n",
    "empty": "",
    "only a comment": "# nothing\n",
    "too large": "name: x\n" + "#" * (schema.MAX_FILE_BYTES + 10) + "\n",
    "an undefined alias": "robot: *nothing\n",
    "huge integer key": f"{HUGE_INT}: 1\n",
    "an unknown top-level key": PAPER_TEXT + "colour: red\n",
    "an unknown base key": PAPER_TEXT.replace("  base:\n", "  base:\n    colour: red\n", 1),
}


@pytest.mark.parametrize("text", YAML_CASES.values(), ids=YAML_CASES.keys())
def test_hostile_yaml_is_one_line_and_fast(text):
    with no_hang("refusing the hostile YAML"), pytest.raises(UserError) as caught:
        scene_from_text(text, "scene.yaml")
    message = str(caught.value)
    assert "\n" not in message and len(message) <= MAX_MESSAGE, message
    assert caught.value.key, message


def test_the_alias_bomb_is_small_and_refused_as_an_expansion():
    assert len(ALIAS_BOMB) < 600
    with pytest.raises(UserError, match="expands to more than"):
        schema.load_yaml(ALIAS_BOMB, what="bomb.yaml")


def test_duplicate_keys_name_the_key():
    with pytest.raises(UserError) as caught:
        schema.load_yaml("a: 1\nb: 2\na: 3\n")
    assert caught.value.key == "a" and "duplicate" in str(caught.value)


@pytest.mark.parametrize("text, value", [
    ("1e-10", 1e-10), ("1E5", 1e5), ("-2.5e+3", -2500.0), ("1.", 1.0), (".5", 0.5), ("017", 17),
    ("0o17", 15), ("0x1f", 31), ("1_000", "1_000"), ("yes", "yes"), ("on", "on"), ("1:30", "1:30"),
    ("~", None), ("null", None), ("True", True), (".inf", math.inf)])
def test_yaml_1_2_core_scalars(text, value):
    assert schema.load_yaml(f"v: {text}\n")["v"] == value


@pytest.mark.parametrize("text, value", [("!!float 1", 1.0), ("!!float .inf", math.inf),
                                         ("!!int 0x1f", 31), ("!!float 0x1F", 31.0),
                                         ("!!float 0o17", 15.0), ("!!str 1.5", "1.5"),
                                         ("!!bool false", False), ("!!null ~", None)])
def test_explicit_core_tags_that_fit_their_value(text, value):
    assert schema.load_yaml(f"v: {text}\n")["v"] == value
    assert schema.load_yaml(f"%YAML 1.2\n---\nv: {text}\n")["v"] == value


def test_a_joint_locked_twice_is_refused():
    doc = replaced(PAPER, "effects", {"locked_joints": ["arm_revolute_1", "arm_revolute_1"]})
    with pytest.raises(UserError) as caught:
        parse_scene(doc)
    assert_one_line(caught.value, "effects.locked_joints[1]")


def test_yaml_1_2_exponent_without_a_dot_is_a_valid_tolerance():
    scene = scene_from_text(PAPER_TEXT.replace("rtol: 1.0e-10", "rtol: 1e-10"))
    assert scene.integrator.rtol == 1e-10


def test_shared_aliases_within_the_budget_still_load():
    doc = schema.load_yaml("a: &a [1, 2, 3]\nb: *a\nc: {<<: {x: 1}, y: 2}\n")
    assert doc == {"a": [1, 2, 3], "b": [1, 2, 3], "c": {"x": 1, "y": 2}}


def test_every_shipped_scene_still_loads(tmp_path):
    from pathlib import Path

    from mobile_manip_sim.scene.loading import load_scene
    config = Path(__file__).resolve().parents[2] / "config"
    scenes = [p for p in sorted(config.glob("*.yaml")) if not p.name.endswith(".params.yaml")]
    assert len(scenes) >= 10
    for path in scenes:
        assert load_scene(path).duration > 0


def test_special_files_are_refused_without_reading(tmp_path):
    import os
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    for path, problem in (("/dev/zero", "not a regular file"), (fifo, "not a regular file"),
                          (tmp_path, "not a regular file"),
                          (tmp_path / "none.yaml", "cannot read")):
        with no_hang(f"refusing {path}"), pytest.raises(UserError, match=problem):
            schema.load_yaml(__import__("pathlib").Path(path), what="scene")


def test_not_utf8_is_one_line(tmp_path):
    path = tmp_path / "latin1.yaml"
    path.write_bytes(b"name: caf\xe9\n")
    with pytest.raises(UserError, match="not UTF-8"):
        schema.load_yaml(path, what="scene")


def test_run_metadata_is_checked_and_parsed():
    good = {"version": "0.1.0", "integrator_method": "rk4", "dt": "0.001", "rtol": "1e-09",
            "atol": "1e-12", "scene_name": "x", "source": "simulate", "sample_rate": "20.0",
            "duration": "2.0"}
    assert checked_run_metadata(good)["dt"] == 0.001
    for key, value in (("dt", "1e308"), ("dt", "nan"), ("sample_rate", "1e999"), ("rtol", "x"),
                       ("source", "elsewhere"), ("colour", "red")):
        with pytest.raises(UserError) as caught:
            checked_run_metadata({**good, key: value})
        assert_one_line(caught.value, f"mobile_manip_sim.{key}")
