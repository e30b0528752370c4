"""Read a rosbag2 MCAP bag (ours or ``ros2 bag record``'s) for replay and resimulation.

``open_bag`` accepts a bag directory (files listed in ``metadata.yaml``; without it, as after a
crash, every ``*.mcap`` inside) or a single ``.mcap`` file, and checks it is a rosbag2 MCAP bag:
MCAP magic, profile ``ros2``, every channel ``cdr`` with a ``ros2msg`` schema.

A file without a usable summary (the recorder was killed, or the file was cut) is indexed by
scanning its records from the start; the scan stops cleanly at the first incomplete or corrupt
record, so every complete chunk is still read. Record lengths are checked against the file size
before anything is read: a truncated file once made the Python reader allocate its way into a
``MemoryError`` (foxglove/mcap #1220). Every read failure becomes a one-line ``UserError``.
Unchunked files (rosbag2's ``fastwrite`` preset) are read only when complete: their messages
have no chunk index to recover from.
"""

import contextlib
import heapq
import io
import struct
import zlib
from pathlib import Path, PurePath
from typing import Iterable, Iterator, NamedTuple

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import InvalidMagic, McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    Metadata,
    MetadataIndex,
    Schema,
)
from mcap.stream_reader import MAGIC_SIZE, breakup_chunk
from mcap.summary import Summary
from mcap.writer import MCAP0_MAGIC as MCAP_MAGIC

from mobile_manip_sim.recording.rosbag2_metadata import bag_information
from mobile_manip_sim.scene import schema
from mobile_manip_sim.scene.errors import UserError

# What the mcap library raises on damaged input (lz4 raises RuntimeError, CRC mismatch is a
# ValueError, a short read an EndOfFile or struct.error, a huge garbage length OverflowError).
READ_ERRORS = (McapError, EOFError, MemoryError, OverflowError, struct.error, ValueError,
               KeyError, UnicodeDecodeError, zstandard.ZstdError, RuntimeError)

_RECORD_PREFIX = struct.Struct("<BQ")  # opcode, record length
_FOOTER = struct.Struct("<QQI")  # summary start, summary offset start, summary CRC


class BagMessage(NamedTuple):
    """One recorded message: CDR payload (with encapsulation header), times in nanoseconds."""

    topic: str
    type_name: str
    data: bytes
    log_time_ns: int
    publish_time_ns: int


def open_bag(path) -> "Bag":
    """Open and validate a bag directory or ``.mcap`` file; problems → one-line ``UserError``."""
    path = Path(path)
    if not path.exists():
        raise UserError(str(path), "no such bag (file or directory not found)")
    bag = Bag(path, [_McapFile(file) for file in _mcap_files(path)])
    bag.topics()  # a topic recorded with two types in split files is an error now, not later
    return bag


class Bag:
    """The readable content of a bag; each query opens and closes its files."""

    def __init__(self, path: Path, files: list["_McapFile"]):
        self.path = path
        self._files = files

    @property
    def recovered(self) -> bool:
        """True if a file had no usable summary (a crashed or truncated recording)."""
        return any(file.recovered for file in self._files)

    def topics(self) -> dict[str, str]:
        """Topic name → type name (``pkg/msg/Type``)."""
        topics: dict[str, str] = {}
        for file in self._files:
            for name, type_name in file.topics.items():
                if topics.setdefault(name, type_name) != type_name:
                    raise UserError(name, f"recorded as both {topics[name]} and {type_name}")
        return topics

    def channel_metadata(self) -> dict[str, dict[str, str]]:
        """Topic → its channel's metadata (``offered_qos_profiles``, ...), first file first."""
        found: dict[str, dict[str, str]] = {}
        for file in self._files:
            for channel in file.summary.channels.values():
                found.setdefault(channel.topic, dict(channel.metadata))
        return found

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
        """Messages of ``topics`` (all if None) in log-time order, read lazily."""
        if topics is not None:
            topics = {topics} if isinstance(topics, str) else set(topics)
            unknown = sorted(topics - self.topics().keys())
            if unknown:
                raise UserError(unknown[0], f"topic not in bag {self.path}")
        streams = [file.messages(topics) for file in self._files]
        return heapq.merge(*streams, key=lambda message: message.log_time_ns)

    def time_span(self) -> tuple[int, int]:
        """(first, last) log time of its messages (ns), from the chunk indexes; (0, 0) if none."""
        chunks = [chunk for file in self._files for chunk in file.summary.chunk_indexes]
        if not chunks:
            return 0, 0
        return (min(chunk.message_start_time for chunk in chunks),
                max(chunk.message_end_time for chunk in chunks))

    def attachments(self) -> dict[str, bytes]:
        """Attachment name → content."""
        return {name: data for file in self._files for name, data in file.attachments().items()}

    def metadata(self) -> dict[str, dict[str, str]]:
        """MCAP metadata record name → its string map (``rosbag2`` holds the bag metadata)."""
        return {name: data for file in self._files for name, data in file.metadata().items()}


class _McapFile:
    """One ``.mcap`` file of a bag with its summary (read from the file, or rebuilt by a scan)."""

    def __init__(self, path: Path):
        self.path = path
        with _reading(path), open(path, "rb") as stream:
            _check_header(path, stream)
            summary = _stored_summary(stream)
            self.recovered = summary is None
            self.summary = _scanned_summary(path, stream) if summary is None else summary
        self.topics = _checked_topics(path, self.summary)

    def messages(self, topics: set[str] | None) -> Iterator[BagMessage]:
        if self.recovered and not self.summary.chunk_indexes:
            return  # cut before its first complete chunk; mcap would read on into the cut
        with self._reader() as reader:
            for schema, channel, message in reader.iter_messages(topics, log_time_order=True):
                yield BagMessage(channel.topic, schema.name, message.data, message.log_time,
                                 message.publish_time)

    def attachments(self) -> dict[str, bytes]:
        with self._reader() as reader:
            return {record.name: bytes(record.data) for record in reader.iter_attachments()}

    def metadata(self) -> dict[str, dict[str, str]]:
        with self._reader() as reader:
            return {record.name: dict(record.metadata) for record in reader.iter_metadata()}

    @contextlib.contextmanager
    def _reader(self):
        """An mcap reader on a fresh handle, its failures turned into ``UserError``."""
        with _reading(self.path), open(self.path, "rb") as stream:
            yield _IndexedReader(stream, self.summary)


class _IndexedReader(SeekingReader):
    """The mcap seeking reader, given the summary we already hold (stored or rebuilt). Chunk
    CRCs are checked: damaged data must fail loudly, not decode into wrong values."""

    def __init__(self, stream, summary: Summary):
        super().__init__(stream, validate_crcs=True)
        self._given_summary = summary

    def get_summary(self) -> Summary:
        return self._given_summary


def _mcap_files(path: Path) -> list[Path]:
    """The ``.mcap`` files of a bag path, in recording order."""
    if path.is_file():
        return [path]
    metadata_path = path / "metadata.yaml"
    if not metadata_path.exists():
        files = sorted(path.glob("*.mcap"))
        if not files:
            raise UserError(str(path), "not a rosbag2 MCAP bag (no metadata.yaml, no .mcap file)")
        return files
    info = _bag_information(metadata_path)
    if info["storage_identifier"] != "mcap":
        raise UserError(str(path), "not a rosbag2 MCAP bag (storage_identifier "
                                   f"{schema.short(info['storage_identifier'])} in metadata.yaml)")
    files = [path / PurePath(name).name for name in info["relative_file_paths"]]
    seen = {}   # (device, inode) → name: a link to a listed file is that file again
    for i, file in enumerate(files):
        if not file.is_file():
            raise UserError(str(file), "listed in metadata.yaml but missing")
        status = file.stat()
        same = seen.setdefault((status.st_dev, status.st_ino), file.name)
        if file in files[:i] or same != file.name:   # read twice, every message played twice
            again = f"{file.name} is listed twice" if same == file.name else \
                f"{file.name} is {same} again (a link to it)"
            raise UserError(f"{metadata_path}: "
                            f"rosbag2_bagfile_information.relative_file_paths[{i}]", again)
    return files


def _bag_information(metadata_path: Path) -> dict:
    """The ``rosbag2_bagfile_information`` map of a metadata.yaml, read with the schema's
    limits (a regular file, size, nesting, aliases, duplicate keys) and checked key by key
    (`rosbag2_metadata`)."""
    what = str(metadata_path)
    return bag_information(schema.load_yaml(metadata_path, what=what), what)


def _check_header(path: Path, stream) -> None:
    """MCAP magic and a Header record with profile ``ros2``."""
    try:
        stream.seek(0)
        header = SeekingReader(stream).get_header()
    except InvalidMagic:
        raise UserError(str(path), "not a rosbag2 MCAP bag (not an MCAP file)") from None
    except READ_ERRORS:
        raise UserError(str(path), "not a rosbag2 MCAP bag (no complete MCAP header)") from None
    if header.profile != "ros2":
        raise UserError(str(path), f"not a rosbag2 MCAP bag (profile {header.profile!r}, "
                                   "expected 'ros2')")


def _stored_summary(stream) -> Summary | None:
    """The file's own summary, or None if it has none, is damaged or does not fit the file.
    Checking the footer first keeps the summary parser away from garbage lengths."""
    size = stream.seek(0, io.SEEK_END)
    if not _footer_checks_out(stream, size):
        return None
    try:
        stream.seek(0)
        summary = SeekingReader(stream).get_summary()
    except (OSError, *READ_ERRORS):
        return None
    if summary is None:
        return None
    if not summary.chunk_indexes and summary.statistics and summary.statistics.chunk_count:
        return None
    if any(index.chunk_start_offset + index.chunk_length > size
           for index in summary.chunk_indexes):
        return None
    return summary


def _footer_checks_out(stream, size: int) -> bool:
    """The file ends in a footer and the magic (a cut file does not), and the summary matches
    the footer's CRC (the mcap reader does not check it, and a damaged chunk index would
    silently reorder or drop messages)."""
    footer_size = _RECORD_PREFIX.size + _FOOTER.size
    if size < 2 * MAGIC_SIZE + footer_size:
        return False
    tail = _read_at(stream, size - MAGIC_SIZE - footer_size, footer_size + MAGIC_SIZE)
    opcode, length = _RECORD_PREFIX.unpack_from(tail)
    summary_start, _, summary_crc = _FOOTER.unpack_from(tail, _RECORD_PREFIX.size)
    if tail[-MAGIC_SIZE:] != MCAP_MAGIC or opcode != Opcode.FOOTER or length != _FOOTER.size:
        return False
    if summary_crc == 0:
        return True
    crc_end = size - MAGIC_SIZE - 4  # everything up to the CRC field itself
    if summary_start == 0 or not MAGIC_SIZE <= summary_start < crc_end:
        return False
    return zlib.crc32(_read_at(stream, summary_start, crc_end - summary_start)) == summary_crc


def _read_at(stream, offset: int, length: int) -> bytes:
    stream.seek(offset)
    return stream.read(length)


def _scanned_summary(path: Path, stream) -> Summary:
    """Rebuild schemas, channels and chunk/attachment/metadata indexes from the records, up to
    the first incomplete or corrupt one (a crashed recording ends mid-chunk)."""
    size = stream.seek(0, io.SEEK_END)
    summary = Summary()
    offset = MAGIC_SIZE
    while offset + _RECORD_PREFIX.size <= size:
        opcode, length = _RECORD_PREFIX.unpack(_read_at(stream, offset, _RECORD_PREFIX.size))
        end = offset + _RECORD_PREFIX.size + length
        if end > size:
            break
        if opcode == Opcode.MESSAGE:
            raise UserError(str(path), "unchunked MCAP file without summary (a crashed "
                                       "'fastwrite' recording?); run `mcap recover` on it")
        try:
            if not _index_record(summary, opcode, stream.read(length), offset, end - offset):
                break
        except READ_ERRORS:
            break
        offset = end
    return summary


def _index_record(summary: Summary, opcode: int, body: bytes, offset: int, length: int) -> bool:
    """Add one data-section record to ``summary``; False at the end of the data section."""
    if opcode in (Opcode.DATA_END, Opcode.FOOTER):
        return False
    data = ReadDataStream(io.BytesIO(body))
    if opcode == Opcode.CHUNK:
        chunk = Chunk.read(data)
        for record in breakup_chunk(chunk, validate_crc=True):
            _add_definition(summary, record)
        summary.chunk_indexes.append(ChunkIndex(
            message_start_time=chunk.message_start_time, message_end_time=chunk.message_end_time,
            chunk_start_offset=offset, chunk_length=length, message_index_offsets={},
            message_index_length=0, compression=chunk.compression,
            compressed_size=len(chunk.data), uncompressed_size=chunk.uncompressed_size))
    elif opcode == Opcode.SCHEMA:
        _add_definition(summary, Schema.read(data))
    elif opcode == Opcode.CHANNEL:
        _add_definition(summary, Channel.read(data))
    elif opcode == Opcode.ATTACHMENT:
        attachment = Attachment.read(data)
        summary.attachment_indexes.append(AttachmentIndex(
            offset=offset, length=length, log_time=attachment.log_time,
            create_time=attachment.create_time, data_size=len(attachment.data),
            name=attachment.name, media_type=attachment.media_type))
    elif opcode == Opcode.METADATA:
        summary.metadata_indexes.append(
            MetadataIndex(offset=offset, length=length, name=Metadata.read(data).name))
    return True


def _add_definition(summary: Summary, record) -> None:
    """Keep schema and channel records (messages are read later, through the chunk index)."""
    if isinstance(record, Schema):
        summary.schemas[record.id] = record
    elif isinstance(record, Channel):
        summary.channels[record.id] = record


def _checked_topics(path: Path, summary: Summary) -> dict[str, str]:
    """Topic → type, checking every channel is rosbag2-shaped (cdr with a ros2msg schema)."""
    topics = {}
    for channel in summary.channels.values():
        schema = summary.schemas.get(channel.schema_id)
        if channel.message_encoding != "cdr" or schema is None or schema.encoding != "ros2msg":
            problem = (f"topic {channel.topic}: encoding {channel.message_encoding!r}, schema "
                       f"{schema.encoding if schema else None!r}; expected 'cdr' and 'ros2msg'")
            raise UserError(str(path), f"not a rosbag2 MCAP bag ({problem})")
        topics[channel.topic] = schema.name
    return topics


@contextlib.contextmanager
def _reading(path: Path):
    """Turn whatever a damaged or unreadable file makes the mcap library raise into a one-line
    ``UserError`` naming the file."""
    try:
        yield
    except OSError as error:
        raise UserError(str(path), f"cannot read ({error.strerror or error})") from None
    except READ_ERRORS as error:
        raise UserError(str(path), f"corrupt or truncated MCAP file ({_one_line(error)})") \
            from None


def _one_line(error: Exception) -> str:
    text = " ".join(str(error).split())
    return f"{type(error).__name__}: {text}" if text else type(error).__name__
