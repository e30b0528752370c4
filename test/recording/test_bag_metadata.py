"""Damaged bag metadata: metadata.yaml, the ``mobile_manip_sim`` map, the embedded
scene.yaml, impacts.json and the recorded QoS, each checked by the one schema. Every case is a
copy of one bag recorded by the real recorder with one thing damaged; `replay --resimulate` and
`plot` refuse it with status 2 and one line naming the key, promptly: no traceback, no hang, and
no sample grid built from a crafted duration or rate.
"""
import copy
import os
import shutil
from pathlib import Path

import pytest
import yaml

from bag_rewrite import rewrite_bag
from hostile_yaml import ALIAS_BOMB
from mobile_manip_sim.plot import cli as plot
from mobile_manip_sim.recording.bag_reader import open_bag
from mobile_manip_sim.recording.headless import HeadlessRecorder
from mobile_manip_sim.recording.rosbag2_metadata import bag_information
from mobile_manip_sim.replay import cli as replay
from mobile_manip_sim.replay.play import qos_profile
from mobile_manip_sim.runtime.headless import run as simulate_run
from mobile_manip_sim.scene import schema
from mobile_manip_sim.scene.errors import EXIT_USER_ERROR, UserError
from mobile_manip_sim.scene.loading import load_scene, make_integrator
from waiting import no_hang

RATE, DURATION = 20.0, 0.2
ROOT = "rosbag2_bagfile_information"


def recorded_run(path: Path, scene) -> Path:
    """A short rk4 run of `scene` recorded into `path` as `simulate --record` records it."""
    settings = make_integrator(scene.integrator, "rk4", 0.001)
    recorder = HeadlessRecorder(path, scene, settings, RATE, DURATION)
    try:
        simulate_run(scene, DURATION, RATE, settings, on_sample=recorder.sample)
    finally:
        recorder.close()
    return path


@pytest.fixture(scope="module")
def good_bag(tmp_path_factory) -> Path:
    """A short rk4 run of the paper scene."""
    return recorded_run(tmp_path_factory.mktemp("good") / "bag", load_scene())


def refusal(argv, capsys) -> str:
    """The one error line of replay/plot on argv (status 2; a refusal, not a hang)."""
    command, *args = argv
    with no_hang(f"refusing {args}"):
        status = command.main(args)
    err = capsys.readouterr().err
    assert status == EXIT_USER_ERROR, (status, err)
    assert err.count("\n") == 1 and ": error: " in err and len(err) < 400, err
    return err.strip()


def commands(bag: Path, out: Path):
    return [(replay, str(bag), "--resimulate"), (plot, str(bag), "--out", str(out))]


def test_the_good_bag_is_accepted(good_bag, tmp_path, capsys):
    assert replay.main([str(good_bag), "--resimulate"]) == 0
    assert "IDENTICAL" in capsys.readouterr().out


# --- metadata.yaml ----------------------------------------------------------------------------

def edited(change):
    """A metadata.yaml damage: change(info) edits the parsed ``rosbag2_bagfile_information``."""
    def damage(text: str) -> str:
        document = yaml.safe_load(text)
        change(document[ROOT])
        return yaml.safe_dump(document, sort_keys=False)
    return damage


def setting(path, value):
    """Set info[path...] = value (a missing last key is added)."""
    def change(info):
        node = info
        for part in path[:-1]:
            node = node[part]
        node[path[-1]] = value
    return change


def removing(key):
    return lambda info: info.pop(key)


def keyed(key):
    return ROOT if key is None else f"{ROOT}.{key}"


FILE = "bag_0.mcap"
METADATA_YAML = [  # (case id, damage: text → text, key after "metadata.yaml: ", problem)
    ("path list for path", edited(setting(["relative_file_paths"], [[FILE]])),
     keyed("relative_file_paths[0]"), "expected a string"),
    ("paths a string", edited(setting(["relative_file_paths"], FILE)), keyed("relative_file_paths"),
     "expected a list"),
    ("paths a mapping", edited(setting(["relative_file_paths"], {FILE: 1})),
     keyed("relative_file_paths"), "expected a list"),
    ("paths empty", edited(setting(["relative_file_paths"], [])), keyed("relative_file_paths"),
     "at least 1"),
    ("paths null", edited(setting(["relative_file_paths"], None)), keyed("relative_file_paths"),
     "got null"),
    ("path number", edited(setting(["relative_file_paths"], [7])), keyed("relative_file_paths[0]"),
     "expected a string"),
    ("path empty", edited(setting(["relative_file_paths"], [""])), keyed("relative_file_paths[0]"),
     "name of a file"),
    ("path dot dot", edited(setting(["relative_file_paths"], [".."])),
     keyed("relative_file_paths[0]"), "name of a file"),
    ("path NUL", edited(setting(["relative_file_paths"], ["a\x00b.mcap"])),
     keyed("relative_file_paths[0]"), "name of a file"),
    ("path too long", edited(setting(["relative_file_paths"], ["x" * 5000])),
     keyed("relative_file_paths[0]"), "longer than"),
    ("path listed twice", edited(setting(["relative_file_paths"], [FILE, FILE])),
     keyed("relative_file_paths[1]"), "listed twice"),
    ("path missing file", edited(setting(["relative_file_paths"], ["other.mcap"])), "other.mcap",
     "listed in metadata.yaml but missing"),
    ("too many paths", edited(setting(["relative_file_paths"], [FILE] * 10_001)),
     keyed("relative_file_paths"), "at most 10000"),
    ("paths missing", edited(removing("relative_file_paths")), keyed("relative_file_paths"),
     "missing"),
    ("version missing", edited(removing("version")), keyed("version"), "missing"),
    ("version newer", edited(setting(["version"], 10)), keyed("version"), "must be in [1, 9]"),
    ("version zero", edited(setting(["version"], 0)), keyed("version"), "must be in [1, 9]"),
    ("version string", edited(setting(["version"], "9")), keyed("version"), "expected an integer"),
    ("version float", edited(setting(["version"], 9.0)), keyed("version"), "expected an integer"),
    ("version bool", edited(setting(["version"], True)), keyed("version"), "expected an integer"),
    ("version huge", edited(setting(["version"], 10**40)), keyed("version"), "expected an integer"),
    ("storage other", edited(setting(["storage_identifier"], "sqlite3")), "bag",
     "storage_identifier 'sqlite3'"),
    ("storage list", edited(setting(["storage_identifier"], ["mcap"])), keyed("storage_identifier"),
     "expected a string"),
    ("storage missing", edited(removing("storage_identifier")), keyed("storage_identifier"),
     "missing"),
    ("unknown key", edited(setting(["colour"], "red")), keyed("colour"), "unknown key"),
    ("count negative", edited(setting(["message_count"], -1)), keyed("message_count"),
     "must be in"),
    ("count float", edited(setting(["message_count"], 1.5)), keyed("message_count"),
     "expected an integer"),
    ("count past int64", edited(setting(["message_count"], 2**63)), keyed("message_count"),
     "must be in"),
    ("count text", edited(setting(["message_count"], "many")), keyed("message_count"),
     "expected an integer"),
    ("duration negative", edited(setting(["duration", "nanoseconds"], -5)),
     keyed("duration.nanoseconds"), "must be in"),
    ("duration scalar", edited(setting(["duration"], 5)), keyed("duration"), "expected a mapping"),
    ("duration unknown key", edited(setting(["duration", "seconds"], 5)), keyed("duration.seconds"),
     "unknown key"),
    ("duration empty", edited(setting(["duration"], {})), keyed("duration.nanoseconds"), "missing"),
    ("start float", edited(setting(["starting_time", "nanoseconds_since_epoch"], 1e30)),
     keyed("starting_time.nanoseconds_since_epoch"), "expected an integer"),
    ("start null", edited(setting(["starting_time"], None)), keyed("starting_time"), "got null"),
    ("topics mapping", edited(setting(["topics_with_message_count"], {})),
     keyed("topics_with_message_count"), "expected a list"),
    ("topic name list",
     edited(setting(["topics_with_message_count", 0, "topic_metadata", "name"], ["x"])),
     keyed("topics_with_message_count[0].topic_metadata.name"), "expected a string"),
    ("topic type missing",
     edited(lambda info: info["topics_with_message_count"][0]["topic_metadata"].pop("type")),
     keyed("topics_with_message_count[0].topic_metadata.type"), "missing"),
    ("topic unknown key",
     edited(setting(["topics_with_message_count", 1, "topic_metadata", "colour"], 1)),
     keyed("topics_with_message_count[1].topic_metadata.colour"), "unknown key"),
    ("topic qos number",
     edited(setting(["topics_with_message_count", 0, "topic_metadata", "offered_qos_profiles"], 5)),
     keyed("topics_with_message_count[0].topic_metadata.offered_qos_profiles"), "expected a list"),
    ("topic qos list of numbers",
     edited(setting(["topics_with_message_count", 0, "topic_metadata", "offered_qos_profiles"],
                    [5])),
     keyed("topics_with_message_count[0].topic_metadata.offered_qos_profiles[0]"),
     "expected a mapping"),
    ("topic count text", edited(setting(["topics_with_message_count", 2, "message_count"], "3")),
     keyed("topics_with_message_count[2].message_count"), "expected an integer"),
    ("topic entry a string", edited(setting(["topics_with_message_count", 0], "/odom")),
     keyed("topics_with_message_count[0]"), "expected a mapping"),
    ("topic metadata missing",
     edited(lambda info: info["topics_with_message_count"][0].pop("topic_metadata")),
     keyed("topics_with_message_count[0].topic_metadata"), "missing"),
    ("files path list", edited(setting(["files", 0, "path"], [FILE])), keyed("files[0].path"),
     "expected a string"),
    ("files count text", edited(setting(["files", 0, "message_count"], "many")),
     keyed("files[0].message_count"), "expected an integer"),
    ("files duration list", edited(setting(["files", 0, "duration"], [1])),
     keyed("files[0].duration"), "expected a mapping"),
    ("files entry null", edited(setting(["files", 0], None)), keyed("files[0]"), "got null"),
    ("files a string", edited(setting(["files"], FILE)), keyed("files"), "expected a list"),
    ("compression null", edited(setting(["compression_format"], None)), keyed("compression_format"),
     "got null"),
    ("compression number", edited(setting(["compression_mode"], 1)), keyed("compression_mode"),
     "expected a string"),
    ("custom data list value", edited(setting(["custom_data"], {"a": [1]})), keyed("custom_data.a"),
     "expected a string"),
    ("custom data list", edited(setting(["custom_data"], [1])), keyed("custom_data"),
     "expected a mapping"),
    ("custom data number key", edited(setting(["custom_data"], {1: "x"})), keyed("custom_data"),
     "expected a string"),
    ("distro mapping", edited(setting(["ros_distro"], {})), keyed("ros_distro"),
     "expected a string"),
    ("document a list", lambda text: "- 1\n- 2\n", "metadata.yaml", "expected a mapping"),
    ("document empty", lambda text: "", "metadata.yaml", "got null"),
    ("document a number", lambda text: "3\n", "metadata.yaml", "expected a mapping"),
    ("root missing", lambda text: "other: {}\n", "other", "unknown key"),
    ("root a list", lambda text: f"{ROOT}: [1]\n", ROOT, "expected a mapping"),
    ("root twice", lambda text: text + text.splitlines()[0] + "\n", ROOT, "duplicate key"),
    ("duplicate inner key",
     lambda text: text.replace("  version: 9\n", "  version: 9\n  version: 9\n"), "version",
     "duplicate key"),
    ("alias bomb", lambda text: ALIAS_BOMB, "metadata.yaml", "expands to more than"),
    ("recursive alias", lambda text: "a: &a [*a]\n", "metadata.yaml", "recursive alias"),
    ("nesting 3000", lambda text: "[" * 3000 + "]" * 3000, "metadata.yaml", "nested deeper than"),
    ("huge integer", lambda text: text.replace("  version: 9", "  version: " + "9" * 5000),
     keyed("version"), "expected an integer"),
    ("larger than 1 MiB", lambda text: text + "#" * (1 << 20), "metadata.yaml", "larger than"),
    ("not YAML", lambda text: text + "\n  ]: [\n", "metadata.yaml", "not valid YAML"),
    ("tab indent", lambda text: text.replace("  version", "\tversion", 1), "metadata.yaml",
     "not valid YAML"),
    ("YAML 1.1 octal version", lambda text: text.replace("  version: 9", "  version: 011"),
     keyed("version"), "must be in [1, 9]"),
    ("python tag", lambda text: "!!python/object:os.system {}\n", "metadata.yaml",
     "not valid YAML"),
]


@pytest.mark.parametrize("damage, key, problem", [case[1:] for case in METADATA_YAML],
                         ids=[case[0] for case in METADATA_YAML])
def test_damaged_metadata_yaml_is_one_line_naming_the_key(good_bag, tmp_path, capsys, damage, key,
                                                          problem):
    bag = tmp_path / "bag"
    shutil.copytree(good_bag, bag)
    metadata = bag / "metadata.yaml"
    metadata.write_text(damage(metadata.read_text()), encoding="utf-8")
    for argv in commands(bag, tmp_path / "out"):
        line = refusal(argv, capsys)
        assert key in line and problem in line, line
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("link", [os.link, os.symlink])
def test_a_file_listed_again_under_a_link_is_one_line(good_bag, tmp_path, capsys, link):
    """The same .mcap under a second name (a hard or symbolic link) would play every message
    twice: refused as the name listed twice is."""
    bag = tmp_path / "bag"
    shutil.copytree(good_bag, bag)
    link(bag / FILE, bag / "again.mcap")
    metadata = bag / "metadata.yaml"
    metadata.write_text(edited(setting(["relative_file_paths"], [FILE, "again.mcap"]))(
        metadata.read_text()), encoding="utf-8")
    for argv in commands(bag, tmp_path / "out"):
        line = refusal(argv, capsys)
        assert keyed("relative_file_paths[1]") in line, line
        assert f"again.mcap is {FILE} again (a link to it)" in line, line


def special_metadata(tmp_path: Path, kind: str) -> Path:
    if kind == "fifo":
        os.mkfifo(tmp_path / "metadata.yaml")
    elif kind == "directory":
        (tmp_path / "metadata.yaml").mkdir()
    elif kind == "device":
        (tmp_path / "metadata.yaml").symlink_to("/dev/zero")
    elif kind == "binary":
        (tmp_path / "metadata.yaml").write_bytes(bytes(range(256)) * 4)
    elif kind == "unreadable":
        (tmp_path / "metadata.yaml").symlink_to(tmp_path / "nowhere")
    return tmp_path


@pytest.mark.parametrize("kind, problem",
                         [("fifo", "not a regular file"), ("directory", "not a regular file"),
                          ("device", "not a regular file"), ("binary", "not UTF-8"),
                          ("unreadable", "no such bag")])
def test_a_metadata_yaml_that_is_no_text_file_is_refused_without_reading(good_bag, tmp_path, capsys,
                                                                         kind, problem):
    bag = tmp_path / "bag"
    shutil.copytree(good_bag, bag)
    (bag / "metadata.yaml").unlink()
    special_metadata(bag, kind)
    if kind == "unreadable":   # a dangling metadata.yaml: no metadata, and the .mcap is read alone
        assert replay.main([str(bag), "--resimulate"]) == 0
        capsys.readouterr()
        return
    for argv in commands(bag, tmp_path / "out"):
        line = refusal(argv, capsys)
        assert "metadata.yaml" in line and problem in line, line


# --- the mobile_manip_sim map (what a re-run trusts) ------------------------------------------

RUN = "mobile_manip_sim"
RUN_METADATA = [  # (case id, changes to the map (None removes), key, problem)
    ("dt 1e308", {"dt": "1e308"}, f"{RUN}.dt", "must be in"),
    ("dt 1e-300", {"dt": "1e-300"}, f"{RUN}.dt", "must be in"),
    ("dt nan", {"dt": "nan"}, f"{RUN}.dt", "must be finite"),
    ("dt inf", {"dt": "inf"}, f"{RUN}.dt", "must be finite"),
    ("dt negative", {"dt": "-0.001"}, f"{RUN}.dt", "must be in"),
    ("dt zero", {"dt": "0"}, f"{RUN}.dt", "must be in"),
    ("dt text", {"dt": "fast"}, f"{RUN}.dt", "expected a number"),
    ("dt empty", {"dt": ""}, f"{RUN}.dt", "expected a number"),
    ("dt missing", {"dt": None}, f"{RUN}.dt", "missing"),
    ("dt longer than a sample", {"dt": "0.1"}, f"{RUN}.dt", "longer than the sample interval"),
    ("rtol 1e-300", {"rtol": "1e-300"}, f"{RUN}.rtol", "must be in"),
    ("rtol 2", {"rtol": "2"}, f"{RUN}.rtol", "must be in"),
    ("atol 250 digits", {"atol": "9" * 250}, f"{RUN}.atol", "longer than 200"),
    ("atol 1e400", {"atol": "1e400"}, f"{RUN}.atol", "must be finite"),
    ("method unknown", {"integrator_method": "euler2"}, f"{RUN}.integrator_method",
     "unknown method"),
    ("method empty", {"integrator_method": ""}, f"{RUN}.integrator_method", "unknown method"),
    ("method missing", {"integrator_method": None}, f"{RUN}.integrator_method", "missing"),
    ("source unknown", {"source": "elsewhere"}, f"{RUN}.source", "expected node or simulate"),
    ("source missing", {"source": None}, f"{RUN}.source", "missing"),
    ("version missing", {"version": None}, f"{RUN}.version", "missing"),
    ("unknown key", {"colour": "red"}, f"{RUN}.colour", "unknown key"),
    ("duration missing", {"duration": None}, f"{RUN}.duration", "missing"),
    ("duration 1e308", {"duration": "1e308"}, f"{RUN}.duration", "must be in"),
    ("duration 1e9", {"duration": "1e9"}, f"{RUN}.duration", "must be in"),
    ("duration zero", {"duration": "0"}, f"{RUN}.duration", "must be in"),
    ("sample rate missing", {"sample_rate": None}, f"{RUN}.sample_rate", "missing"),
    ("sample rate 1e9", {"sample_rate": "1e9"}, f"{RUN}.sample_rate", "must be in"),
    ("samples beyond the limit",
     {"integrator_method": "dop853", "sample_rate": "1e6", "duration": "1e6"},
     f"{RUN}.sample_rate", "more than 1000000 samples"),
    ("steps beyond the limit", {"duration": "1e6", "dt": "1e-6", "sample_rate": "1e-6"},
     f"{RUN}.duration", "more than 10000000 steps"),
    ("sample rate negative", {"sample_rate": "-20"}, f"{RUN}.sample_rate", "must be in"),
    ("value too long", {"scene_name": "x" * 201}, f"{RUN}.scene_name", "longer than 200"),
    ("node source without its rate", {"source": "node"}, f"{RUN}.publish_rate", "missing"),
    ("controller rate negative", {"controller_rate": "-1.0"}, f"{RUN}.controller_rate",
     "must be in"),
    ("controller rate 2e6", {"controller_rate": "2e6"}, f"{RUN}.controller_rate", "must be in"),
    ("controller rate text", {"controller_rate": "fast"}, f"{RUN}.controller_rate",
     "expected a number"),
    # an arm controller's settings (node runs not in effort mode)
    ("arm controller unknown", {"arm_controller": "torque"}, f"{RUN}.arm_controller",
     "unknown mode 'torque'"),
    ("arm gains missing", {"arm_controller": "position"}, f"{RUN}.arm_kp", "missing"),
    ("arm gains text", {"arm_controller": "position", "arm_kp": "stiff", "arm_ki": "0.0",
                        "arm_kd": "1.0"}, f"{RUN}.arm_kp", "expected numbers"),
    ("arm gain negative", {"arm_controller": "position", "arm_kp": "-1.0", "arm_ki": "0.0",
                           "arm_kd": "1.0"}, f"{RUN}.arm_gains.kp", "expected numbers in"),
    ("arm feedforward unknown", {"arm_controller": "position", "arm_kp": "1.0", "arm_ki": "0.0",
                                 "arm_kd": "1.0", "arm_feedforward": "magic"},
     f"{RUN}.arm_feedforward", "unknown feedforward"),
]


@pytest.mark.parametrize("changes, key, problem", [case[1:] for case in RUN_METADATA],
                         ids=[case[0] for case in RUN_METADATA])
def test_damaged_run_metadata_is_one_line_naming_the_key(good_bag, tmp_path, capsys, changes, key,
                                                         problem):
    recorded = open_bag(good_bag).metadata()[RUN]
    damaged = {name: value for name, value in {**recorded, **changes}.items() if value is not None}
    rewrite_bag(good_bag, tmp_path / "bag", metadata={RUN: damaged})
    line = refusal((replay, str(tmp_path / "bag"), "--resimulate"), capsys)
    assert f"error: {key}: " in line and problem in line, line


@pytest.fixture(scope="module")
def controlled_bag(tmp_path_factory) -> Path:
    """A headless run of the paper scene whose arm is held by its position controller at
    100 Hz (not the default rate) while the wheels drive the base: the efforts change at
    every update."""
    from mobile_manip_sim.scene.loading import parse_scene
    doc = copy.deepcopy(load_scene().document)
    doc["controller"] = {"arm_controller": "position", "rate": 100}
    doc["efforts"] = {"wheels": [0.1, 0.2]}
    return recorded_run(tmp_path_factory.mktemp("controlled") / "bag",
                        parse_scene(doc, "controlled"))


def test_the_bag_names_its_controller_rate_and_the_re_run_takes_it(controlled_bag, tmp_path,
                                                                  capsys):
    """The metadata names the rate the run used; the re-run runs its controllers at the bag's
    rate (another rate in the metadata: the states differ, status 1); a bag naming none is
    re-run at the scene's rate with a note saying so."""
    recorded = open_bag(controlled_bag).metadata()[RUN]
    assert recorded["controller_rate"] == "100.0"
    assert replay.main([str(controlled_bag), "--resimulate"]) == 0
    assert "IDENTICAL" in capsys.readouterr().out
    rewrite_bag(controlled_bag, tmp_path / "other", metadata={
        RUN: {**recorded, "controller_rate": "1000.0"}})
    assert replay.main([str(tmp_path / "other"), "--resimulate"]) == 1
    capsys.readouterr()
    rewrite_bag(controlled_bag, tmp_path / "none", metadata={
        RUN: {key: value for key, value in recorded.items() if key != "controller_rate"}})
    assert replay.main([str(tmp_path / "none"), "--resimulate"]) == 0
    out = capsys.readouterr().out
    assert "note: the bag names no controller_rate" in out and "100 Hz" in out
    assert "IDENTICAL" in out


def test_a_bag_without_a_controller_needs_no_controller_rate(good_bag, tmp_path, capsys):
    recorded = open_bag(good_bag).metadata()[RUN]
    rewrite_bag(good_bag, tmp_path / "none", metadata={
        RUN: {key: value for key, value in recorded.items() if key != "controller_rate"}})
    assert replay.main([str(tmp_path / "none"), "--resimulate"]) == 0
    out = capsys.readouterr().out
    assert "IDENTICAL" in out and "controller_rate" not in out


def test_run_metadata_missing_entirely_is_one_line(good_bag, tmp_path, capsys):
    rewrite_bag(good_bag, tmp_path / "bag", metadata={RUN: None})
    line = refusal((replay, str(tmp_path / "bag"), "--resimulate"), capsys)
    assert "not recorded by mobile_manip_sim" in line


# --- the embedded scene and impacts -----------------------------------------------------------

SCENE_TEXT = load_scene().to_yaml()
SCENE = [  # (case id, scene.yaml bytes, problem)
    ("alias bomb", ALIAS_BOMB.encode(), "expands to more than"),
    ("duplicate key", (SCENE_TEXT + "duration: 2.0\n").encode(), "duration: duplicate key"),
    ("nesting 3000", ("robot: " + "[" * 3000 + "]" * 3000).encode(), "nested deeper than"),
    ("not UTF-8", b"name: caf\xe9\n", "not UTF-8"),
    ("huge integer", SCENE_TEXT.replace("duration: 1.5", "duration: " + "1" * 400).encode(),
     "duration: number too large"),
    ("null method", SCENE_TEXT.replace("method: dop853", "method: null").encode(),
     "integrator.method: expected a value, got null"),
    ("radius 1e-300", SCENE_TEXT.replace("wheel_radius: 0.08", "wheel_radius: 1.0e-300").encode(),
     "robot.base.wheel_radius: must be in"),
    ("mass 1e308", SCENE_TEXT.replace("mass: 6.64", "mass: 1.0e308").encode(),
     "robot.base.mass: must be in"),
    ("duration 1e308", SCENE_TEXT.replace("duration: 1.5", "duration: 1.0e308").encode(),
     "duration: must be in"),
    ("robot missing", b"name: x\n", "robot: missing"),
    ("a list", b"- 1\n", "expected a mapping"),
    ("empty", b"", "empty"),
    ("larger than 1 MiB", SCENE_TEXT.encode() + b"#" * (1 << 20), "larger than"),
    ("1000 links", yaml.safe_dump({**yaml.safe_load(SCENE_TEXT), "robot": {
        **yaml.safe_load(SCENE_TEXT)["robot"],
        "arm": {"links": [yaml.safe_load(SCENE_TEXT)["robot"]["arm"]["links"][0]] * 1000}}}
    ).encode(),
     "robot.arm.links: at most 64 entries"),
]


@pytest.mark.parametrize("text, problem", [case[1:] for case in SCENE],
                         ids=[case[0] for case in SCENE])
def test_a_damaged_embedded_scene_is_one_line(good_bag, tmp_path, capsys, text, problem):
    rewrite_bag(good_bag, tmp_path / "bag", attachments={"scene.yaml": text})
    for argv in commands(tmp_path / "bag", tmp_path / "out"):
        line = refusal(argv, capsys)
        assert "scene.yaml" in line or problem.startswith(("robot", "duration", "integrator")), line
        assert problem in line, line


IMPACT = {"time": 0.1, "link": 1, "stop": "lower", "ld_before": -0.5, "ld_after": 0.0,
          "energy_lost": 0.1, "resting": False}


def impact(**changes):
    record = {**IMPACT, **changes}
    return [{key: value for key, value in record.items() if value is not None}]


IMPACTS = [  # (case id, impacts.json bytes, key, problem)
    ("not JSON", b"[{", "impacts.json", "not valid JSON"),
    ("nesting 100000", b"[" * 100_000 + b"]" * 100_000, "impacts.json", "nested too deeply"),
    ("not UTF-8", b"[\xff]", "impacts.json", "not UTF-8"),
    ("a mapping", b'{"time": 1}', "impacts.json", "expected a list"),
    ("huge integer", b"[" + b"9" * 5000 + b"]", "impacts.json", "not valid JSON"),
    ("record a list", b"[[1, 2]]", "impact 1", "expected a mapping"),
    ("field missing", impact(stop=None), "impact 1", "missing stop"),
    ("link beyond the arm", impact(link=99), "impact 1.link", "must be in [1, 2]"),
    ("link zero", impact(link=0), "impact 1.link", "must be in [1, 2]"),
    ("link float", impact(link=1.5), "impact 1.link", "expected an integer"),
    ("link infinite",
     b'[{"time": 0.1, "link": Infinity, "stop": "lower", "ld_before": 0, "ld_after": 0, '
     b'"energy_lost": 0, "resting": false}]', "impact 1.link", "expected an integer"),
    ("time NaN", b'[{"time": NaN, "link": 1, "stop": "lower", "ld_before": 0, "ld_after": 0, '
                 b'"energy_lost": 0, "resting": false}]', "impact 1.time", "must be finite"),
    ("time 1e400", b'[{"time": 1e400, "link": 1, "stop": "lower", "ld_before": 0, "ld_after": 0, '
                   b'"energy_lost": 0, "resting": false}]', "impact 1.time", "must be finite"),
    ("time text", impact(time="soon"), "impact 1.time", "expected a number"),
    ("speed list", impact(ld_before=[1]), "impact 1.ld_before", "expected a number"),
    ("stop middle", impact(stop="middle"), "impact 1.stop", "expected lower or upper"),
    ("stop list", impact(stop=["lower"]), "impact 1.stop", "expected lower or upper"),
    ("resting number", impact(resting=5), "impact 1.resting", "expected true or false"),
    ("resting null", b'[{"time": 0.1, "link": 1, "stop": "lower", "ld_before": 0, "ld_after": 0, '
                      b'"energy_lost": 0, "resting": null}]', "impact 1.resting",
     "expected true or false"),
]


@pytest.mark.parametrize("data, key, problem", [case[1:] for case in IMPACTS],
                         ids=[case[0] for case in IMPACTS])
def test_damaged_impacts_are_one_line_naming_the_record(good_bag, tmp_path, capsys, data, key,
                                                        problem):
    import json

    data = data if isinstance(data, bytes) else json.dumps(data).encode()
    rewrite_bag(good_bag, tmp_path / "bag", attachments={"impacts.json": data})
    line = refusal((plot, str(tmp_path / "bag"), "--out", str(tmp_path / "out")), capsys)
    assert key in line and problem in line, line
    assert not (tmp_path / "out").exists()


# --- the recorded QoS (what playback offers its subscribers) ----------------------------------

QOS = [  # (offered_qos_profiles text, key, problem)
    (ALIAS_BOMB, "/odom: offered_qos_profiles", "expands to more than"),
    ("- depth: 1\n  depth: 2\n", "depth", "duplicate key"),
    ("- {depth: -1}\n", "/odom: offered_qos_profiles[0].depth", "must be in"),
    ("- {depth: 1.5}\n", "/odom: offered_qos_profiles[0].depth", "expected an integer"),
    ("- {depth: 100000000000}\n", "/odom: offered_qos_profiles[0].depth", "must be in"),
    ("- {depth: deep}\n", "/odom: offered_qos_profiles[0].depth", "expected an integer"),
    ("- 5\n", "/odom: offered_qos_profiles[0]", "expected a mapping"),
    ("depth: 5\n", "/odom: offered_qos_profiles", "expected a list"),
    ("[" * 3000, "/odom: offered_qos_profiles", "nested deeper than"),
    ("- {depth: 1}\n" * 101, "/odom: offered_qos_profiles", "at most 100 entries"),
]


@pytest.mark.parametrize("offered, key, problem", QOS)
def test_damaged_recorded_qos_is_one_line_naming_the_topic(offered, key, problem):
    with pytest.raises(UserError) as caught:
        qos_profile(offered, "/odom")
    message = str(caught.value)
    assert "\n" not in message and key in message and problem in message, message


def test_recorded_qos_of_our_recorder_and_of_none_is_read():
    from mobile_manip_sim.recording.recorder import topic_qos

    assert qos_profile(topic_qos("/odom"), "/odom").depth == 100
    assert qos_profile("", "/odom").depth == 10
    assert qos_profile(None, "/odom").depth == 10


def test_metadata_yaml_schema_accepts_what_our_writer_writes(good_bag):
    document = schema.load_yaml(good_bag / "metadata.yaml")
    info = bag_information(copy.deepcopy(document))
    assert info["relative_file_paths"] == [FILE] and info["version"] == 9


def test_a_node_bag_whose_states_jump_far_ahead_is_refused_before_simulating(good_bag, tmp_path,
                                                                             capsys):
    """A crafted stamp gap in a node's bag (which has no duration) would ask the re-simulation
    for 2·10⁹ segments: refused at once by the work limits `simulate` applies, naming the stamp."""
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import JointState

    def jump(topic, data, index):
        if topic != "/joint_states" or index == 0:
            return data
        message = deserialize_message(data, JointState)
        message.header.stamp.sec = 10 ** 8
        return serialize_message(message)
    run = dict(open_bag(good_bag).metadata()[RUN])
    run.update(source="node", publish_rate=run.pop("sample_rate"))
    del run["duration"]
    rewrite_bag(good_bag, tmp_path / "bag", jump, metadata={RUN: run})
    assert "/joint_states stamp" in refusal((replay, str(tmp_path / "bag"), "--resimulate"), capsys)
