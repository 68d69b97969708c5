"""Reading bytes that anybody could have written, within bounds.

Every input of the product crosses a trust boundary: a log file from a robot, a
bag, a FRET export, a status document any DDS node can publish, a control
request, an HTTP body.  Each is parsed once where it enters, with the helpers
here, so that no input can exhaust memory (size, nesting and decompression are
capped), crash the reader (``RecursionError``, bad UTF-8) or reach a terminal
as control sequences.  Failures are :class:`Untrusted` (a ``ValueError``), with
one line saying what is wrong; the caller adds the file and line.

The limits and what each surface does with bad input: docs/reference/faults.md,
"Trust".
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path
from typing import Any, BinaryIO

MAX_DEPTH = 64  # nesting of a JSON document; the product's own documents nest < 10
# Decompression: the inflated size of one chunk, file or message, and its ratio to
# the compressed size.  zstd and lz4 rarely exceed 20x on robot data.
MAX_INFLATED = 64 * 1024 * 1024
MAX_RATIO = 100


class Untrusted(ValueError):
    """An input that breaks a bound or does not parse; ``str`` is one line."""


def load_json(data: bytes | str, *, max_bytes: int, max_depth: int = MAX_DEPTH) -> Any:
    """One JSON document of at most ``max_bytes`` bytes and ``max_depth`` levels."""
    if len(data) > max_bytes:
        raise Untrusted(f"larger than {max_bytes} bytes")
    if isinstance(data, bytes):
        try:
            data = data.decode("utf-8")
        except UnicodeDecodeError as e:
            raise Untrusted(f"not UTF-8 (byte {e.start})") from None
    try:
        doc = json.loads(data)
    except RecursionError:
        raise Untrusted(f"nested more than {max_depth} levels") from None
    except ValueError as e:
        raise Untrusted(f"not JSON ({str(e).splitlines()[0]})") from None
    if depth_exceeds(doc, max_depth):
        raise Untrusted(f"nested more than {max_depth} levels")
    return doc


def depth_exceeds(doc: Any, max_depth: int) -> bool:
    """Whether ``doc`` (lists and dicts) nests deeper than ``max_depth``;
    iterative, so any depth is safe to ask about."""
    stack: list[tuple[Any, int]] = [(doc, 1)]
    while stack:
        node, depth = stack.pop()
        if isinstance(node, dict):
            children = node.values()
        elif isinstance(node, list):
            children = node
        else:
            continue
        if depth > max_depth:
            return True
        stack.extend((c, depth + 1) for c in children if isinstance(c, dict | list))
    return False


def printable(text: str) -> str:
    """``text`` safe for a terminal: control characters (C0, DEL, C1) and the
    invisible format characters that reorder or hide text (bidi overrides,
    zero-width) as ``\\xNN`` or ``\\uNNNN``, as journalctl and systemctl show
    them.  Tab and newline are escaped too: one record is one line."""
    if text.isprintable():
        return text
    return "".join(ch if ch.isprintable() else _escape(ch) for ch in text)


def shown(text: str, limit: int) -> str:
    """``text`` as ``printable`` shows it, cut to at most ``limit`` characters (the last
    one an ellipsis when cut): untrusted text of a bounded width."""
    line = printable(text)
    return line if len(line) <= limit else line[: limit - 1] + "…"


def _escape(ch: str) -> str:
    n = ord(ch)
    return f"\\x{n:02x}" if n < 0x100 else f"\\u{n:04x}" if n <= 0xFFFF else f"\\U{n:08x}"


def read_regular(path: str | Path, *, max_bytes: int) -> bytes:
    """The bytes of a regular file of at most ``max_bytes``: never a FIFO, a
    device (``/dev/zero``) or a directory, whatever a path names."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as e:
        raise Untrusted(f"cannot open: {e.strerror}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise Untrusted("not a regular file")
        if st.st_size > max_bytes:
            raise Untrusted(f"larger than {max_bytes} bytes")
        with os.fdopen(fd, "rb", closefd=False) as f:
            data = f.read(max_bytes + 1)
    finally:
        os.close(fd)
    if len(data) > max_bytes:
        raise Untrusted(f"larger than {max_bytes} bytes")
    return data


def inflate(
    compression: str,
    data: bytes,
    *,
    max_size: int = MAX_INFLATED,
    max_ratio: int = MAX_RATIO,
) -> bytes:
    """``data`` decompressed (``zstd``, ``lz4`` frame or ``gzip``), streamed so
    that no more than ``min(max_size, max_ratio * len(data))`` bytes are ever
    produced; past that, :class:`Untrusted`.  Damage is :class:`Untrusted` too,
    except a zstd frame cut short that does not declare its size (zstd's stream
    reader cannot tell): the caller's format check sees it."""
    limit = min(max_size, max_ratio * max(len(data), 1))
    try:
        if compression == "zstd":
            import zstandard

            declared = zstandard.frame_content_size(data)  # -1: not in the frame header
            if declared > limit:
                raise Untrusted(f"inflates to more than {limit} bytes")
            reader = zstandard.ZstdDecompressor().stream_reader(data, read_across_frames=True)
        elif compression == "lz4":
            import lz4.frame

            reader = lz4.frame.LZ4FrameFile(_BytesReader(data), "rb")
        elif compression == "gzip":
            import gzip

            reader = gzip.GzipFile(fileobj=_BytesReader(data), mode="rb")
        else:
            raise Untrusted(f"unknown compression {compression!r}")
        with reader:
            out = read_capped(reader, limit)
        if compression == "zstd" and declared >= 0 and len(out) < declared:
            raise Untrusted(f"zstd data is cut short ({len(out)} of {declared} bytes)")
    except Untrusted:
        raise
    except Exception as e:  # each library has its own error types for damage
        raise Untrusted(f"{compression} data does not decompress ({e})") from None
    return out


def read_capped(stream: BinaryIO, limit: int, block: int = 1 << 20) -> bytes:
    """Everything ``stream`` yields, or :class:`Untrusted` past ``limit`` bytes."""
    parts: list[bytes] = []
    total = 0
    while True:
        part = stream.read(min(block, limit + 1 - total))
        if not part:
            return b"".join(parts)
        total += len(part)
        if total > limit:
            raise Untrusted(f"inflates to more than {limit} bytes")
        parts.append(part)


class _BytesReader:
    """A minimal read-only file over bytes for the gzip and lz4 file readers."""

    def __init__(self, data: bytes) -> None:
        self._view = memoryview(data)
        self._pos = 0

    def read(self, n: int = -1) -> bytes:
        end = len(self._view) if n is None or n < 0 else min(len(self._view), self._pos + n)
        out = bytes(self._view[self._pos : end])
        self._pos = end
        return out

    def readable(self) -> bool:
        return True

    def close(self) -> None:
        pass

    @property
    def closed(self) -> bool:
        return False
