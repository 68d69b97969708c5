"""Field paths into ROS 2 messages: ``twist.twist.linear.x``, ``ranges[0]``,
``status[].level`` (docs/reference/config.md, "field").

A path is names joined by dots; a name may be followed by ``[N]`` (element N of
an array or sequence, ``[-1]`` the last) or ``[]`` (every element: the rest of
the path is read in each, and ``reduce:`` makes one value of them).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from mitigations.rosmsg import message_class
from monitors.errors import UserError

_SEGMENT = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(?:\[(-?\d{1,9})?\])?")
EVERY = "every"  # a segment's index: every element


class ReadError(Exception):
    """This message has no value at the path (an element past the end)."""


@dataclass(frozen=True)
class Segment:
    name: str
    index: int | str | None = None  # None, an element number, or EVERY

    def __str__(self) -> str:
        if self.index is None:
            return self.name
        return f"{self.name}[{'' if self.index == EVERY else self.index}]"


@dataclass(frozen=True)
class FieldPath:
    segments: tuple[Segment, ...]

    def __str__(self) -> str:
        return ".".join(str(s) for s in self.segments)

    @property
    def plain(self) -> bool:
        """Names only: what the CDR layout reader understands (supervisor/daemon/cdr.py)."""
        return all(s.index is None for s in self.segments)

    @property
    def many(self) -> bool:
        """Crosses every element of an array: gives a list of values."""
        return any(s.index == EVERY for s in self.segments)


def parse_path(text: str) -> FieldPath:
    parts = str(text).split(".")
    segments = []
    for part in parts:
        m = _SEGMENT.fullmatch(part.strip())
        if m is None:
            raise UserError(
                f"'{text}' is not a field path",
                hint="names joined by dots, each maybe with [N] or []: ranges[0], status[].level",
            )
        name, index = m.group(1), m.group(2)
        if index is not None:
            segments.append(Segment(name, int(index)))
        elif part.strip().endswith("[]"):
            segments.append(Segment(name, EVERY))
        else:
            segments.append(Segment(name))
    return FieldPath(tuple(segments))


# ------------------------------------------------------------ types


def element_type(t: str) -> str | None:
    """The element type of an array or sequence type ('sequence<float>', 'float[360]',
    'sequence<float, 10>', 'float[<=5]'), or None for any other type."""
    if t.startswith("sequence<") and t.endswith(">"):
        return t[len("sequence<") : -1].split(",")[0].strip()
    if t.endswith("]") and "[" in t:
        return t[: t.index("[")]
    return None


def nested_class(t: str) -> type:
    """The class of a nested type as rosidl names it in a parent ('std_msgs/Header',
    'std_srvs/Trigger_Request'): messages, then service and action parts."""
    pkg, _, name = t.partition("/")
    for kind in ("msg", "srv", "action"):
        try:
            return message_class(f"{pkg}/{kind}/{name}")
        except UserError:
            continue
    raise UserError(f"message type '{t}' is not installed")


@dataclass(frozen=True)
class PathType:
    """What a path reads: the ROS type at its end, and whether it is a list of
    those (``[]`` crossed) and/or an array itself."""

    leaf: str  # the ROS type at the end ('float', 'sequence<float>', 'std_msgs/Header')
    many: bool  # a value per element of a crossed array


def path_type(msg_class: type, path: FieldPath) -> PathType:
    """The type ``path`` reads from messages of ``msg_class``; a name the message
    lacks, an index on a field that is no array, or a path through a primitive is
    an error naming the field."""
    klass: Any = msg_class
    many = False
    done: list[str] = []
    t = ""
    for i, seg in enumerate(path.segments):
        fields = klass.get_fields_and_field_types()
        if seg.name not in fields:
            where = f"'{'.'.join(done)}' ({klass.__name__})" if done else klass.__name__
            raise UserError(
                f"message {where} has no field '{seg.name}' (fields: {', '.join(fields) or 'none'})"
            )
        t = fields[seg.name]
        done.append(str(seg))
        if seg.index is not None:
            element = element_type(t)
            if element is None:
                raise UserError(f"field '{'.'.join(done)}' indexes {t}, which is not an array")
            many = many or seg.index == EVERY
            t = element
        if i == len(path.segments) - 1:
            return PathType(t, many)
        if "/" not in t or element_type(t) is not None:
            raise UserError(f"field '{'.'.join(done)}' is {t}, not a message with fields")
        klass = nested_class(t)
    raise UserError("an empty field path")


# ------------------------------------------------------------ reading


def reader(path: FieldPath) -> Callable[[Any], Any]:
    """A function reading ``path`` from a message (rclpy's or rosbags'): the value,
    or the list of values when the path crosses ``[]``.  An element past the end
    raises ReadError."""
    if path.plain:
        names = tuple(s.name for s in path.segments)
        if len(names) == 1:
            (only,) = names

            def one(msg: Any) -> Any:
                return getattr(msg, only)

            return one

        def plain(msg: Any) -> Any:
            for n in names:
                msg = getattr(msg, n)
            return msg

        return plain
    segments = path.segments

    def walk(msg: Any, k: int) -> Any:
        for j in range(k, len(segments)):
            seg = segments[j]
            msg = getattr(msg, seg.name)
            if seg.index is None:
                continue
            if seg.index == EVERY:
                out: list[Any] = []
                for item in msg:
                    got = walk(item, j + 1) if j + 1 < len(segments) else item
                    if isinstance(got, list) and _crosses(segments, j + 1):
                        out.extend(got)
                    else:
                        out.append(got)
                return out
            try:
                msg = msg[seg.index]
            except IndexError:
                raise ReadError(
                    f"{'.'.join(str(s) for s in segments[: j + 1])}: the message's "
                    f"{seg.name} has {len(msg)} elements"
                ) from None
        return msg

    def indexed(msg: Any) -> Any:
        return walk(msg, 0)

    return indexed


def _crosses(segments: tuple[Segment, ...], start: int) -> bool:
    return any(s.index == EVERY for s in segments[start:])
