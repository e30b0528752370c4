"""Full ``ros2msg`` message definitions, as rosbag2 stores them in MCAP schemas.

The text of ``pkg/msg/Type`` is its ``.msg`` file followed by every (transitive) dependency once,
in depth-first order of first use, each preceded by a line of 80 ``=`` and a line
``MSG: pkg/Type`` (rosbag2 ``LocalMessageDefinitionSource``, MCAP ``ros2`` profile). Readers such
as ``mcap_ros2`` and ``rosbags`` rebuild the type from this text alone.
"""

import functools
import re
import sys
from pathlib import Path

from mobile_manip_sim.scene.errors import UserError

DELIMITER = "=" * 80

PRIMITIVE_TYPES = frozenset({
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string", "wstring",
})

# Types our bags and live view carry from packages that PyPI has no wheel of (every ROS install
# has them), and whose payloads we encode ourselves (`cdr.tf_message_cdr`): full name → (.msg
# text, exactly the upstream definition; rosidl's type hash, which test_tf_messages checks
# against the package built from that text). Always these, installed or not: a bag's schema
# does not depend on the machine that recorded it.
BUNDLED = {
    "tf2_msgs/msg/TFMessage": (
        "geometry_msgs/TransformStamped[] transforms\n",
        "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"),
}

# "pkg/msg/Type" or "pkg/Type"; the interface kind must be msg.
_TYPE_NAME = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)/(?:msg/)?([A-Za-z][A-Za-z0-9_]*)$")
# The field type is the first token, without array ("[]", "[3]", "[<=3]") or bound ("<=10").
_FIELD_TYPE = re.compile(r"^([A-Za-z][A-Za-z0-9_/]*)")


def split_type_name(type_name: str) -> tuple[str, str]:
    """``sensor_msgs/msg/JointState`` (or ``sensor_msgs/JointState``) → ``(package, Type)``."""
    match = _TYPE_NAME.match(type_name)
    if match is None:
        raise UserError(type_name, "not a message type name (expected pkg/msg/Type)")
    return match.group(1), match.group(2)


@functools.lru_cache(maxsize=None)
def definition_text(type_name: str) -> str:
    """The ``ros2msg`` schema text of ``type_name`` (cached); unknown type → ``UserError``."""
    package, name = split_type_name(type_name)
    return _with_dependencies(package, name, {(package, name)})


def _with_dependencies(package: str, name: str, seen: set) -> str:
    """``.msg`` text of ``package/name``, then each not-yet-seen dependency, depth first."""
    text = _msg_text(package, name)
    for dependency in _dependencies(package, text):
        if dependency in seen:
            continue
        seen.add(dependency)
        header = f"{DELIMITER}\nMSG: {dependency[0]}/{dependency[1]}\n"
        text += header + _with_dependencies(*dependency, seen)
    return text


def _dependencies(package: str, text: str) -> list[tuple[str, str]]:
    """The non-primitive field types of a ``.msg`` text, in order of appearance."""
    found = []
    for line in text.splitlines():
        match = _FIELD_TYPE.match(line.strip())
        if match is None or match.group(1) in PRIMITIVE_TYPES:
            continue
        field_type = match.group(1)
        dependency = split_type_name(field_type) if "/" in field_type else (package, field_type)
        if dependency not in found:
            found.append(dependency)
    return found


@functools.lru_cache(maxsize=None)
def _msg_text(package: str, name: str) -> str:
    """The ``.msg`` file of ``package/msg/name``, ending in exactly one newline."""
    full_name = f"{package}/msg/{name}"
    if full_name in BUNDLED:
        return BUNDLED[full_name][0]
    path = _share_directory(package, full_name) / "msg" / f"{name}.msg"
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise UserError(f"{package}/msg/{name}",
                        f"unknown message type (cannot read {path}: {error.strerror})") from None
    return text.replace("\r\n", "\n").rstrip("\n") + "\n"


def _share_directory(package: str, type_name: str) -> Path:
    """``share/<package>`` from the ament index, or from this interpreter's prefix (a venv with
    the ROS packages installed but no ``AMENT_PREFIX_PATH`` set)."""
    from ament_index_python.packages import get_package_share_directory

    try:
        return Path(get_package_share_directory(package))
    except (LookupError, ValueError, OSError):
        pass
    candidate = Path(sys.prefix) / "share" / package
    if candidate.is_dir():
        return candidate
    raise UserError(type_name, f"unknown message type (package {package!r} not installed)")


@functools.lru_cache(maxsize=None)
def type_hash(type_name: str) -> str:
    """The ``RIHS01_<64 hex>`` type hash of ``pkg/msg/Type``, as rosidl computed it at the
    package's build (``share/<pkg>/msg/<Type>.json``, what rclpy reports for an endpoint and
    `ros2 bag record` stores); "" when the package ships no type description (pre-Jazzy)."""
    import json

    package, name = split_type_name(type_name)
    full_name = f"{package}/msg/{name}"
    if full_name in BUNDLED:
        return BUNDLED[full_name][1]
    path = _share_directory(package, full_name) / "msg" / f"{name}.json"
    try:
        hashes = json.loads(path.read_text(encoding="utf-8")).get("type_hashes", [])
    except (OSError, ValueError):
        return ""
    return next((entry.get("hash_string", "") for entry in hashes
                 if entry.get("type_name") == full_name), "")
