"""Where a field lies in a CDR-encoded ROS 2 message, when that place is fixed.

A ROS 2 message on the wire is a 4-byte encapsulation header and the fields in
order, each primitive aligned to its own size counted from the end of the header
(XCDR1, what rmw and rosbag2 write). Until the first string or sequence every field
has a fixed offset; after one, each message's offset follows from the lengths that
precede the field. Either way the field is read from many payloads at once with
numpy instead of deserialising each message (``FieldPlan.gather``).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

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
class FieldPlan:
    """How to find a primitive field in a payload: the steps over the fields before
    it. ``("skip", align, size)`` aligns and skips fixed bytes; ``("string",)`` and
    ``("seq", elem_size)`` skip a length-prefixed string or primitive sequence, whose
    length each message says. Without those the field has a fixed offset."""

    steps: tuple[tuple[Any, ...], ...]
    size: int
    dtype: str  # numpy dtype, little-endian
    ros_type: str

    @property
    def fixed(self) -> bool:
        return all(s[0] == "skip" for s in self.steps)

    def gather(self, buf: np.ndarray, start: np.ndarray, end: np.ndarray) -> np.ndarray | None:
        """The field of every payload ``buf[start[i]:end[i]]`` at once, or None if
        one is too short or not little-endian (the caller then deserialises them)."""
        if not len(start):
            return np.empty(0, dtype=self.dtype)
        if ((end - start) < HEADER).any() or (buf[start + 1] != CDR_LE).any():
            return None
        body = start + HEADER
        room = end - body
        if self.fixed:
            pos = 0
            for _, align, size in self.steps:
                pos = _align(pos, align) + size
            pos = _align(pos, self.size)
            if (room < pos + self.size).any():
                return None
            return _take(buf, body + pos, self.size, self.dtype)
        at = np.zeros(len(start), dtype=np.int64)
        for step in self.steps:
            if step[0] == "skip":
                at = _align_a(at, step[1]) + step[2]
                continue
            at = _align_a(at, 4)
            if (room < at + 4).any():
                return None
            n = _take(buf, body + at, 4, "<u4").astype(np.int64)
            at = at + 4
            if step[0] == "string":
                at = at + n
            else:
                # rosbags aligns a sequence's elements only when it has some
                at = np.where(n > 0, _align_a(at, step[1]), at) + n * step[1]
        at = _align_a(at, self.size)
        if (room < at + self.size).any():
            return None
        return _take(buf, body + at, self.size, self.dtype)

    def read(self, data: bytes) -> Any:
        """The field of ONE payload (the daemon's recording path, where the message
        arrives serialized), or None when it is too short or not little-endian, or
        the field's type is one the daemon reads differently (the caller then
        deserialises it).  A bool is a bool, as rclpy gives it."""
        unpack = _SCALAR.get(self.ros_type)
        if unpack is None or len(data) < HEADER or data[1] != CDR_LE:
            return None
        pos = 0
        for step in self.steps:
            if step[0] == "skip":
                pos = _align(pos, step[1]) + step[2]
                continue
            pos = _align(pos, 4)
            if HEADER + pos + 4 > len(data):
                return None
            (n,) = _U32.unpack_from(data, HEADER + pos)
            pos += 4
            if step[0] == "string":
                pos += n
            else:  # elements aligned only when there are some, as rosbags writes them
                pos = (_align(pos, step[1]) if n else pos) + n * step[1]
        pos = _align(pos, self.size)
        if HEADER + pos + self.size > len(data):
            return None
        value = unpack.unpack_from(data, HEADER + pos)[0]
        return value != 0 if self.ros_type == "bool" else value


_U32 = struct.Struct("<I")
# The field types read from a payload directly: rclpy gives these as bool, int and
# float; byte and char come out of rclpy differently, so they are deserialised.
_SCALAR = {
    "bool": struct.Struct("<B"),
    "int8": struct.Struct("<b"),
    "uint8": struct.Struct("<B"),
    "int16": struct.Struct("<h"),
    "uint16": struct.Struct("<H"),
    "int32": struct.Struct("<i"),
    "uint32": struct.Struct("<I"),
    "int64": struct.Struct("<q"),
    "uint64": struct.Struct("<Q"),
    "float32": struct.Struct("<f"),
    "float64": struct.Struct("<d"),
}


def _take(buf: np.ndarray, at: np.ndarray | int, size: int, dtype: str) -> np.ndarray:
    idx = np.asarray(at)[..., None] + np.arange(size)
    return np.ascontiguousarray(buf[idx]).view(dtype).reshape(-1)


def _align(pos: int, size: int) -> int:
    return pos + (-pos % size)


def _align_a(pos: np.ndarray, size: int) -> np.ndarray:
    return pos + (-pos % size)


class _Unsupported(Exception):
    """A field the plan cannot reach (after a sequence of strings or messages)."""


MAX_UNROLL = 64  # array elements laid out one by one at most (arrays of strings/messages)


def _plan(
    store: Typestore, msgtype: str, path: list[str] | None, steps: list[tuple[Any, ...]]
) -> FieldPlan | None:
    """Append msgtype's steps (all of it, or up to path's field, which it returns)."""
    fields = store.fielddefs[msgtype][1]
    for name, (kind, detail) in fields:
        want = path is not None and path[0] == name
        rest = path[1:] if want and path is not None else None
        if kind == Nodetype.BASE:
            typ = detail[0]
            if typ in PRIMITIVES:
                size, dtype = PRIMITIVES[typ]
                if want and not rest:
                    return FieldPlan(tuple(steps), size, dtype, typ)
                steps.append(("skip", size, size))
            elif typ == "string":
                steps.append(("string",))
            else:
                raise _Unsupported  # wstring
        elif kind == Nodetype.NAME:
            found = _plan(store, detail, rest or None, steps)
            if want:
                return found
        elif kind == Nodetype.ARRAY:
            (subkind, subdetail), length = detail
            if subkind == Nodetype.BASE and subdetail[0] in PRIMITIVES:
                size = PRIMITIVES[subdetail[0]][0]
                steps.append(("skip", size, size * length))
            elif length > MAX_UNROLL:
                raise _Unsupported
            elif subkind == Nodetype.BASE and subdetail[0] == "string":
                steps.extend([("string",)] * length)
            elif subkind == Nodetype.NAME:
                for _ in range(length):
                    _plan(store, subdetail, None, steps)
            else:
                raise _Unsupported
        else:
            (subkind, subdetail), _ = detail
            if subkind == Nodetype.BASE and subdetail[0] in PRIMITIVES:
                steps.append(("seq", PRIMITIVES[subdetail[0]][0]))
            else:
                raise _Unsupported  # a sequence of strings or messages
        if want:
            return None  # the path goes through a primitive, array or sequence
    if not fields:
        steps.append(("skip", 1, 1))  # an empty message is one uint8 in CDR
    return None


def field_plan(store: Typestore, msgtype: str, path: str) -> FieldPlan | None:
    """How to read the dotted field path of msgtype from payloads in bulk, or None if
    a sequence of strings or messages comes before it."""
    try:
        return _plan(store, msgtype, path.split("."), [])
    except (_Unsupported, KeyError):
        return None
