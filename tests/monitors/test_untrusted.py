"""monitors/untrusted.py: the bounds every input is read within."""

from __future__ import annotations

import gzip
import os

import lz4.frame
import pytest
import zstandard
from hypothesis import given
from hypothesis import strategies as st

from monitors.untrusted import (
    Untrusted,
    depth_exceeds,
    inflate,
    load_json,
    printable,
    read_regular,
)


def test_json_nested_past_python_recursion_is_one_error() -> None:
    for depth in (65, 3000, 200_000):
        with pytest.raises(Untrusted, match="nested more than 64 levels"):
            load_json("[" * depth + "]" * depth, max_bytes=1 << 20)
    assert load_json("[" * 64 + "]" * 64, max_bytes=1 << 20) is not None


def test_json_size_and_encoding() -> None:
    with pytest.raises(Untrusted, match="larger than 10 bytes"):
        load_json(b'{"a": "0123456789"}', max_bytes=10)
    with pytest.raises(Untrusted, match=r"not UTF-8 \(byte 7\)"):
        load_json(b'{"a": "\xff"}', max_bytes=100)
    with pytest.raises(Untrusted, match="not JSON"):
        load_json("{", max_bytes=100)


@given(
    st.recursive(st.none() | st.integers(), lambda c: st.lists(c) | st.dictionaries(st.text(), c))
)
def test_depth_agrees_with_a_recursive_count(doc: object) -> None:
    def depth(x: object) -> int:
        if isinstance(x, dict):
            return 1 + max((depth(v) for v in x.values()), default=0)
        if isinstance(x, list):
            return 1 + max((depth(v) for v in x), default=0)
        return 0

    for limit in range(0, 6):
        assert depth_exceeds(doc, limit) == (depth(doc) > limit)


def test_printable_escapes_what_a_terminal_would_obey() -> None:
    assert printable("plain text, ümlaut") == "plain text, ümlaut"
    assert printable("\x1b]0;pwned\x07\r\x1b[2J") == "\\x1b]0;pwned\\x07\\x0d\\x1b[2J"
    assert printable("a\tb\nc\x7f\x9b") == "a\\x09b\\x0ac\\x7f\\x9b"
    assert printable("abc\u202edef\u200b") == "abc\\u202edef\\u200b"


@given(st.text())
def test_printable_output_has_no_control_characters(text: str) -> None:
    assert printable(text).isprintable()


def test_read_regular_refuses_devices_fifos_and_large_files(tmp_path) -> None:
    with pytest.raises(Untrusted, match="not a regular file"):
        read_regular("/dev/zero", max_bytes=100)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(Untrusted, match="not a regular file"):
        read_regular(fifo, max_bytes=100)
    with pytest.raises(Untrusted, match="not a regular file"):
        read_regular(tmp_path, max_bytes=100)
    big = tmp_path / "big"
    big.write_bytes(b"x" * 101)
    with pytest.raises(Untrusted, match="larger than 100 bytes"):
        read_regular(big, max_bytes=100)
    assert read_regular(big, max_bytes=101) == b"x" * 101
    with pytest.raises(Untrusted, match="cannot open"):
        read_regular(tmp_path / "missing", max_bytes=100)


@pytest.mark.parametrize(
    ("kind", "pack"),
    [
        ("zstd", zstandard.ZstdCompressor().compress),
        ("lz4", lz4.frame.compress),
        ("gzip", gzip.compress),
    ],
)
def test_inflate_stops_at_the_cap_without_producing_it(kind: str, pack) -> None:
    bomb = pack(b"\0" * (256 << 20))  # 256 MiB of zeros: a few hundred kB packed at most
    assert len(bomb) < 2 << 20
    with pytest.raises(Untrusted, match="inflates to more than"):
        inflate(kind, bomb)
    with pytest.raises(Untrusted, match="inflates to more than 1000 bytes"):
        inflate(kind, pack(b"\0" * 5000), max_size=1000, max_ratio=10_000)
    data = os.urandom(5000)
    assert inflate(kind, pack(data)) == data
    with pytest.raises(Untrusted, match="does not decompress|cut short"):
        inflate(kind, pack(data)[:100])
    with pytest.raises(Untrusted, match="does not decompress"):
        inflate(kind, b"garbage" + pack(data))


def test_a_zstd_bomb_that_hides_its_size_is_stopped_while_streaming() -> None:
    packed = zstandard.ZstdCompressor(write_content_size=False).compressobj()
    bomb = b"".join(packed.compress(b"\0" * (1 << 20)) for _ in range(256)) + packed.flush()
    assert zstandard.frame_content_size(bomb) == -1
    with pytest.raises(Untrusted, match="inflates to more than"):
        inflate("zstd", bomb)
