"""Bag storage: bags we write are read back by independent readers (rosbags, mcap + mcap_ros2),
and our reader survives truncation, SIGKILL and damaged files with one-line errors."""

import errno
import os
import random
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
import yaml
from builtin_interfaces.msg import Time
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap_ros2.decoder import DecoderFactory
from nav_msgs.msg import Odometry
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import Reader as RosbagsReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from mobile_manip_sim.recording.bag_reader import open_bag
from mobile_manip_sim.recording.bag_writer import BagWriter, qos_yaml
from mobile_manip_sim.ros.message_definitions import DELIMITER, definition_text
from mobile_manip_sim.scene.errors import UserError

REPO = Path(__file__).resolve().parents[2]
T0 = 1_000_000_000  # simulated time of the first message [ns]
STEPS = 60
TOPICS = {
    "/clock": "rosgraph_msgs/msg/Clock",
    "/joint_states": "sensor_msgs/msg/JointState",
    "/odom": "nav_msgs/msg/Odometry",
    "/arm/effort": "std_msgs/msg/Float64MultiArray",
}


def _stamp(t_ns: int) -> Time:
    return Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9)


def _message(topic: str, step: int, t_ns: int):
    """A real rclpy message whose values encode ``step`` (checked after decoding)."""
    if topic == "/clock":
        return Clock(clock=_stamp(t_ns))
    if topic == "/joint_states":
        joint_state = JointState(name=["wheel_left", "shoulder", "slide"],
                                 position=[0.1 * step, -0.2, 0.3],
                                 velocity=[1.0, 2.0, float(step)], effort=[0.0, 0.5, -0.5])
        joint_state.header.stamp = _stamp(t_ns)
        return joint_state
    if topic == "/odom":
        odometry = Odometry(child_frame_id="base_link")
        odometry.header.stamp = _stamp(t_ns)
        odometry.header.frame_id = "odom"
        odometry.pose.pose.position.x = 0.01 * step
        odometry.twist.twist.angular.z = -0.5
        return odometry
    return Float64MultiArray(data=[float(step), 2.0 * step])


def _recorded():
    """(topic, type, message, log_time, publish_time, CDR) in log-time order, unique times.
    The CDR is kept: rclpy leaves alignment padding uninitialised, so serialising the same
    message twice can give different bytes."""
    records = []
    for step in range(STEPS):
        for k, topic in enumerate(TOPICS):
            t_ns = T0 + step * 10_000_000 + k * 1_000
            message = _message(topic, step, t_ns)
            records.append((topic, TOPICS[topic], message, t_ns, t_ns - 500,
                            serialize_message(message)))
    return records


def _write_bag(path: Path, records, **options) -> Path:
    with BagWriter(path, custom_data={"scene": "demo.yaml"}, **options) as writer:
        for topic, type_name in TOPICS.items():
            reliability = "best_effort" if topic == "/odom" else "reliable"
            writer.add_topic(topic, type_name, qos_yaml(reliability=reliability))
        for topic, _, _, log_time, publish_time, data in records:
            writer.write(topic, data, log_time, publish_time)
        writer.add_attachment("scene.yaml", "application/yaml", b"robot: {}\n", log_time_ns=T0)
        writer.add_metadata("mobile_manip_sim", {"integrator": "rk4", "dt": "0.001"})
    return path


@pytest.fixture(scope="module")
def records():
    return _recorded()


@pytest.fixture(scope="module")
def bag(tmp_path_factory, records) -> Path:
    return _write_bag(tmp_path_factory.mktemp("bags") / "run", records)


def _check_values(topic: str, step: int, decoded) -> None:
    """Field values of a message decoded by a reader other than rclpy."""
    if topic == "/clock":
        assert decoded.clock.sec == 1 and decoded.clock.nanosec == step * 10_000_000
    elif topic == "/joint_states":
        assert list(decoded.name) == ["wheel_left", "shoulder", "slide"]
        assert list(decoded.position) == pytest.approx([0.1 * step, -0.2, 0.3])
        assert decoded.velocity[2] == step
        assert decoded.header.stamp.nanosec == step * 10_000_000 + 1_000
    elif topic == "/odom":
        assert decoded.header.frame_id == "odom" and decoded.child_frame_id == "base_link"
        assert decoded.pose.pose.position.x == pytest.approx(0.01 * step)
        assert decoded.twist.twist.angular.z == -0.5
        assert len(decoded.pose.covariance) == 36
    else:
        assert list(decoded.data) == [step, 2.0 * step]


def _step(log_time: int) -> int:
    return (log_time - T0) // 10_000_000


def _is_one_line_user_error(error: UserError, path) -> bool:
    return str(path) in str(error) and "\n" not in str(error)


# --- message definitions ------------------------------------------------------------------

def test_definition_lists_each_dependency_once_after_a_delimiter():
    text = definition_text("sensor_msgs/msg/JointState")
    assert text.startswith("# This is a message that holds data")
    assert text.count("MSG: builtin_interfaces/Time\n") == 1
    assert text.count("MSG: std_msgs/Header\n") == 1
    lines = text.splitlines()
    for index, line in enumerate(lines):
        if line.startswith("MSG: "):
            assert lines[index - 1] == "=" * 80 == DELIMITER
    odometry = definition_text("nav_msgs/msg/Odometry")
    for dependency in ("geometry_msgs/Vector3", "geometry_msgs/Pose", "std_msgs/Header",
                       "builtin_interfaces/Time", "geometry_msgs/TwistWithCovariance"):
        assert odometry.count(f"MSG: {dependency}\n") == 1
    assert "MSG: float64" not in odometry
    assert definition_text("sensor_msgs/msg/JointState") is text  # cached


@pytest.mark.parametrize("type_name", ["no_such_msgs/msg/Foo", "std_msgs/msg/NoSuchType",
                                       "JointState", "sensor_msgs/srv/JointState"])
def test_unknown_type_is_a_user_error(type_name):
    with pytest.raises(UserError, match="message type"):
        definition_text(type_name)


# --- independent readers ------------------------------------------------------------------

def test_metadata_yaml_has_every_rosbag2_field(bag, records):
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    assert info["ros_distro"] == "jazzy"
    assert info["relative_file_paths"] == ["run_0.mcap"]
    assert info["message_count"] == len(records)
    assert info["starting_time"]["nanoseconds_since_epoch"] == records[0][3]
    assert info["duration"]["nanoseconds"] == records[-1][3] - records[0][3]
    assert info["compression_format"] == "" and info["compression_mode"] == ""
    assert info["custom_data"] == {"scene": "demo.yaml"}
    assert info["files"] == [{"path": "run_0.mcap", "starting_time": info["starting_time"],
                              "duration": info["duration"], "message_count": len(records)}]
    counts = {entry["topic_metadata"]["name"]: entry["message_count"]
              for entry in info["topics_with_message_count"]}
    assert counts == {topic: STEPS for topic in TOPICS}
    for entry in info["topics_with_message_count"]:
        topic = entry["topic_metadata"]
        assert topic["type"] == TOPICS[topic["name"]] and topic["serialization_format"] == "cdr"
        assert re.fullmatch(r"RIHS01_[0-9a-f]{64}", topic["type_description_hash"])
        # rosbag2 Jazzy decodes this field as a string holding YAML
        assert isinstance(topic["offered_qos_profiles"], str)
        assert yaml.safe_load(topic["offered_qos_profiles"])[0]["history"] == "keep_last"


def test_rosbags_reads_topics_counts_order_and_values(bag, records):
    typestore = get_typestore(Stores.EMPTY)
    with RosbagsReader(bag) as reader:
        connections = {c.topic: c for c in reader.connections}
        assert {t: c.msgtype for t, c in connections.items()} == TOPICS
        assert all(c.msgcount == STEPS for c in connections.values())
        odom_qos = connections["/odom"].ext.offered_qos_profiles[0]
        assert odom_qos.reliability.name == "BEST_EFFORT" and odom_qos.depth == 10
        for connection in connections.values():  # types come from the bag's own schemas
            typestore.register(get_types_from_msg(connection.msgdef.data, connection.msgtype))
        read = [(c.topic, t, typestore.deserialize_cdr(raw, c.msgtype))
                for c, t, raw in reader.messages()]
    assert [(topic, t) for topic, t, _ in read] == [(r[0], r[3]) for r in records]
    for topic, log_time, decoded in read:
        _check_values(topic, _step(log_time), decoded)


def test_mcap_ros2_decodes_schemas_channels_and_messages(bag, records):
    with open(bag / "run_0.mcap", "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary.statistics.message_count == len(records)
        assert summary.chunk_indexes and all(i.message_index_offsets and i.compression == "zstd"
                                             for i in summary.chunk_indexes)
        schemas = {s.name: s for s in summary.schemas.values()}
        assert set(schemas) == set(TOPICS.values())
        assert all(s.encoding == "ros2msg" for s in schemas.values())
        assert b"MSG: builtin_interfaces/Time" in schemas["sensor_msgs/msg/JointState"].data
        for channel in summary.channels.values():
            assert channel.message_encoding == "cdr"
            profiles = yaml.safe_load(channel.metadata["offered_qos_profiles"])
            assert profiles[0]["durability"] == "volatile"
            assert profiles[0]["deadline"] == {"sec": 0, "nsec": 0}
        decoded = list(reader.iter_decoded_messages())
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert [(d.channel.topic, d.message.log_time, d.message.publish_time) for d in decoded] == \
        [(r[0], r[3], r[4]) for r in records]
    for item in decoded:
        _check_values(item.channel.topic, _step(item.message.log_time), item.decoded_message)
    serialized = yaml.safe_load(metadata["rosbag2"]["serialized_metadata"])
    assert serialized["version"] == 9 and serialized["message_count"] == len(records)
    assert "rosbag2_bagfile_information" not in serialized
    assert metadata["mobile_manip_sim"] == {"integrator": "rk4", "dt": "0.001"}


# --- our reader ---------------------------------------------------------------------------

@pytest.mark.parametrize("which", ["directory", "file"])
def test_open_bag_returns_what_was_written(bag, records, which):
    opened = open_bag(bag if which == "directory" else bag / "run_0.mcap")
    assert opened.topics() == TOPICS and not opened.recovered
    expected = [(r[0], r[1], r[5], r[3], r[4]) for r in records]
    assert [tuple(m) for m in opened.messages()] == expected
    clock_times = [m.log_time_ns for m in opened.messages(["/clock"])]
    assert clock_times == [r[3] for r in records if r[0] == "/clock"]
    assert opened.attachments() == {"scene.yaml": b"robot: {}\n"}
    assert set(opened.metadata()) == {"mobile_manip_sim", "rosbag2"}
    with pytest.raises(UserError, match="/nope"):
        opened.messages(["/nope"])


def test_not_a_bag_is_a_one_line_user_error(tmp_path, bag):
    text_file = tmp_path / "notes.mcap"
    text_file.write_text("hello, this is not an MCAP file at all\n")
    missing = tmp_path / "missing"
    other_storage = tmp_path / "sqlite_bag"
    other_storage.mkdir()
    (other_storage / "metadata.yaml").write_text(
        "rosbag2_bagfile_information: {version: 9, storage_identifier: sqlite3}\n")
    for path in (text_file, missing, other_storage, tmp_path / "empty.mcap"):
        if path.name == "empty.mcap":
            path.write_bytes(b"")
        with pytest.raises(UserError) as caught:
            open_bag(path)
        assert _is_one_line_user_error(caught.value, path)
    wrong_profile = tmp_path / "plain.mcap"
    raw = (bag / "run_0.mcap").read_bytes()
    wrong_profile.write_bytes(raw.replace(b"\x04\x00\x00\x00ros2", b"\x04\x00\x00\x00json", 1))
    with pytest.raises(UserError, match="profile 'json'"):
        open_bag(wrong_profile)


def _chunk_ends_and_counts(path: Path, records):
    """(end offset, messages in complete chunks up to there) for each chunk, and the data
    section end."""
    with open(path, "rb") as stream:
        summary = make_reader(stream).get_summary()
    times = [r[3] for r in records]
    ends, total = [], 0
    for index in sorted(summary.chunk_indexes, key=lambda i: i.chunk_start_offset):
        total += sum(index.message_start_time <= t <= index.message_end_time for t in times)
        ends.append((index.chunk_start_offset + index.chunk_length, total))
    return ends


def test_truncated_file_yields_complete_chunks_or_a_user_error(tmp_path, records):
    bag = _write_bag(tmp_path / "small_chunks", records, chunk_size=2048)
    mcap_path = bag / "small_chunks_0.mcap"
    raw = mcap_path.read_bytes()
    ends = _chunk_ends_and_counts(mcap_path, records)
    assert len(ends) >= 5
    cuts = {0, 5, 8, 12, 30, ends[0][0] // 2, len(raw) - 1, len(raw) - 30, len(raw) // 2}
    for end, _ in ends:
        cuts |= {end - 1, end, end + 3, end + 40}
    all_messages = [(r[0], r[3]) for r in records]
    for cut in sorted(cuts):
        cut_path = tmp_path / f"cut_{cut}.mcap"
        cut_path.write_bytes(raw[:cut])
        complete = max([count for end, count in ends if end <= cut], default=0)
        try:
            read = [(m.topic, m.log_time_ns) for m in open_bag(cut_path).messages()]
        except UserError as error:
            assert _is_one_line_user_error(error, cut_path), cut
            assert complete == 0, f"cut at {cut} lost {complete} messages: {error}"
            continue
        assert read[:complete] == all_messages[:complete], cut
        assert read == all_messages[:len(read)], cut  # never anything out of order or invented


def test_corrupt_chunk_is_a_one_line_user_error(tmp_path, records):
    bag = _write_bag(tmp_path / "corrupt", records, chunk_size=2048)
    mcap_path = bag / "corrupt_0.mcap"
    raw = bytearray(mcap_path.read_bytes())
    end, _ = _chunk_ends_and_counts(mcap_path, records)[2]
    raw[end - 300:end - 100] = random.Random(7).randbytes(200)
    mcap_path.write_bytes(bytes(raw))
    with pytest.raises(UserError) as caught:
        list(open_bag(bag).messages())
    assert _is_one_line_user_error(caught.value, mcap_path)


def test_damaged_bytes_never_give_wrong_data_or_a_traceback(tmp_path, records):
    """Overwrite a few bytes anywhere (header, chunks, indexes, summary, footer): the reader
    returns every message, a prefix of them (summary unusable, data scanned), or a UserError."""
    bag = _write_bag(tmp_path / "damaged", records, chunk_size=2048)
    mcap_path = bag / "damaged_0.mcap"
    good = mcap_path.read_bytes()
    expected = [(r[0], r[3], r[5]) for r in records]
    rng = random.Random(11)
    for _ in range(150):
        raw = bytearray(good)
        width = rng.randrange(1, 8)
        position = rng.randrange(0, len(raw) - width)
        raw[position:position + width] = rng.randbytes(width)
        mcap_path.write_bytes(bytes(raw))
        try:
            opened = open_bag(bag)
            read = [(m.topic, m.log_time_ns, m.data) for m in opened.messages()]
            opened.attachments(), opened.metadata()
        except UserError as error:
            assert _is_one_line_user_error(error, mcap_path), position
            continue
        assert read == expected[:len(read)], position


# --- crash, write failures, memory --------------------------------------------------------

_KILLED_WRITER = textwrap.dedent("""
    import sys
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock
    from mobile_manip_sim.recording.bag_writer import BagWriter

    writer = BagWriter(sys.argv[1], chunk_size=4096)
    writer.add_topic("/clock", "rosgraph_msgs/msg/Clock")
    step = 0
    while True:
        writer.write("/clock", serialize_message(Clock()), 1000 + step)
        step += 1
        if writer.buffered_bytes == 0:  # a chunk just went to the file
            print(step, flush=True)
""")


def test_sigkill_keeps_every_complete_chunk(tmp_path):
    bag = tmp_path / "killed"
    env = dict(os.environ, PYTHONPATH=f"{REPO}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    child = subprocess.Popen([sys.executable, "-c", _KILLED_WRITER, str(bag)], env=env,
                             stdout=subprocess.PIPE, text=True)
    flushed, deadline = [], time.monotonic() + 15
    try:
        while len(flushed) < 6 and time.monotonic() < deadline:
            line = child.stdout.readline()
            assert line, "writer exited early"
            flushed.append(int(line))
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
    assert len(flushed) == 6
    assert not (bag / "metadata.yaml").exists()

    opened = open_bag(bag)
    assert opened.recovered and opened.topics() == {"/clock": "rosgraph_msgs/msg/Clock"}
    times = [m.log_time_ns for m in opened.messages()]
    assert len(times) >= flushed[-1]
    assert times == list(range(1000, 1000 + len(times)))

    mcap_file = bag / "killed_0.mcap"
    with open(mcap_file, "rb") as stream:  # mcap's own sequential reader, up to the crash
        streamed = 0
        with pytest.raises(McapError):
            for _ in NonSeekingReader(stream).iter_messages(log_time_order=False):
                streamed += 1
    assert streamed >= flushed[-1]


def test_unwritable_paths_are_user_errors(tmp_path):
    regular_file = tmp_path / "a_file"
    regular_file.write_text("x")
    occupied = tmp_path / "occupied"
    occupied.mkdir()
    (occupied / "old_0.mcap").write_bytes(b"old")
    for path in (regular_file / "bag", Path("/proc/mobile_manip_sim_bag"), occupied,
                 regular_file):
        with pytest.raises(UserError) as caught:
            BagWriter(path)
        assert _is_one_line_user_error(caught.value, path)
    empty = tmp_path / "empty_dir"
    empty.mkdir()
    BagWriter(empty).close()
    assert (empty / "metadata.yaml").exists()


class _FullDisk:
    """Stands in for the open .mcap file on a disk that has just filled up."""

    def write(self, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    flush = write

    def fileno(self):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def close(self):
        pass


@pytest.mark.parametrize("when", ["chunk", "close"])
def test_full_disk_is_reported_naming_the_bag(tmp_path, when):
    path = tmp_path / "full"
    writer = BagWriter(path, chunk_size=1024)
    writer.add_topic("/clock", "rosgraph_msgs/msg/Clock")
    data = serialize_message(Clock())
    writer.write("/clock", data, 1)
    writer._file._file = _FullDisk()
    with pytest.raises(UserError) as caught:
        if when == "chunk":
            for step in range(1000):
                writer.write("/clock", data, 2 + step)
        else:
            writer.close()
    assert _is_one_line_user_error(caught.value, path)
    assert "No space left on device" in str(caught.value)
    with pytest.raises(UserError, match="unusable|closed"):
        writer.write("/clock", data, 5000)
    writer.close()
    writer.close()
    assert not (path / "metadata.yaml").exists()


def test_misuse_is_a_user_error(tmp_path):
    with BagWriter(tmp_path / "bag") as writer:
        with pytest.raises(UserError, match="/unknown"):
            writer.write("/unknown", b"", 0)
        with pytest.raises(UserError, match="message type"):
            writer.add_topic("/x", "no_such_msgs/msg/X")
        writer.add_topic("/clock", "rosgraph_msgs/msg/Clock")
        with pytest.raises(UserError, match="already added"):
            writer.add_topic("/clock", "std_msgs/msg/Float64MultiArray")
        with pytest.raises(UserError, match="reserved"):
            writer.add_metadata("rosbag2", {})
        with pytest.raises(UserError, match="depth"):
            qos_yaml(depth=0)
    with pytest.raises(UserError, match="closed"):
        writer.write("/clock", b"", 0)
    assert open_bag(tmp_path / "bag").topics() == {"/clock": "rosgraph_msgs/msg/Clock"}


def test_flush_puts_the_open_chunk_on_disk(tmp_path):
    writer = BagWriter(tmp_path / "flushed")
    writer.add_topic("/clock", "rosgraph_msgs/msg/Clock")
    for step in range(10):
        writer.write("/clock", serialize_message(Clock()), step)
    assert writer.buffered_bytes > 0
    writer.flush()
    assert writer.buffered_bytes == 0
    unfinished = open_bag(tmp_path / "flushed")  # as a crash now would leave it
    assert unfinished.recovered and len(list(unfinished.messages())) == 10
    writer.close()
    assert len(list(open_bag(tmp_path / "flushed").messages())) == 10


def test_open_chunk_stays_bounded_over_a_long_run(tmp_path):
    chunk_size = 16 * 1024
    writer = BagWriter(tmp_path / "long", chunk_size=chunk_size)
    writer.add_topic("/clock", "rosgraph_msgs/msg/Clock")
    data = serialize_message(Clock())
    largest = 0
    for step in range(200_000):
        writer.write("/clock", data, step)
        largest = max(largest, writer.buffered_bytes)
    writer.close()
    assert chunk_size - 31 - len(data) <= largest <= chunk_size + 31 + len(data)
    with open(tmp_path / "long" / "long_0.mcap", "rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary.statistics.message_count == 200_000
    assert summary.statistics.chunk_count >= 200_000 * len(data) // chunk_size


@pytest.mark.parametrize("log_times", [[], [0, 0, 10_000_000, 470_000_000], [5, 3, 9]])
def test_the_statistics_agree_with_the_messages_and_metadata_yaml(tmp_path, log_times):
    """Statistics' message_start/end_time are the least and greatest log times — 0 included, a
    node's bags start at t = 0 — and 0, 0 with no message; metadata.yaml says the same. (The Go
    writer of `mcap recover` takes a start time of 0 for 'unset' and writes a later one, which
    `mcap doctor` flags; this writer's own summary is consistent.)"""
    path = tmp_path / "bag"
    with BagWriter(path) as writer:
        writer.add_topic("/clock", "rosgraph_msgs/msg/Clock")
        for t in log_times:
            writer.write("/clock", serialize_message(Clock()), t)
    with open(path / "bag_0.mcap", "rb") as stream:
        summary = make_reader(stream).get_summary()
    statistics = summary.statistics
    assert statistics.message_count == len(log_times)
    assert (statistics.message_start_time, statistics.message_end_time) == (
        (min(log_times), max(log_times)) if log_times else (0, 0))
    chunks = summary.chunk_indexes
    assert len(chunks) == (1 if log_times else 0)   # no empty chunk, with its times of 0
    if log_times:
        assert (chunks[0].message_start_time, chunks[0].message_end_time) == (
            min(log_times), max(log_times))
    information = yaml.safe_load(
        (path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert information["starting_time"]["nanoseconds_since_epoch"] == statistics.message_start_time
    assert information["duration"]["nanoseconds"] == (
        statistics.message_end_time - statistics.message_start_time)
    assert information["message_count"] == statistics.message_count
