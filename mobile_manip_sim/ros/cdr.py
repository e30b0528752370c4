"""Exact, deterministic CDR payloads from rclpy messages.

``rclpy.serialization.serialize_message`` (the rmw_fastrtps type support of the PyPI wheels)
returns a buffer with the right values but uninitialised alignment padding and a few extra
bytes after the end of the message: the same message serialises to different bytes from one
call to the next, and readers that check the size (``rosbags``: "CDR message size mismatch")
reject it. ``exact_cdr`` keeps rclpy as the serialiser and cleans its output: it walks the
message layout (plain CDR, XCDR1: every primitive aligned to its size, at most 8, counted from
the end of the 4-byte encapsulation header; strings and sequences prefixed by a uint32 length),
zeroes every padding byte and cuts the buffer at the message's true end. Values are never
touched, so the result deserialises to the very same message — in rclpy and in every other
CDR reader — and equal messages always give equal bytes.
"""
from __future__ import annotations

import struct

from rclpy.serialization import serialize_message
from rosidl_parser import definition

from ..scene.errors import CdrLayoutError
from .message_types import message_class

ENCAPSULATION_HEADER = 4
_MAX_ALIGNMENT = 8  # XCDR1

_PRIMITIVE_SIZES = {
    "boolean": 1, "octet": 1, "char": 1, "uint8": 1, "int8": 1,
    "wchar": 2, "uint16": 2, "int16": 2,
    "float": 4, "uint32": 4, "int32": 4,
    "double": 8, "uint64": 8, "int64": 8,
}


def exact_cdr(message) -> bytes:
    """``message`` serialised by rclpy, padding zeroed and trailing bytes removed."""
    return canonical_cdr(serialize_message(message), type(message))


def canonical_cdr(raw: bytes, message_type) -> bytes:
    """The exact CDR of a ``message_type`` payload ``raw`` (with its encapsulation header):
    padding zeroed, options field zeroed, cut at the end of the message."""
    if len(raw) < ENCAPSULATION_HEADER or raw[0] != 0 or raw[1] not in (0, 1):
        raise CdrLayoutError(f"{message_type.__name__}: not a plain CDR encapsulation "
                             f"({bytes(raw[:4]).hex()})")
    walker = _Walker(bytearray(raw), little_endian=raw[1] == 1)
    walker.structure(message_type)
    end = ENCAPSULATION_HEADER + walker.position
    if end > len(raw):
        raise CdrLayoutError(f"{message_type.__name__}: layout needs {end} bytes, buffer has "
                             f"{len(raw)}")
    walker.buffer[2:4] = b"\0\0"
    return bytes(walker.buffer[:end])


class _Walker:
    """Walks a payload by type; ``position`` counts from the end of the encapsulation header."""

    def __init__(self, buffer: bytearray, little_endian: bool):
        self.buffer = buffer
        self.position = 0
        self._uint32 = struct.Struct("<I" if little_endian else ">I")

    def align(self, size: int) -> None:
        alignment = min(size, _MAX_ALIGNMENT)
        padding = -self.position % alignment
        if padding:
            start = ENCAPSULATION_HEADER + self.position
            self.buffer[start:start + padding] = bytes(padding)
            self.position += padding

    def length(self) -> int:
        self.align(4)
        start = ENCAPSULATION_HEADER + self.position
        if start + 4 > len(self.buffer):
            raise CdrLayoutError("buffer ends inside a length field")
        (value,) = self._uint32.unpack_from(self.buffer, start)
        self.position += 4
        return value

    def structure(self, message_type) -> None:
        slot_types = _slot_types(message_type)
        if not slot_types:  # an empty .msg is serialised as one uint8 placeholder
            self.position += 1
        for slot_type in slot_types:
            self.value(slot_type)

    def value(self, slot_type) -> None:
        if isinstance(slot_type, definition.BasicType):
            size = _PRIMITIVE_SIZES.get(slot_type.typename)
            if size is None:
                raise CdrLayoutError(f"unsupported primitive {slot_type.typename!r}")
            self.align(size)
            self.position += size
        elif isinstance(slot_type, definition.AbstractWString):
            raise CdrLayoutError("wstring fields are not supported")
        elif isinstance(slot_type, definition.AbstractString):
            size = self.length()  # includes the terminating NUL
            self.position += size
            self.check()
        elif isinstance(slot_type, definition.NamespacedType):
            self.structure(message_class("/".join((*slot_type.namespaces, slot_type.name))))
        elif isinstance(slot_type, definition.Array):
            self.elements(slot_type.value_type, slot_type.size)
        elif isinstance(slot_type, definition.AbstractSequence):
            self.elements(slot_type.value_type, self.length())
        else:
            raise CdrLayoutError(f"unsupported field type {slot_type!r}")

    def elements(self, value_type, count: int) -> None:
        if count == 0:
            return  # Fast-CDR aligns for the first element only when there is one
        if isinstance(value_type, definition.BasicType):
            size = _PRIMITIVE_SIZES.get(value_type.typename)
            if size is None:
                raise CdrLayoutError(f"unsupported primitive {value_type.typename!r}")
            self.align(size)
            self.position += size * count
            self.check()
            return
        for _ in range(count):
            self.value(value_type)
            self.check()

    def check(self) -> None:
        """A length read from the buffer must not lead past its end (garbage would make
        the walk run away)."""
        if ENCAPSULATION_HEADER + self.position > len(self.buffer):
            raise CdrLayoutError(f"layout runs past the end of the {len(self.buffer)}-byte "
                                 f"buffer")


def _slot_types(message_type) -> tuple:
    return tuple(getattr(message_type, "SLOT_TYPES", ()))


TF_MESSAGE_TYPE = "tf2_msgs/msg/TFMessage"


def tf_message_cdr(stamp_ns: int, transforms) -> bytes:
    """The exact CDR (little endian, padding zeroed) of a tf2_msgs/TFMessage holding
    ``transforms`` (`frames.Transform`: parent, child, translation, rotation x y z w), all stamped
    ``stamp_ns``. Encoded here because PyPI has no tf2_msgs for rclpy to serialise with; equal to
    ``exact_cdr`` of the same message where tf2_msgs is installed (test_tf_messages)."""
    out = bytearray(b"\0\1\0\0")            # CDR_LE encapsulation, options zero

    def align(size):
        out.extend(bytes(-(len(out) - ENCAPSULATION_HEADER) % size))

    def string(text):
        data = text.encode("utf-8") + b"\0"
        align(4)
        out.extend(struct.pack("<I", len(data)) + data)

    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    align(4)
    out.extend(struct.pack("<I", len(transforms)))
    for transform in transforms:
        align(4)
        out.extend(struct.pack("<iI", sec, nanosec))   # header.stamp
        string(transform.parent)                       # header.frame_id
        string(transform.child)                        # child_frame_id
        align(8)
        out.extend(struct.pack("<7d", *transform.translation, *transform.rotation))
    return bytes(out)


def tf_message_transforms(data: bytes) -> list[tuple[int, tuple]]:
    """The transforms of a tf2_msgs/TFMessage's CDR (either byte order), as (stamp ns,
    (parent, child, translation, rotation x y z w)) — the inverse of `tf_message_cdr`, for bags
    read where tf2_msgs is not installed. Damage is a ValueError."""
    data = bytes(data)
    if len(data) < ENCAPSULATION_HEADER or data[0] != 0 or data[1] not in (0, 1):
        raise ValueError("not a CDR payload (bad encapsulation header)")
    order = "<" if data[1] == 1 else ">"
    at = ENCAPSULATION_HEADER

    def take(fmt: str, size: int):
        nonlocal at
        at += -(at - ENCAPSULATION_HEADER) % size
        values = struct.unpack_from(order + fmt, data, at)   # struct.error is a ValueError
        at += struct.calcsize(order + fmt)
        return values

    def string() -> str:
        nonlocal at
        (length,) = take("I", 4)
        if not 0 < length <= len(data) - at:
            raise ValueError("string length beyond the payload")
        text = data[at:at + length - 1].decode("utf-8")
        at += length
        return text

    (count,) = take("I", 4)
    if count > len(data) // 60:   # a transform takes at least 60 bytes
        raise ValueError(f"{count} transforms cannot fit in {len(data)} bytes")
    transforms = []
    for _ in range(count):
        sec, nanosec = take("iI", 4)
        parent, child = string(), string()
        values = take("7d", 8)
        transforms.append((sec * 1_000_000_000 + nanosec,
                           (parent, child, values[:3], values[3:])))
    return transforms
