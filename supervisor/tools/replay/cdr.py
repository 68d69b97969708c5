"""Where a field lies in a CDR-encoded ROS 2 message, when that place is fixed.

A ROS 2 message on the wire is a 4-byte encapsulation header and the fields in
order, each primitive aligned to its own size counted from the end of the header
(XCDR1, what rmw and rosbag2 write). Until the first string or sequence every field
has a fixed offset, so a field before it can be read from each payload at that
offset: for many messages at once with numpy instead of deserialising each one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.typesys.store import Typestore

HEADER = 4  # the CDR encapsulation header: 2 bytes kind, 2 bytes options
CDR_LE = 1  # the header's second byte: 1 is little-endian CDR (0 is big-endian)

# primitive type -> (size, numpy dtype, little-endian)
PRIMITIVES: dict[str, tuple[int, str]] = {
    "bool": (1, "u1"),
    "byte": (1, "u1"),
    "octet": (1, "u1"),
    "char": (1, "u1"),
    "uint8": (1, "u1"),
    "int8": (1, "i1"),
    "uint16": (2, "<u2"),
    "int16": (2, "<i2"),
    "uint32": (4, "<u4"),
    "int32": (4, "<i4"),
    "float32": (4, "<f4"),
    "uint64": (8, "<u8"),
    "int64": (8, "<i8"),
    "float64": (8, "<f8"),
}


@dataclass(frozen=True)
class FixedField:
    """A primitive at a fixed byte offset of every payload (the header included)."""

    offset: int
    size: int
    dtype: str  # numpy dtype, little-endian
    ros_type: str

    def gather(self, buf: np.ndarray, start: np.ndarray, end: np.ndarray) -> np.ndarray | None:
        """The field of every payload ``buf[start[i]:end[i]]`` at once, or None if
        one is too short or not little-endian (the caller then deserialises them)."""
        if not len(start):
            return np.empty(0, dtype=self.dtype)
        if ((end - start) < self.offset + self.size).any() or (buf[start + 1] != CDR_LE).any():
            return None
        idx = (start + self.offset)[:, None] + np.arange(self.size)
        return np.ascontiguousarray(buf[idx]).view(self.dtype).reshape(len(start))


class _Variable(Exception):
    """The walk met a string or sequence: nothing after it has a fixed offset."""


def _align(pos: int, size: int) -> int:
    return pos + (-pos % size)


def _walk(
    store: Typestore, msgtype: str, pos: int, path: list[str] | None
) -> tuple[int, FixedField | None]:
    """Lay out msgtype from body offset pos; returns the end offset and, when path is
    given, the field it names (None when the path is not in this message)."""
    found: FixedField | None = None
    for name, (kind, detail) in store.fielddefs[msgtype][1]:
        want = path is not None and path[0] == name
        if kind == Nodetype.BASE:
            typ = detail[0]
            if typ not in PRIMITIVES:
                raise _Variable  # a string
            size, dtype = PRIMITIVES[typ]
            pos = _align(pos, size)
            if want and path is not None and len(path) == 1:
                return pos + size, FixedField(HEADER + pos, size, dtype, typ)
            pos += size
        elif kind == Nodetype.NAME:
            rest = path[1:] if want and path is not None else None
            pos, sub = _walk(store, detail, pos, rest or None)
            if want:
                return pos, sub
        elif kind == Nodetype.ARRAY:
            (subkind, subdetail), length = detail
            if subkind != Nodetype.BASE or subdetail[0] not in PRIMITIVES:
                raise _Variable  # an array of messages or strings: not worth laying out
            size = PRIMITIVES[subdetail[0]][0]
            pos = _align(pos, size) + size * length
        else:
            raise _Variable  # a sequence
        if want:
            return pos, None  # the path goes through a primitive or an array
    # An empty message is one uint8 in CDR (rosidl's structure_needs_at_least_one_member).
    if not store.fielddefs[msgtype][1]:
        pos += 1
    return pos, found


def fixed_field(store: Typestore, msgtype: str, path: str) -> FixedField | None:
    """The fixed place of the dotted field path in msgtype, or None if a string or
    sequence comes before it (or the path does not lead to a primitive)."""
    try:
        return _walk(store, msgtype, 0, path.split("."))[1]
    except _Variable:
        return None
    except KeyError:
        return None
