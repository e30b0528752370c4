"""rosbag2's ``metadata.yaml``: the ``rosbag2_bagfile_information`` map as rosbag2 writes it
(metadata versions 1 to 9, Jazzy's), checked key by key for the reader (`bag_reader`). Only
storage_identifier and relative_file_paths are used; the rest is checked so that a damaged or
crafted file is refused with its key, not read on into a traceback.
"""
from __future__ import annotations

from pathlib import Path

from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.schema import (
    MAX_FILE_BYTES,
    integer,
    keys,
    mapping,
    sequence,
    short,
    string,
    string_map,
)

ROSBAG2_MAX_VERSION = 9
MAX_BAG_FILES = 10_000     # entries of relative_file_paths and files
MAX_BAG_TOPICS = 10_000    # entries of topics_with_message_count
_NS = (0, 2**63 - 1)       # rosbag2 keeps times and counts in int64


def _count(value, path):
    integer(value, path, lo=_NS[0], hi=_NS[1])


def _text(value, path):
    string(value, path, max_length=MAX_FILE_BYTES)


def _file_path(value, path):
    """A file of the bag, named relative to its directory (older rosbag2 put the bag's own
    directory in front: only the last part counts)."""
    name = string(value, path, max_length=4096)
    if "\x00" in name or Path(name).name in ("", ".", ".."):
        raise UserError(path, f"expected the name of a file in the bag, got {short(name)}")


def _qos_profiles(value, path):
    """A YAML text (Jazzy) or the list it became in later rosbag2 versions."""
    if isinstance(value, str):
        return _text(value, path)
    for i, profile in enumerate(sequence(value, path, max_length=100)):
        mapping(profile, f"{path}[{i}]")


def _custom_data(value, path):
    if value is not None:   # rosbag2 writes an empty map as ~
        string_map(value, path)


def _record(fields: dict, required=()):
    """A check of a mapping with these keys (each checked by its function), no others."""
    def check(value, path):
        value = mapping(value, path)
        keys(value, path, required=required,
             optional=[key for key in fields if key not in required])
        for key, item in value.items():
            fields[key](item, f"{path}.{key}")
    return check


def _list_of(check, max_length: int, min_length: int = 0):
    def checked(value, path):
        items = sequence(value, path, max_length=max_length)
        if len(items) < min_length:
            raise UserError(path, f"at least {min_length} entries, got {len(items)}")
        for i, item in enumerate(items):
            check(item, f"{path}[{i}]")
    return checked


def _version(value, path):
    integer(value, path, lo=1, hi=ROSBAG2_MAX_VERSION)


_duration = _record({"nanoseconds": _count}, required=("nanoseconds",))
_starting_time = _record({"nanoseconds_since_epoch": _count}, required=("nanoseconds_since_epoch",))
_BAG_INFORMATION = _record({
    "version": _version,
    "storage_identifier": _text,
    "duration": _duration,
    "starting_time": _starting_time,
    "message_count": _count,
    "topics_with_message_count": _list_of(_record({
        "topic_metadata": _record({"name": _text, "type": _text, "serialization_format": _text,
                                   "offered_qos_profiles": _qos_profiles,
                                   "type_description_hash": _text}, required=("name", "type")),
        "message_count": _count}, required=("topic_metadata",)), MAX_BAG_TOPICS),
    "compression_format": _text,
    "compression_mode": _text,
    "relative_file_paths": _list_of(_file_path, MAX_BAG_FILES, min_length=1),
    "files": _list_of(_record({"path": _file_path, "starting_time": _starting_time,
                               "duration": _duration, "message_count": _count},
                              required=("path",)), MAX_BAG_FILES),
    "custom_data": _custom_data,
    "ros_distro": _text,
}, required=("version", "storage_identifier", "relative_file_paths"))


def bag_information(document, what: str = "metadata.yaml") -> dict:
    """The checked ``rosbag2_bagfile_information`` map of a parsed metadata.yaml (`load_yaml`);
    every mistake one `UserError` naming its key path, prefixed with `what` (the file)."""
    root = "rosbag2_bagfile_information"
    try:
        _record({root: _BAG_INFORMATION}, required=(root,))(document, "")
    except UserError as error:
        raise UserError(f"{what}: {error.key}" if error.key else what, error.problem) from None
    return document[root]
