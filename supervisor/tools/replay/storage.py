"""What every reader of a recording gives (supervisor/tools/replay/sources.py): raw
chunks of receive times, topic ids and payloads, and where the damage is."""

from __future__ import annotations

import contextlib
import errno
import os
import struct
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Literal

import numpy as np
from rosbags.typesys.store import Typestore

# type names are written as the one type lookup writes them (mitigations/rosmsg.py)
from mitigations.rosmsg import normalise_type as normalise_type
from monitors.errors import UserError
from monitors.untrusted import Untrusted, inflate, printable
from supervisor import files
from supervisor.names import RECORDS_TOPIC, VIOLATIONS_TOPIC

# The daemon's JSON records on ROS: the full record stream (with markers) and the
# violations topic (docs/reference/ros-interfaces.md); both std_msgs/msg/String.
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
    """``path`` opened for reading if it is a regular file (``files.open_regular``);
    ``Damage`` otherwise."""
    try:
        return files.open_regular(path)
    except files.NotRegularFile:
        raise Damage("not a regular file") from None
    except OSError as e:
        raise Damage(f"cannot open: {e.strerror}") from None


def refuse_serialization(topic: str, fmt: str, label: str) -> None:
    """A topic recorded in a serialisation other than CDR, the only one replay decodes,
    is refused rather than misread (an empty one is rosbag2's default, CDR)."""
    if fmt and fmt != "cdr":
        raise UserError(
            f"topic {printable(topic[:200])} is recorded as '{printable(fmt[:40])}', "
            "not 'cdr', the only serialization replay decodes",
            file=label,
            hint="record it again with an RMW that writes CDR (every ROS 2 RMW does by "
            "default), or convert its messages to CDR",
        )


# rosbag2's zstd compression (docs/reference/commands.md, "replay"): a whole storage
# file (``compression_mode: FILE``, ``.db3.zstd``/``.mcap.zstd``) or each payload
# (``MESSAGE``). A CDR payload starts with 0x00 (its encapsulation), a zstd frame with
# this magic, so a payload says which it is even without the bag's metadata.
ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"
_BLOCK = 1 << 20


def inflate_payloads(raw: Raw, bounds: Bounds) -> Raw:
    """``raw`` with each zstd-compressed payload decompressed, each by the bounded
    ``inflate`` (at most ``bounds.chunk_bytes``, ``bounds.ratio`` times its size)."""
    if not len(raw) or raw.items is not None:
        return raw
    b = np.frombuffer(raw.buf, np.uint8)
    some = raw.end > raw.start
    first = np.zeros(len(raw), np.bool_)
    first[some] = b[raw.start[some]] == ZSTD_MAGIC[0]
    if not first.any():
        return raw
    payloads: list[bytes] = []
    for i in range(len(raw)):
        p = raw.payload(i)
        if first[i] and p.startswith(ZSTD_MAGIC):
            try:
                p = inflate("zstd", p, max_size=bounds.chunk_bytes, max_ratio=int(bounds.ratio))
            except Untrusted as e:
                raise Damage(
                    f"the zstd-compressed message at t_ns {int(raw.t_ns[i])}: {e} ({bounds.says()})"
                ) from None
        payloads.append(p)
    return raw_chunk(raw.t_ns.tolist(), raw.topic.tolist(), payloads)


def inflate_file(path: Path, bounds: Bounds) -> Path:
    """A ``.zstd`` storage file decompressed, streamed block by block into a temporary
    file (the caller deletes it), at most ``bounds.ratio`` times the file's size;
    ``Damage`` if it is not zstd, is cut short or inflates past that."""
    import zstandard

    with open_regular(path) as f:
        size = os.fstat(f.fileno()).st_size
        limit = int(bounds.ratio * max(size, 1))
        _zstd_whole(f, size)
        f.seek(0)
        with temp_room(f"inflate {path.name}", limit):  # mkstemp and the writes
            fd, name = tempfile.mkstemp(suffix=path.suffixes[-2] if len(path.suffixes) > 1 else "")
            out_path = Path(name)
            try:
                with os.fdopen(fd, "wb") as out:
                    reader = zstandard.ZstdDecompressor().stream_reader(f, read_across_frames=True)
                    total = 0
                    while block := reader.read(min(_BLOCK, limit + 1 - total)):
                        total += len(block)
                        if total > limit:
                            raise Damage(f"inflates to more than {limit} bytes ({bounds.says()})")
                        out.write(block)
            except zstandard.ZstdError as e:
                out_path.unlink(missing_ok=True)
                raise Damage(f"damaged: the zstd data does not decompress ({e})") from None
            except BaseException:
                out_path.unlink(missing_ok=True)
                raise
    return out_path


# a temporary file's write that failed for want of room (not a bag's read error)
_NO_ROOM = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


@contextlib.contextmanager
def temp_room(what: str, size: int) -> Iterator[None]:
    """A temporary file's writes: a full TMPDIR is one line naming it, not a bug."""
    try:
        yield
    except OSError as e:
        if e.errno not in _NO_ROOM:
            raise
        raise UserError(
            f"cannot {what} into the temporary directory: {e.strerror}",
            file=tempfile.gettempdir(),
            hint=f"set TMPDIR to a directory with room for up to {size:,} bytes",
        ) from None


def _zstd_whole(f: BinaryIO, size: int) -> None:
    """Every zstd frame of ``f`` whole, by its frame and block headers (RFC 8878,
    section 3.1), read without decompressing: zstandard's stream reader ends a frame
    cut short without a word."""
    pos = 0
    while pos < size:
        f.seek(pos)
        head = f.read(18)
        if len(head) < 4:
            raise Damage(f"damaged: zstd data cut short at byte {pos} of {size}")
        (magic,) = struct.unpack_from("<I", head)
        if magic & 0xFFFFFFF0 == 0x184D2A50:  # a skippable frame
            if len(head) < 8:
                raise Damage(f"damaged: zstd data cut short at byte {pos} of {size}")
            pos += 8 + struct.unpack_from("<I", head, 4)[0]
            continue
        if head[:4] != ZSTD_MAGIC:
            raise Damage(f"damaged: no zstd frame at byte {pos}")
        if len(head) < 5:
            raise Damage(f"damaged: zstd data cut short at byte {pos + len(head)} of {size}")
        fhd = head[4]
        single = bool(fhd & 0x20)
        fcs = (1 if single else 0, 2, 4, 8)[fhd >> 6]
        pos += 5 + (0 if single else 1) + (0, 1, 2, 4)[fhd & 3] + fcs
        last = False
        while not last:
            f.seek(pos)
            bh = f.read(3)
            if len(bh) < 3:
                raise Damage(f"damaged: zstd data cut short at byte {pos} of {size}")
            v = bh[0] | bh[1] << 8 | bh[2] << 16
            last, kind, n = bool(v & 1), (v >> 1) & 3, v >> 3
            if kind == 3:
                raise Damage(f"damaged: a reserved zstd block type at byte {pos}")
            pos += 3 + (1 if kind == 1 else n)
        pos += 4 if fhd & 4 else 0  # the content checksum
        if pos > size:
            raise Damage(f"damaged: zstd data cut short at byte {size}, its frame ends at {pos}")


class Source:
    """One file or bag directory: its topics and a stream of raw chunks."""

    label: str
    topics: dict[str, str]  # topic -> recorded type
    counts: dict[str, int] | None  # messages per topic, when the bag's metadata says
    store: Typestore
    warnings: list[str]  # what was found at opening and is not read (said in the summary)

    def chunks(self, ids: dict[str, int], chunk: int) -> Iterator[Raw]:
        raise NotImplementedError
