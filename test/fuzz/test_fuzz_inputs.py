"""Fuzzing the inputs with hypothesis: scenes (as documents and as raw YAML text) and
bag metadata; and explicit YAML tags and blank values in every YAML reader (scene,
sweep spec, params file, bag metadata), blank or odd ``-p`` values for every node parameter,
mutated sweep specs, run-time node parameters at their extremes, and huge finite commands for
every method right after a reset (in their own process: test/helpers/huge_commands.py). And
what hostile peers send: JointTrajectory bytes read without rclpy (`ros.trajectory_wire`),
message type and topic names from bags, scene names drawn by `plot`, and the node's frame,
prefix, record and host parameters.

Whatever comes in, the outcome is a valid result or one `UserError` whose message
is one short line naming a key — never another exception, never a long wait.

The default run is derandomized (the same cases every time, as CI needs) and small; ``-m slow``
runs many more random cases.
"""
import copy
import json
import math
import random
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from engine_cases import paper_doc
from huge_commands import COMMANDS, check_huge_command
from mobile_manip_sim.node import arguments as node_arguments
from mobile_manip_sim.node import parameters as node_parameters
from mobile_manip_sim.node.loop import MAX_WAIT
from mobile_manip_sim.node.parameters import MIN_REAL_TIME_FACTOR, PARAMETERS
from mobile_manip_sim.recording import bag_format, rosbag2_metadata
from mobile_manip_sim.scene import schema
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.loading import parse_scene, scene_from_text
from mobile_manip_sim.scene.methods import METHODS
from mobile_manip_sim.sweep.spec import parse_spec
from test_stepping_loop import Harness
from waiting import no_hang

PAPER = paper_doc()
PAPER_TEXT = yaml.safe_dump(PAPER, sort_keys=False)

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
    try:
        with no_hang("accepting or refusing one input"):
            call()
        error = None
    except UserError as caught:
        error = caught
        message = str(caught)
        assert "\n" not in message and len(message) <= 300, message
        assert caught.key, message
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
        "offered_qos_profiles": "- history: 1\n  depth: 100\n",
        "type_description_hash": "RIHS01_00"},
        "message_count": 5}],
    "compression_format": "", "compression_mode": "", "relative_file_paths": ["bag_0.mcap"],
    "files": [{"path": "bag_0.mcap", "starting_time": {"nanoseconds_since_epoch": 0},
               "duration": {"nanoseconds": 200000000}, "message_count": 24}],
    "custom_data": {}, "ros_distro": "jazzy"}}


def check_bag_information(changes):
    doc = mutated(BAG_INFORMATION, changes)
    outcome(lambda: rosbag2_metadata.bag_information(doc))
    outcome(lambda: rosbag2_metadata.bag_information(
        schema.load_yaml(yaml.safe_dump(doc), what="metadata.yaml")))


# --- more classes: YAML tags, blank values, sweep specs, node parameters, huge commands ---

SWEEP = {"duration": 0.05, "time_limit": 60, "grid": {
    "integrator.method": ["rk4", "dop853"], "robot.arm.links[0].mass_per_length": [0.9, 1.1]},
    "random": {"count": 4, "seed": 7, "vary": {"initial.velocity[2]": {"normal": [0.0, 0.1]}}}}
PARAMS_FILE = {"/**": {"ros__parameters": {
    name: spec.default for name, spec in PARAMETERS.items() if "." not in name}}}
PLACE = "PLACEHOLDER_OF_THE_FUZZER"
TAGS = ["!!float", "!!int", "!!bool", "!!str", "!!null", "!!binary", "!!timestamp", "!!map",
        "!!seq", "!!set", "!!omap", "!!pairs", "!!merge", "!!value", "!!python/object:os.system",
        "!!python/name:os.system", "!foo", "!<tag:yaml.org,2002:float>", "!", "!!"]
tagged_scalars = st.tuples(
    st.sampled_from(TAGS),
    st.one_of(st.sampled_from(["abc", "1.5", "1", "1e308", "1e400", ".nan", "-.inf", "0x1F",
                               "0o17", "0b1", "yes", "~", "''", "[]", "{}", "2001-12-14", "1_000",
                               "+1", "-0", ".5", "5.", "1:30", "True", "null", "\"\""]),
              st.text(alphabet=st.sampled_from(list("0123456789.eE+-_:xnaAbl ")), max_size=12)))


def sweep_check(doc):
    """parse_spec, and the runs themselves when there are few (a draw may overflow)."""
    spec = parse_spec(doc)
    if math.prod(len(v) for v in spec.grid.values()) * max(1, spec.count) <= 1000:
        spec.runs()


def params_file_check(text):
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "params.yaml"
        path.write_text(text)
        node_arguments.check(["--ros-args", "--params-file", str(path)])


# what each YAML document is, and the loader that reads it (as its executable does)
READERS = {
    "scene": (PAPER, lambda text: scene_from_text(text, "scene.yaml")),
    "sweep": (SWEEP, lambda text: sweep_check(schema.load_yaml(text, what="sweep.yaml"))),
    "params": (PARAMS_FILE, params_file_check),
    "metadata": (BAG_INFORMATION["rosbag2_bagfile_information"], lambda text: (
        rosbag2_metadata.bag_information({"rosbag2_bagfile_information": schema.load_yaml(
            text, what="metadata.yaml")}))),
}


def with_tag(doc, path, tag, text) -> str:
    """The YAML of `doc` with the value at `path` written as ``tag text``."""
    marked = mutate(doc, path, PLACE, False)
    dumped = yaml.safe_dump(marked, sort_keys=False)
    return dumped.replace(f"'{PLACE}'", PLACE).replace(PLACE, f"{tag} {text}")


def check_tags(case):
    reader, path_index, (tag, text) = case
    doc, read = READERS[reader]
    leaves = [p for p in paths(doc) if p]
    outcome(lambda: read(with_tag(doc, leaves[path_index % len(leaves)], tag, text)))


BLANKS = ["", " ", "\t", "  \t ", "''", '""', "~", "null"]


def check_blank_argument(case):
    """``-p NAME:=VALUE`` for every parameter, VALUE blank or odd: refused in one line, or
    handed to rcl (which then parses it), never a traceback."""
    name, value = case
    outcome(lambda: node_arguments.check(["--ros-args", "-p", f"{name}:={value}"]))


# --- `-p NAME:=VALUE` on to the declarations: what arguments.check hands to rcl ---------------
# rcl parses the value and rclpy declares it (type, range; node/declare.py); then the record
# (parameters.read), the integrator and arm controller built from it, and the QoS overrides
# (node/qos.py), as SimulatorNode.__init__ does before it builds the engine. A node per case, in
# one context of this process on a private domain (this host only).
QOS_TOPICS = ("/odom", "/joint_states")   # two the node publishes: Odometry, JointState
QOS_KEYS = [f"qos_overrides.{topic}.publisher.{policy}" for topic in (*QOS_TOPICS, "/elsewhere")
            for policy in ("history", "depth", "reliability")]
DECLARED_VALUES = [
    "[]", "[1.0, 2.0]", "[1.0, 2.0, 3.0, 4.0]", "[1, 2]", "[true]", "['a']", "[[1.0]]", "{}",
    "1e400", "-1e400", ".nan", ".inf", "1e308", "-1e308", "1e-300", "0", "-1", "1", "1.0", "0.0",
    "-0.0", "2147483648", "9223372036854775807", "9223372036854775808",
    "-9223372036854775809", "99999999999999999999", "true", "false", "yes", "keep_all",
    "keep_last", "best_effort", "reliable", "rk4", "radau", "position", "velocity", "effort",
    "none", "base", "0.0.0.0", "/odom", "null", "~", "a\nb", "[1.0,\n 2.0]", "1.0\r",
    "[1.0,\n'a']", "\n\x08"]   # rcl refused these two in a message of two lines
declared_arguments = st.tuples(
    st.sampled_from([*PARAMETERS, *QOS_KEYS]),
    st.one_of(st.sampled_from(DECLARED_VALUES), st.sampled_from(BLANKS), st.text(max_size=12)))
_declaring = {}   # the context (made at the first case, shut down at exit) and the robot


def declared_at_start_up(node) -> None:
    """What SimulatorNode.__init__ makes of ``node``'s parameters before the engine."""
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import JointState

    from mobile_manip_sim.engine.arm_control import for_robot
    from mobile_manip_sim.node import declare, qos
    from mobile_manip_sim.ros.topics import state_qos
    from mobile_manip_sim.scene.loading import make_integrator
    scene = _declaring["scene"]
    values = node_parameters.read(declare.declare(node))
    make_integrator(scene.integrator, values.method, values.dt, values.rtol, values.atol,
                    prefix="integrator")
    for_robot(values.arm_controller, scene.robot)
    for topic, kind in zip(QOS_TOPICS, (Odometry, JointState), strict=True):
        qos.publisher(node, kind, topic, state_qos())
    qos.check_unknown(node)


def check_declared_argument(case):
    """``-p NAME:=VALUE`` past arguments.check: refused in one line at start-up (rcl's parse
    as the node reports it, a declaration, the record, a QoS override) or taken — never
    another exception. Returns the refusal, or None."""
    import atexit

    import rclpy
    from rclpy.context import Context
    from rclpy.impl.implementation_singleton import rclpy_implementation

    from mobile_manip_sim.node.parameters import NODE_NAME
    from mobile_manip_sim.scene.loading import load_scene
    from ros_harness import on_domain, private_domain
    name, value = case
    argv = ["--ros-args", "-p", f"{name}:={value}"]
    error = outcome(lambda: node_arguments.check(argv))
    if error is not None:
        return error
    if not _declaring:
        context, domain = Context(), private_domain(100, 232)
        rclpy.init(context=context, domain_id=domain)
        atexit.register(rclpy.try_shutdown, context=context)
        _declaring.update(context=context, domain=domain, scene=load_scene(None))
    with on_domain(_declaring["domain"]):
        try:
            node = rclpy.create_node(NODE_NAME, context=_declaring["context"], cli_args=argv,
                                     start_parameter_services=False, enable_rosout=False)
        except rclpy_implementation.RCLInvalidROSArgsError:   # rcl refuses it: as the node says
            from mobile_manip_sim.node import shell
            error = outcome(lambda: shell._init(argv))
            assert error is not None, argv   # refused: nothing initialised, nothing to shut down
            return error
    try:
        return outcome(lambda: declared_at_start_up(node))
    finally:
        node.destroy_node()


def check_blank_in_yaml(case):
    reader, path_index, blank = case
    doc, read = READERS[reader]
    leaves = [p for p in paths(doc) if p]
    path = leaves[path_index % len(leaves)]
    outcome(lambda: read(with_tag(doc, path, "", blank) if blank.strip()
                         else yaml.safe_dump(mutate(doc, path, None, False))))


def check_sweep(changes):
    outcome(lambda: sweep_check(mutated(SWEEP, changes)))


sweep_values = st.one_of(values, st.sampled_from([1e9, 1e10, 10**12, -1, 0, 1e-300, 1e300]),
                         st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=12),
                         st.fixed_dictionaries({"uniform": st.lists(
                             st.floats(allow_nan=False, allow_infinity=True), min_size=2,
                             max_size=2)}))
sweep_changes = st.lists(st.tuples(st.sampled_from([p for p in paths(SWEEP) if p]
                                                   + [("sample_rate",), ("chunk",), ("scene",)]),
                                   sweep_values, st.booleans()), min_size=1, max_size=4)

DYNAMIC = [name for name, spec in PARAMETERS.items() if spec.dynamic]
extremes = st.one_of(
    st.sampled_from([0.0, -0.0, 5e-324, 1e-300, 1e-12, MIN_REAL_TIME_FACTOR,
                     math.nextafter(MIN_REAL_TIME_FACTOR, 0.0), 1.0, 1e4, 1e6, 1e308,
                     math.inf, -math.inf, math.nan]),
    st.floats(allow_nan=True, allow_infinity=True))


def check_run_time_parameter(case):
    """A change while the node runs, as the shell validates it (the declared range, then
    `value_problem`); an accepted one is honoured: the loop keeps publishing in waits of
    bounded length (`test_stepping_loop.Harness`, on a fake clock)."""
    name, value = case
    low, high = PARAMETERS[name].range
    problem = None if low <= value <= high else "out of range"
    problem = problem or node_parameters.value_problem(name, value)
    if problem is not None:
        assert "\n" not in problem and len(problem) < 200
        return
    assert math.isfinite(value)
    harness = Harness()
    harness.loop.begin()
    harness.run_until(2)
    if name == "real_time_factor":
        assert value == 0.0 or value >= MIN_REAL_TIME_FACTOR
        harness.loop.set_real_time_factor(value)
        for _ in range(5):
            harness.loop.turn()
        assert all(wait is None or 0.0 <= wait <= MAX_WAIT for wait in harness.waits)
        harness.loop.set_real_time_factor(1.0)
        harness.run_until(max(harness.ks()) + 2)
    else:   # command_timeout: whole nanoseconds of simulated time, an int64 like every stamp
        assert 0 <= round(value * 1e9) < 2 ** 63


def check_huge_commands(seed_and_count, fuzz_settings):
    """test/helpers/huge_commands.py in its own process (a loop would hang it, not the run)."""
    seed, count = seed_and_count
    result = subprocess.run([sys.executable, "huge_commands.py", str(seed), str(count)],
                            capture_output=True, text=True, timeout=1800,
                            cwd=Path(__file__).parents[1] / "helpers")
    assert result.returncode == 0, result.stderr
    cases = [json.loads(line) for line in result.stdout.splitlines()]
    assert len(cases) == len(METHODS) * (len(COMMANDS) + count)
    for case in cases:
        check_huge_command(case)
    return len(cases)


def check_trajectory_wire(data):
    """Any bytes on the trajectory topic: a `Trajectory` or an `Outcome` (the goal's answer),
    or a one-line ValueError (ignored with a warning) — never another exception."""
    from mobile_manip_sim.ros.trajectory_goals import Codes, Outcome, Trajectory
    from mobile_manip_sim.ros.trajectory_wire import arrays, read_trajectory
    try:
        wire = read_trajectory(data)
    except ValueError as error:
        assert "\n" not in str(error) and len(str(error)) < 200
        return
    codes = Codes._make(range(len(Codes._fields)))
    result = arrays(wire, ["j1", "j2"], codes)
    assert isinstance(result, (Trajectory, Outcome))


def _trajectory_bytes(mutations):
    """A valid JointTrajectory's CDR with ``mutations`` ((offset, byte), ...) applied, cut."""
    from rclpy.serialization import serialize_message
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
    message = JointTrajectory(joint_names=["j1", "j2"])
    message.points = [JointTrajectoryPoint(positions=[0.1 * i, 0.2], velocities=[0.0, 0.0])
                      for i in range(3)]
    for i, point in enumerate(message.points):
        point.time_from_start.sec, point.time_from_start.nanosec = i, 5
    data = bytearray(serialize_message(message))
    cut, changes = mutations
    for offset, value in changes:
        data[offset % len(data)] = value
    return bytes(data[:max(0, len(data) - cut)])


wire_bytes = st.one_of(st.binary(max_size=300), st.tuples(
    st.integers(0, 120), st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)),
                                  max_size=6)).map(_trajectory_bytes))


def check_type_name(name):
    """A bag's type name: a message class of a known package or one line; nothing outside the
    known packages is imported because of it."""
    from mobile_manip_sim.ros.message_types import KNOWN_PACKAGES, message_class
    before = set(sys.modules)
    found = None
    error = outcome(lambda: found_class.append(message_class(name)))
    if error is None:
        found = found_class.pop()
        assert found.__module__.split(".")[0] in KNOWN_PACKAGES
    new = {module.split(".")[0] for module in set(sys.modules) - before}
    assert new <= KNOWN_PACKAGES | {"rosidl_parser", "rpyutils"}, new


found_class = []
type_names = st.one_of(st.text(max_size=40), st.builds(
    lambda package, name: f"{package}/msg/{name}",
    st.sampled_from(["std_msgs", "sensor_msgs", "os", "this", "..os", "antigravity", "",
                     "tf2_msgs", "std_msgs.msg", "nav_msgs"]),
    st.sampled_from(["String", "Zen", "X", "system", "JointState", "", "__class__", "Odometry"])))


def check_topic_name(name):
    """A bag's topic name: replay plays it only if rcl takes it as a topic name."""
    from rclpy.exceptions import InvalidTopicNameException
    from rclpy.validate_full_topic_name import validate_full_topic_name

    from mobile_manip_sim.replay.play import _problem
    problem = _problem(name, "std_msgs/msg/String")
    if problem is None:
        try:
            validate_full_topic_name(name)
        except InvalidTopicNameException as error:
            pytest.fail(f"{name!r} accepted by replay, refused by rcl: {error}")
    else:
        assert "\n" not in problem


topic_names = st.one_of(st.text(max_size=30), st.from_regex(r"/[A-Za-z0-9_/ !~{}.-]{0,20}",
                                                             fullmatch=True))


def check_scene_name_in_a_title(name):
    """Any scene name in a figure's title draws (mathtext would parse `$…$`)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from mobile_manip_sim.plot.figures import plain
    figure = Figure(figsize=(2, 1))
    FigureCanvasAgg(figure)
    figure.suptitle(f"{plain(name)}: energy balance")
    figure.canvas.draw()


DEFAULTS = {name: spec.default for name, spec in PARAMETERS.items()}
NAMED = ["odom_frame", "base_frame", "frame_prefix", "record", "foxglove_host"]
names_and_values = st.tuples(st.sampled_from(NAMED), st.one_of(
    st.text(max_size=16), st.sampled_from(["/odom", "a b", "robot1//", "null", "~", "base_link",
                                           "odom", "0.0.0.0", "::1", "x/", "//", "a/b"])))


def check_named_parameter(case):
    """Frame names, prefix, record and host as the node reads them: one line or a record
    whose frames tf would take."""
    name, value = case
    read = []
    error = outcome(lambda: read.append(node_parameters.read({**DEFAULTS, name: value})))
    if error is None and name in ("odom_frame", "base_frame"):
        assert value and not value.startswith("/") and not any(c.isspace() for c in value)


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
    (check_metadata_yaml, st.text(max_size=200)),
    (check_bag_information, mutations_of(BAG_INFORMATION)),
    (check_tags, st.tuples(st.sampled_from(list(READERS)), st.integers(0, 10**6), tagged_scalars)),
    (check_blank_argument, st.tuples(st.sampled_from(list(PARAMETERS)), st.one_of(
        st.sampled_from(BLANKS), st.text(max_size=12)))),
    (check_declared_argument, declared_arguments),
    (check_blank_in_yaml, st.tuples(st.sampled_from(list(READERS)), st.integers(0, 10**6),
                                    st.sampled_from(BLANKS))),
    (check_sweep, sweep_changes),
    (check_run_time_parameter, st.tuples(st.sampled_from(DYNAMIC), extremes)),
    (check_trajectory_wire, wire_bytes), (check_type_name, type_names),
    (check_topic_name, topic_names), (check_scene_name_in_a_title, st.text(max_size=24)),
    (check_named_parameter, names_and_values),
]


@pytest.mark.parametrize("check, strategy", CHECKS, ids=[c.__name__ for c, _ in CHECKS])
def test_fuzz_fixed_seed(check, strategy):
    assert fuzz(FAST, check, strategy) >= 100   # the examples really ran (each one checked)


@pytest.mark.slow
@pytest.mark.parametrize("check, strategy", CHECKS, ids=[c.__name__ for c, _ in CHECKS])
def test_fuzz_long(check, strategy):
    assert fuzz(LONG, check, strategy) >= 1000


def test_huge_commands_for_every_method_after_a_reset_fixed_seed():
    """Random huge finite commands (1e20 to 1.8e308, any signs, any group) right after
    a reset, 3 per method with a fixed seed besides the fixed cases."""
    assert check_huge_commands((22, 3), FAST) == len(METHODS) * (len(COMMANDS) + 3)


@pytest.mark.slow
def test_huge_commands_for_every_method_after_a_reset_long():
    seed = random.randrange(10**6)
    print(f"huge commands: seed {seed}")
    assert check_huge_commands((seed, 60), LONG) == len(METHODS) * (len(COMMANDS) + 60)


def test_the_fuzzer_can_fail():
    """The checks are not vacuous: an input known to be bad is refused, and a check that
    accepted anything other than a UserError would see it."""
    assert outcome(lambda: parse_scene(mutate(PAPER, ("duration",), 1e308, False))) is not None
    assert outcome(lambda: rosbag2_metadata.bag_information(BAG_INFORMATION)) is None
    assert outcome(lambda: rosbag2_metadata.bag_information(mutate(
        BAG_INFORMATION, ("rosbag2_bagfile_information", "custom_data"), [1], False))) is not None
    # these classes: a bad tag, a blank value and a huge sweep are refused, good ones not
    scene_yaml = READERS["scene"][1]
    assert outcome(lambda: scene_yaml(with_tag(PAPER, ("duration",), "!!float", "abc")))
    assert outcome(lambda: scene_yaml(with_tag(PAPER, ("duration",), "!!float", "0.5"))) is None
    assert outcome(lambda: node_arguments.check(["--ros-args", "-p", "publish_rate:="]))
    # arguments.check hands these to rcl; the declarations refuse them (and take a good one)
    for name, value in (("arm_gains.kp", "[]"),
                        ("qos_overrides./odom.publisher.depth", "99999999999"),
                        ("qos_overrides./elsewhere.publisher.depth", "5")):
        argv = ["--ros-args", "-p", f"{name}:={value}"]
        assert outcome(lambda argv=argv: node_arguments.check(argv)) is None
        assert check_declared_argument((name, value)).key == name
    assert check_declared_argument(("publish_rate", "50.0")) is None
    assert outcome(lambda: sweep_check(mutate(SWEEP, ("random", "count"), 10**9, False)))
    assert outcome(lambda: sweep_check(SWEEP)) is None
    harness_runs = []
    original = Harness.run_until
    try:   # an accepted run-time value reaches the loop; a refused one does not
        Harness.run_until = lambda self, k: harness_runs.append(k) or original(self, k)
        check_run_time_parameter(("real_time_factor", 1e-12))
        assert harness_runs == []
        check_run_time_parameter(("real_time_factor", MIN_REAL_TIME_FACTOR))
        assert harness_runs
    finally:
        Harness.run_until = original
    with pytest.raises(AssertionError):
        outcome(lambda: (_ for _ in ()).throw(UserError("k", "two\nlines")))
    with pytest.raises(ZeroDivisionError):
        outcome(lambda: 1 / 0)


def test_trajectory_bytes_read_without_rclpy_give_rclpys_goal_answer():
    """`trajectory_wire` (the topic's bytes into arrays) against the reference path (rclpy's
    message → `goal_of` → `trajectory_goals.arrange`) on 300 seeded random trajectories: the
    same trajectory, or the same refusal word for word."""
    import numpy as np
    from rclpy.serialization import serialize_message
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    from mobile_manip_sim.node.trajectory_action import goal_of
    from mobile_manip_sim.ros.trajectory_goals import Codes, Outcome, arrange
    from mobile_manip_sim.ros.trajectory_wire import arrays, read_trajectory
    names = ["j1", "j2", "j3", "j4"]
    codes = Codes._make(range(len(Codes._fields)))
    rng = random.Random(30)
    kinds = {"refused": 0, "taken": 0}
    for _ in range(300):
        message = JointTrajectory(joint_names=rng.sample(names, 4) if rng.random() < 0.9
                                  else ["j1", "j1", "j3", "j4"])
        message.header.stamp.sec = rng.choice([0, 3])
        given = {"positions": True, "velocities": rng.random() < 0.5,
                 "accelerations": rng.random() < 0.3, "effort": rng.random() < 0.05}
        m = rng.randint(0, 5)
        for i in range(m):
            point = JointTrajectoryPoint()
            for field, present in given.items():
                count = (4 if rng.random() < 0.97 else rng.choice([0, 3, 5])) if present else \
                    (0 if rng.random() < 0.98 else 4)
                values = [float("nan") if rng.random() < 0.01 else rng.uniform(-2, 2)
                          for _ in range(count)]
                if field == "velocities" and i == m - 1 and rng.random() < 0.9:
                    values = [0.0] * count
                setattr(point, field, values)
            point.time_from_start.sec = i if rng.random() < 0.97 else 0
            point.time_from_start.nanosec = rng.randint(0, 999_999_999)
            message.points.append(point)
        reference = arrange(goal_of(message), names, codes)
        wire = read_trajectory(serialize_message(message))
        ours = arrays(wire, names, codes)
        assert wire.start_ns == goal_of(message).start_ns
        if isinstance(reference, Outcome):
            assert ours == reference
            kinds["refused"] += 1
        else:
            for theirs, mine in zip(reference, ours, strict=True):
                assert (theirs is None and mine is None) or np.array_equal(theirs, mine)
            kinds["taken"] += 1
    assert min(kinds.values()) > 30   # both kinds really compared
