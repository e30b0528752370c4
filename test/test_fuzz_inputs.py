"""Fuzzing the inputs with hypothesis (issue 13): scenes (as documents and as raw YAML text) and
bag metadata. Whatever comes in, the outcome is a valid result or one `UserError` whose message
is one short line naming a key — never another exception, never a long wait.

The default run is derandomized (the same cases every time, as CI needs) and small; ``-m slow``
runs many more random cases.
"""
import copy
import time

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from engine_cases import paper_doc
from mobile_manip_sim import schema
from mobile_manip_sim.errors import UserError
from mobile_manip_sim.recording import bag_format, rosbag2_metadata
from mobile_manip_sim.scene import parse_scene, scene_from_text

PAPER = paper_doc()
PAPER_TEXT = yaml.safe_dump(PAPER, sort_keys=False)
BOUND_S = 2.0          # wall seconds any one input may take to be accepted or refused

FAST = settings(max_examples=150, derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
LONG = settings(max_examples=3000, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

scalars = st.one_of(
    st.none(), st.booleans(), st.integers(), st.integers(min_value=10**300, max_value=10**320),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([1e308, -1e308, 1e-300, 0.0]),
    st.text(max_size=20), st.sampled_from(["rk4", "impulse", "dop853", "q1", "l2"]))
values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=6), st.dictionaries(st.text(max_size=8), inner, max_size=4)),
    max_leaves=20)


def paths(node, prefix=()):
    yield prefix
    if isinstance(node, dict):
        for key, value in node.items():
            yield from paths(value, prefix + (key,))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            yield from paths(value, prefix + (i,))


def mutate(doc, path, value, delete):
    doc = copy.deepcopy(doc)
    node = doc
    for part in path[:-1]:
        node = node[part]
    if delete and isinstance(node, dict):
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return doc


def outcome(call):
    """Run `call`; a UserError must be one short line with a key. Returns the error or None."""
    start = time.perf_counter()
    try:
        call()
        error = None
    except UserError as caught:
        error = caught
        message = str(caught)
        assert "\n" not in message and len(message) <= 300, message
        assert caught.key, message
    assert time.perf_counter() - start < BOUND_S
    return error


def mutations_of(doc):
    """Lists of up to four (path, value, delete) changes to `doc`."""
    return st.lists(st.tuples(st.sampled_from([p for p in paths(doc) if p]), values, st.booleans()),
                    min_size=1, max_size=4)


def mutated(doc, changes):
    for path, value, delete in changes:
        try:
            doc = mutate(doc, path, value, delete)
        except (KeyError, IndexError, TypeError):  # an earlier change removed the parent
            continue
    return doc


def check_mutated_scene(changes):
    doc = mutated(PAPER, changes)
    outcome(lambda: parse_scene(doc))


def check_scene_text(text):
    outcome(lambda: scene_from_text(text, "scene.yaml"))


def check_yaml_of_values(value):
    text = yaml.safe_dump(value)
    outcome(lambda: scene_from_text(text, "scene.yaml"))


splices = st.tuples(st.integers(0, len(PAPER_TEXT)), st.integers(0, 40),
                    st.text(alphabet=st.sampled_from(list("&*[]{}:-,'\"!#|>%@`\t\n ~?.0123456789eE")
                                                     + ["\x00", "\ufeff", "<"]), max_size=30))


def check_spliced_text(edit):
    at, cut, insert = edit
    check_scene_text(PAPER_TEXT[:at] + insert + PAPER_TEXT[at + cut:])


metadata = st.dictionaries(
    st.one_of(st.sampled_from(bag_format.RUN_METADATA_KEYS), st.text(max_size=10)),
    st.one_of(st.text(max_size=30), st.sampled_from(["1e308", "nan", "-1", "1e-300", "0.001", "rk4",
                                                     "simulate", "node"]), values),
    max_size=12)


def check_metadata(doc):
    outcome(lambda: bag_format.checked_run_metadata(doc))


def check_metadata_yaml(text):
    outcome(lambda: bag_format.checked_run_metadata(schema.load_yaml(text, what="metadata.yaml")))


BAG_INFORMATION = {"rosbag2_bagfile_information": {   # a metadata.yaml as BagWriter writes it
    "version": 9, "storage_identifier": "mcap", "duration": {"nanoseconds": 200000000},
    "starting_time": {"nanoseconds_since_epoch": 0}, "message_count": 24,
    "topics_with_message_count": [{"topic_metadata": {
        "name": "/odom", "type": "nav_msgs/msg/Odometry", "serialization_format": "cdr",
        "offered_qos_profiles": "- history: 1\n  depth: 100\n", "type_description_hash": "RIHS01_00"},
        "message_count": 5}],
    "compression_format": "", "compression_mode": "", "relative_file_paths": ["bag_0.mcap"],
    "files": [{"path": "bag_0.mcap", "starting_time": {"nanoseconds_since_epoch": 0},
               "duration": {"nanoseconds": 200000000}, "message_count": 24}],
    "custom_data": {}, "ros_distro": "jazzy"}}


def check_bag_information(changes):
    doc = mutated(BAG_INFORMATION, changes)
    outcome(lambda: rosbag2_metadata.bag_information(doc))
    outcome(lambda: rosbag2_metadata.bag_information(schema.load_yaml(yaml.safe_dump(doc), what="metadata.yaml")))


def fuzz(settings, check, strategy) -> int:
    """Run `check` on hypothesis examples of `strategy` (each check asserts through `outcome`);
    returns how many examples it saw."""
    seen = []

    def counted(value):
        seen.append(None)
        check(value)
    settings(given(strategy)(counted))()
    return len(seen)


CHECKS = [
    (check_mutated_scene, mutations_of(PAPER)), (check_scene_text, st.text(max_size=200)),
    (check_yaml_of_values, values), (check_spliced_text, splices), (check_metadata, metadata),
    (check_metadata_yaml, st.text(max_size=200)), (check_bag_information, mutations_of(BAG_INFORMATION)),
]


@pytest.mark.parametrize("check, strategy", CHECKS, ids=[c.__name__ for c, _ in CHECKS])
def test_fuzz_fixed_seed(check, strategy):
    assert fuzz(FAST, check, strategy) >= 100   # the examples really ran (each one checked)


@pytest.mark.slow
@pytest.mark.parametrize("check, strategy", CHECKS, ids=[c.__name__ for c, _ in CHECKS])
def test_fuzz_long(check, strategy):
    assert fuzz(LONG, check, strategy) >= 1000


def test_the_fuzzer_can_fail():
    """The checks are not vacuous: an input known to be bad is refused, and a check that
    accepted anything other than a UserError would see it."""
    assert outcome(lambda: parse_scene(mutate(PAPER, ("duration",), 1e308, False))) is not None
    assert outcome(lambda: rosbag2_metadata.bag_information(BAG_INFORMATION)) is None
    assert outcome(lambda: rosbag2_metadata.bag_information(mutate(
        BAG_INFORMATION, ("rosbag2_bagfile_information", "custom_data"), [1], False))) is not None
    with pytest.raises(AssertionError):
        outcome(lambda: (_ for _ in ()).throw(UserError("k", "two\nlines")))
    with pytest.raises(ZeroDivisionError):
        outcome(lambda: 1 / 0)
