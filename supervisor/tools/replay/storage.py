"""What every reader of a recording gives (supervisor/tools/replay/sources.py): raw
chunks of receive times, topic ids and payloads, and where the damage is."""

from __future__ import annotations

import fcntl
import os
import stat
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Literal

import numpy as np
from rosbags.typesys.store import Typestore

# one type resolution for replay and the recorder (supervisor/inputs/rostypes.py)
from supervisor.inputs.rostypes import normalise_type as normalise_type
from supervisor.names import VIOLATIONS_TOPIC

# The daemon's JSON records on ROS: the full record stream (with markers) and the
# violations topic (docs/reference/ros-interfaces.md); both std_msgs/msg/String.
RECORDS_TOPIC = "/safety_supervisor/records"
RECORD_TOPICS = (RECORDS_TOPIC, VIOLATIONS_TOPIC)
STRING = "std_msgs/msg/String"
CHUNK = 100_000
# What a bag or trace may make replay hold (docs/reference/faults.md, "Trust"): a
# chunk of raw messages in bytes, the metadata.yaml, one JSON-lines line, one JSON
# record on the records topic.  Each is far above what the daemon or rosbag2 writes.
CHUNK_BYTES = 64 << 20
METADATA_BYTES = 4 << 20
LINE_BYTES = 1 << 20
RECORD_BYTES = 16 << 20
NS_MAX = 2**63 - 1  # a receive time in int64 nanoseconds (year 2262)

ValueEvent = tuple[int, str, list[tuple[str, Any]]]
RecordEvent = tuple[int, Literal["record"], dict[str, Any]]
Event = ValueEvent | RecordEvent
Progress = Callable[[int, int | None], None]  # (messages read, total if known)
DTYPES: dict[str, Any] = {"bool": np.bool_, "int64": np.int64, "double": np.float64}


def field_value(msg: Any, path: str) -> Any:
    """A dotted field of a deserialised message (as mitigations/rosmsg.py's get_field)."""
    for part in path.split("."):
        msg = getattr(msg, part)
    return msg


@dataclass
class Raw:
    """Messages of one source as read: receive times, topic ids and the payloads,
    message i's being ``buf[start[i]:end[i]]`` (one buffer, so that a fixed field
    is gathered for all messages at once); a JSON-lines trace has ``items``."""

    t_ns: np.ndarray  # int64
    topic: np.ndarray  # int32, index into Recording.topics
    buf: bytes = b""
    start: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    end: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    items: list[Any] | None = None

    def __len__(self) -> int:
        return len(self.t_ns)

    def payload(self, i: int) -> bytes:
        return self.buf[self.start[i] : self.end[i]]

    def part(self, i: int, j: int) -> Raw:
        items = self.items[i:j] if self.items is not None else None
        return Raw(self.t_ns[i:j], self.topic[i:j], self.buf, self.start[i:j], self.end[i:j], items)

    def in_order(self) -> Raw:
        """Sorted by receive time (stable: equal times keep the file's order)."""
        if len(self.t_ns) < 2 or bool((np.diff(self.t_ns) >= 0).all()):
            return self
        o = np.argsort(self.t_ns, kind="stable")
        items = [self.items[i] for i in o] if self.items is not None else None
        return Raw(self.t_ns[o], self.topic[o], self.buf, self.start[o], self.end[o], items)


def raw_chunk(ts: list[int], topics: list[int], payloads: list[bytes]) -> Raw:
    lengths = np.fromiter(map(len, payloads), dtype=np.int64, count=len(payloads))
    end = np.cumsum(lengths)
    return Raw(
        np.asarray(ts, dtype=np.int64),
        np.asarray(topics, dtype=np.int32),
        b"".join(payloads),
        end - lengths,
        end,
    )


class Damage(Exception):
    """A source ends here; its message locates the damage (the source adds the file)."""


@dataclass(frozen=True)
class Bounds:
    """How far one chunk of a bag may inflate (the config's ``limits:``)."""

    chunk_bytes: int = 64 << 20
    ratio: float = 100.0

    def says(self) -> str:
        return (
            f"limits.replay_chunk_mb {self.chunk_bytes / (1 << 20):g}, "
            f"limits.replay_ratio {self.ratio:g}"
        )


DEFAULT_BOUNDS = Bounds()


def open_regular(path: Path) -> BinaryIO:
    """``path`` opened for reading if it is a regular file: never waits on a FIFO or
    reads a device, whatever a bag names; ``Damage`` otherwise."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as e:
        raise Damage(f"cannot open: {e.strerror}") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise Damage("not a regular file")
    fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
    return os.fdopen(fd, "rb")


class Source:
    """One file or bag directory: its topics and a stream of raw chunks."""

    label: str
    topics: dict[str, str]  # topic -> recorded type
    counts: dict[str, int] | None  # messages per topic, when the bag's metadata says
    store: Typestore
    warnings: list[str]  # what was found at opening and is not read (said in the summary)

    def chunks(self, ids: dict[str, int], chunk: int) -> Iterator[Raw]:
        raise NotImplementedError
