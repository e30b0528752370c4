"""Write a rosbag2 (Jazzy, metadata version 9) bag directory with one MCAP file.

Layout (rosbag2's own, as ``ros2 bag record -s mcap`` writes it): ``<dir>/<dirname>_0.mcap``
with profile ``ros2``, one ``ros2msg`` schema per type, one ``cdr`` channel per topic carrying
``offered_qos_profiles``, zstd chunks with message indexes, a full summary with statistics and a
``rosbag2`` metadata record; beside it ``metadata.yaml``, written at close.

Crash safety: messages collect in an open chunk in memory; when it exceeds ``chunk_size`` the
mcap writer compresses it and hands it to the file, and we flush the file right away, so a
SIGKILL loses at most the open chunk (the Python mcap writer cannot append to a chunk already
on disk). ``flush()`` closes the open chunk early, e.g. on a wall-clock timer. There is no fsync
per chunk: the OS keeps data of a killed process, only a power loss could drop more.

Every I/O failure (full disk, EIO, a closed file) raises ``UserError`` naming the bag directory
and the OS error, never a traceback, and leaves the writer unusable: rosbag2 once dropped such
errors silently (rosbag2 PR #2443).
"""

import contextlib
import os
from pathlib import Path

import yaml
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, IndexType, Writer

from mobile_manip_sim import __version__
from mobile_manip_sim.ros.message_definitions import (
    definition_text,
    split_type_name,
    type_hash,
)
from mobile_manip_sim.scene.errors import UserError

# At ~300 messages/s of 200-500 bytes (60-150 KB/s) a 64 KiB chunk holds 0.4-1 s of data, the
# most a SIGKILL may lose. It must stay larger than any single message: files whose messages
# exceed the chunk size have been unreadable by Jazzy's reader (rosbag2 #2040).
DEFAULT_CHUNK_SIZE = 64 * 1024

ROSBAG2_METADATA_VERSION = 9
ROS_DISTRO = "jazzy"
LIBRARY = f"mobile_manip_sim/{__version__}; {LIBRARY_IDENTIFIER}"

# opcode (1) + record length (8) + channel id (2) + sequence (4) + log/publish time (8 + 8)
_MESSAGE_RECORD_OVERHEAD = 31
# A generous bound on the fixed part of a schema or channel record (ids, lengths, opcode).
_REGISTRATION_RECORD_OVERHEAD = 64

RELIABILITY_POLICIES = ("reliable", "best_effort", "system_default", "best_available")
DURABILITY_POLICIES = ("volatile", "transient_local", "system_default", "best_available")


def qos_yaml(reliability: str = "reliable", durability: str = "volatile", depth: int = 10) -> str:
    """``offered_qos_profiles`` as rosbag2 Jazzy writes it: a YAML list of one QoS map with
    string enums. Durations ``{sec: 0, nsec: 0}`` mean "unspecified" (the RMW default); rosbag2
    copies the publisher's infinities instead, and infinity values broke playback (#656)."""
    if reliability not in RELIABILITY_POLICIES:
        raise UserError("qos.reliability", f"{reliability!r} is not one of {RELIABILITY_POLICIES}")
    if durability not in DURABILITY_POLICIES:
        raise UserError("qos.durability", f"{durability!r} is not one of {DURABILITY_POLICIES}")
    if not isinstance(depth, int) or isinstance(depth, bool) or depth < 1:
        raise UserError("qos.depth", f"{depth!r} is not a positive integer")
    unspecified = {"sec": 0, "nsec": 0}
    profile = {
        "history": "keep_last",
        "depth": depth,
        "reliability": reliability,
        "durability": durability,
        "deadline": dict(unspecified),
        "lifespan": dict(unspecified),
        "liveliness": "automatic",
        "liveliness_lease_duration": dict(unspecified),
        "avoid_ros_namespace_conventions": False,
    }
    return yaml.safe_dump([profile], sort_keys=False, default_flow_style=False)


class _BlockStyleDumper(yaml.SafeDumper):
    """Multi-line strings (the QoS YAML inside metadata) as ``|`` blocks, as rosbag2 shows them."""


_BlockStyleDumper.add_representer(
    str,
    lambda dumper, text: dumper.represent_scalar(
        "tag:yaml.org,2002:str", text, style="|" if "\n" in text else None),
)


def dump_yaml(data: dict) -> str:
    """YAML in rosbag2's key order (no sorting), block style."""
    return yaml.dump(data, Dumper=_BlockStyleDumper, sort_keys=False, default_flow_style=False)


def describe_os_error(error: Exception) -> str:
    """One line: ``No space left on device [errno 28]``."""
    if isinstance(error, OSError) and error.strerror:
        return f"{error.strerror} [errno {error.errno}]"
    return " ".join(str(error).split()) or type(error).__name__


class _CountingFile:
    """The ``.mcap`` file as the mcap writer sees it; counting the bytes handed over tells us
    when a chunk has left memory (the writer has no hook for that)."""

    def __init__(self, path: Path):
        self._file = open(path, "wb")
        self.bytes_written = 0

    def write(self, data: bytes) -> int:
        self._file.write(data)
        self.bytes_written += len(data)
        return len(data)

    def tell(self) -> int:
        return self.bytes_written

    def flush(self) -> None:
        self._file.flush()

    def sync(self) -> None:
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> None:
        self._file.close()


class _Topic:
    """A registered topic: its channel and what metadata.yaml reports about it."""

    def __init__(self, channel_id: int, type_name: str, qos: str):
        self.channel_id = channel_id
        self.type_name = type_name
        self.qos = qos
        self.message_count = 0


class BagWriter:
    """A rosbag2 MCAP bag being written; see the module docstring. Use as a context manager or
    call ``close()`` (idempotent) — without it the bag has no summary and no metadata.yaml."""

    def __init__(self, path, *, chunk_size: int = DEFAULT_CHUNK_SIZE,
                 custom_data: dict | None = None):
        self.path = Path(path)
        self._key = str(self.path)
        self._custom_data = _checked_string_map("custom_data", custom_data or {})
        if not isinstance(chunk_size, int) or chunk_size < 1:
            raise UserError("chunk_size", f"{chunk_size!r} is not a positive number of bytes")
        self.file_name = f"{self.path.name}_0.mcap"
        self._topics: dict[str, _Topic] = {}
        self._schema_ids: dict[str, int] = {}
        self._buffered = 0
        self._time_range: tuple[int, int] | None = None
        self._closed = False
        self._failure: str | None = None
        _create_empty_directory(self.path)
        with self._io("cannot create bag file"):
            self._file = _CountingFile(self.path / self.file_name)
            self._mcap = Writer(self._file, chunk_size=chunk_size,
                                compression=CompressionType.ZSTD, index_types=IndexType.ALL,
                                use_chunking=True, use_statistics=True, use_summary_offsets=True)
            self._mcap.start(profile="ros2", library=LIBRARY)
            self._file.flush()

    @property
    def buffered_bytes(self) -> int:
        """Bytes of the open chunk not yet on disk (estimate; what a SIGKILL now would lose)."""
        return self._buffered

    def add_topic(self, name: str, type_name: str, qos_profiles_yaml: str | None = None) -> None:
        """Register ``name`` (absolute, e.g. ``/joint_states``) with ``type_name``
        (``pkg/msg/Type``); the type's schema is written once, shared by its topics."""
        self._check_writable()
        package, short_name = split_type_name(type_name)
        type_name = f"{package}/msg/{short_name}"
        if not name.startswith("/"):
            raise UserError(name, "topic name must be absolute (start with '/')")
        if name in self._topics:
            if self._topics[name].type_name != type_name:
                raise UserError(name, f"already added with type {self._topics[name].type_name}")
            return
        qos = qos_profiles_yaml if qos_profiles_yaml is not None else qos_yaml()
        schema_id = self._schema_id(type_name)
        with self._io("cannot register topic"):
            before = self._file.bytes_written
            metadata = {"offered_qos_profiles": qos}
            if type_hash(type_name):
                metadata["topic_type_hash"] = type_hash(type_name)
            channel_id = self._mcap.register_channel(name, "cdr", schema_id, metadata)
            self._account(before, _REGISTRATION_RECORD_OVERHEAD + len(name) + len(qos))
        self._topics[name] = _Topic(channel_id, type_name, qos)

    def write(self, topic: str, serialized_cdr: bytes, log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        """Append one message: ``serialized_cdr`` as ``rclpy.serialization.serialize_message``
        returns it (with its encapsulation header); times in nanoseconds (``log_time`` = when
        it was received/recorded, ``publish_time`` = when it was sent, default ``log_time``)."""
        self._check_writable()
        entry = self._topics.get(topic)
        if entry is None:
            raise UserError(topic, "not a topic of this bag (call add_topic first)")
        if log_time_ns < 0 or (publish_time_ns is not None and publish_time_ns < 0):
            raise UserError(topic, f"negative time (log {log_time_ns} ns, "
                                   f"publish {publish_time_ns} ns)")
        publish_time_ns = log_time_ns if publish_time_ns is None else publish_time_ns
        with self._io("cannot write message"):
            before = self._file.bytes_written
            self._mcap.add_message(entry.channel_id, log_time_ns, serialized_cdr,
                                   publish_time_ns, sequence=entry.message_count & 0xFFFFFFFF)
            self._account(before, _MESSAGE_RECORD_OVERHEAD + len(serialized_cdr))
        entry.message_count += 1
        low, high = self._time_range or (log_time_ns, log_time_ns)
        self._time_range = (min(low, log_time_ns), max(high, log_time_ns))

    def add_attachment(self, name: str, media_type: str, data: bytes,
                       log_time_ns: int = 0) -> None:
        """Store a file (scene YAML, config, ...) as an MCAP attachment."""
        self._check_writable()
        with self._io("cannot write attachment"):
            self._mcap.add_attachment(create_time=log_time_ns, log_time=log_time_ns, name=name,
                                      media_type=media_type, data=data)
            self._file.flush()

    def add_metadata(self, name: str, data: dict) -> None:
        """Store a string→string map as an MCAP metadata record (``rosbag2`` is reserved)."""
        self._check_writable()
        if name == "rosbag2":
            raise UserError(name, "metadata name reserved for the bag's own metadata")
        data = _checked_string_map(f"metadata {name}", data)
        with self._io("cannot write metadata"):
            self._mcap.add_metadata(name, data)
            self._file.flush()

    def flush(self) -> None:
        """Close the open chunk now and hand everything to the OS (bounds loss by time)."""
        self._check_writable()
        with self._io("cannot flush bag"):
            self._mcap.flush()
            self._buffered = 0

    def close(self) -> None:
        """Finish the MCAP (metadata record, summary, footer), then write metadata.yaml.
        Idempotent. After a write failure it only releases the file: that error was raised."""
        if self._closed:
            return
        self._closed = True
        if self._failure is not None:
            self._release()
            return
        info = self.bag_information()
        try:
            with self._io("cannot finish bag"):
                self._mcap.add_metadata("rosbag2", {"serialized_metadata": dump_yaml(info)})
                self._mcap.finish()
                self._file.sync()
                self._file.close()
                _write_atomically(self.path / "metadata.yaml",
                                  dump_yaml({"rosbag2_bagfile_information": info}))
        finally:
            self._release()

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def bag_information(self) -> dict:
        """The rosbag2 bag metadata (version 9), in rosbag2's key order."""
        start, end = self._time_range or (0, 0)
        total = sum(topic.message_count for topic in self._topics.values())
        return {
            "version": ROSBAG2_METADATA_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": end - start},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": total,
            "topics_with_message_count": [
                {"topic_metadata": {"name": name, "type": topic.type_name,
                                    "serialization_format": "cdr",
                                    "offered_qos_profiles": topic.qos,
                                    "type_description_hash": type_hash(topic.type_name)},
                 "message_count": topic.message_count}
                for name, topic in self._topics.items()],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self.file_name],
            "files": [{"path": self.file_name,
                       "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": end - start},
                       "message_count": total}],
            "custom_data": dict(self._custom_data),
            "ros_distro": ROS_DISTRO,
        }

    def _schema_id(self, type_name: str) -> int:
        """The schema of ``type_name``, registered on first use."""
        if type_name not in self._schema_ids:
            data = definition_text(type_name).encode()
            with self._io("cannot register schema"):
                before = self._file.bytes_written
                schema_id = self._mcap.register_schema(type_name, "ros2msg", data)
                self._account(before, _REGISTRATION_RECORD_OVERHEAD + len(data))
            self._schema_ids[type_name] = schema_id
        return self._schema_ids[type_name]

    def _account(self, bytes_before: int, record_size: int) -> None:
        """After adding a record: if a chunk went to the file, flush it (crash safety);
        otherwise the record sits in the open chunk."""
        if self._file.bytes_written != bytes_before:
            self._file.flush()
            self._buffered = 0
        else:
            self._buffered += record_size

    def _check_writable(self) -> None:
        if self._failure is not None:
            raise UserError(self._key, f"bag unusable after a write error ({self._failure})")
        if self._closed:
            raise UserError(self._key, "bag is already closed")

    @contextlib.contextmanager
    def _io(self, doing: str):
        """Turn an OS error (or a write to a closed file) into a one-line ``UserError``."""
        try:
            yield
        except (OSError, ValueError) as error:
            self._failure = describe_os_error(error)
            raise UserError(self._key, f"{doing}: {self._failure}") from None

    def _release(self) -> None:
        """Close the file without further checks (any error has already been reported)."""
        with contextlib.suppress(OSError, ValueError, AttributeError):
            self._file.close()


def _create_empty_directory(path: Path) -> None:
    """Create the bag directory; an existing one must be empty (never overwrite a bag)."""
    try:
        if path.exists() and (not path.is_dir() or any(path.iterdir())):
            raise UserError(str(path), "already exists and is not an empty directory")
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise UserError(str(path), f"cannot create bag directory: {describe_os_error(error)}") \
            from None


def _write_atomically(path: Path, text: str) -> None:
    """Write via a temporary file and rename, so a crash never leaves half a metadata.yaml."""
    temporary = path.with_name(path.name + ".tmp")
    with open(temporary, "w", encoding="utf-8") as file:
        file.write(text)
        file.flush()
        os.fsync(file.fileno())
    os.replace(temporary, path)


def _checked_string_map(key: str, data: dict) -> dict:
    """MCAP metadata and rosbag2 custom_data are maps from string to string."""
    if not isinstance(data, dict) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        raise UserError(key, "must map strings to strings")
    return dict(data)
