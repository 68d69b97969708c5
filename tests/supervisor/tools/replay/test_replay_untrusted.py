"""Bags and traces anybody could have written, read by ``replay`` and ``report --bag``
(docs/reference/faults.md, "Trust"): decompression bombs, a huge ``metadata.yaml``,
crafted MCAP records, hostile sqlite3 rows and JSON-lines lines.  Every outcome is exit
0, or exit 1 with one located line (the damage recorded as ``replay_damaged``), never
exit 3 or a traceback, and the bombs stay under 512 MB of memory.

The bombs run in a child limited to 2 GiB of address space, so that the code before
the bounds failed (MemoryError, exit 3) instead of taking the machine's memory."""

from __future__ import annotations

import json
import os
import sqlite3
import struct
import subprocess
import sys
import tracemalloc
import zlib
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from mitigations.violationlog.reader import iter_records
from supervisor.cli import main

TS = get_typestore(Stores.ROS2_JAZZY)
GIB = 1 << 30
MEMORY = 2 * GIB  # the child's address space: a red run fails instead of swapping
PEAK = 512 << 20  # what replay may hold on any of these inputs

CONFIG = """\
component: Robot
step: {policy: on_message}
variables:
  x: {type: int64, topic: /x, msg: std_msgs/msg/Int64}
  level: {type: double, topic: /status, msg: acme_msgs/msg/Status, field: level, initial: 0.0}
requirements:
  - {id: R1, text: Robot shall always satisfy x < 100}
  - {id: R2, text: Robot shall always satisfy level < 100.0}
"""

# The child reports its own peak resident size (ru_maxrss of the replay it ran).
MEASURED = (
    "import json, resource, subprocess, sys;"
    f"lim = lambda: resource.setrlimit(resource.RLIMIT_AS, ({MEMORY}, {MEMORY}));"
    "r = subprocess.run([sys.executable, '-m', 'supervisor', *sys.argv[1:]],"
    " capture_output=True, text=True, preexec_fn=lim, timeout=300);"
    "peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024;"
    "print(json.dumps({'rc': r.returncode, 'out': r.stdout, 'err': r.stderr, 'peak': peak}))"
)


def cli(*args: str, timeout: float = 300) -> dict[str, Any]:
    """The real ``safety-supervisor`` in a child limited to MEMORY: exit code, output
    and peak resident bytes."""
    env = {k: v for k, v in os.environ.items() if k != "SAFETY_SUPERVISOR_DEBUG"}
    run = subprocess.run(
        [sys.executable, "-c", MEASURED, *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
    )
    assert run.returncode == 0, run.stderr
    out: dict[str, Any] = json.loads(run.stdout)
    return out


def errors(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.strip() and "replay:" not in line[:8]]


def assert_one_located_line(err: str, name: str) -> str:
    lines = errors(err)
    assert "Traceback" not in err and "internal error" not in err, err
    assert len(lines) == 1, err
    assert name in lines[0], lines[0]
    return lines[0]


def in_process(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str]:
    """The replay command's entry point in this process (fast for many inputs); its
    exit code and stderr (stdout in ``LAST_OUT``)."""
    os.environ.pop("SAFETY_SUPERVISOR_DEBUG", None)
    rc = main([*args])
    got = capsys.readouterr()
    LAST_OUT[:] = [got.out]
    return rc, got.err


LAST_OUT = [""]


@pytest.fixture
def cfg(tmp_path: Path) -> Path:
    p = tmp_path / "c.yaml"
    p.write_text(CONFIG)
    return p


def ser_int64(v: int) -> bytes:
    return TS.serialize_cdr(TS.types["std_msgs/msg/Int64"](data=v), "std_msgs/msg/Int64")


def ser_string(s: str) -> bytes:
    return TS.serialize_cdr(TS.types["std_msgs/msg/String"](data=s), "std_msgs/msg/String")


# ----------------------------------------------------------------- MCAP by hand


def _str(s: str) -> bytes:
    b = s.encode()
    return struct.pack("<I", len(b)) + b


def _rec(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def _message(cid: int, seq: int, t: int, payload: bytes) -> bytes:
    return _rec(5, struct.pack("<HIQQ", cid, seq, t, t) + payload)


def _head() -> bytes:
    schema = _rec(3, struct.pack("<H", 1) + _str("std_msgs/msg/Int64") + _str("ros2msg")
                  + struct.pack("<I", 10) + b"int64 data")  # fmt: skip
    channel = _rec(4, struct.pack("<HH", 1, 1) + _str("/x") + _str("cdr") + struct.pack("<I", 0))
    return b"\x89MCAP0\r\n" + _rec(1, _str("ros2") + _str("test")) + schema + channel


def _tail() -> bytes:
    return _rec(15, struct.pack("<I", 0)) + _rec(2, struct.pack("<QQI", 0, 0, 0)) + b"\x89MCAP0\r\n"


def zeros_compressed(compression: str, size: int, *, frame_size: bool = False) -> bytes:
    """``size`` zero bytes compressed, streamed (never all in memory)."""
    block = b"\0" * (16 << 20)
    if compression == "zstd":
        import zstandard

        c = zstandard.ZstdCompressor(level=3)
        z = c.compressobj(size=size if frame_size else -1)
        parts = [z.compress(block[: min(len(block), size - i)]) for i in range(0, size, len(block))]
        return b"".join(parts) + z.flush()
    import lz4.frame

    lc = lz4.frame.LZ4FrameCompressor()
    parts = [lc.begin()]
    parts += [lc.compress(block[: min(len(block), size - i)]) for i in range(0, size, len(block))]
    return b"".join(parts) + lc.flush()


def bomb_mcap(path: Path, compression: str, size: int, declared: int, frame_size: bool) -> Path:
    """Three good messages, then a chunk of ``compression`` that inflates to ``size``
    zero bytes and says it holds ``declared``."""
    good = b"".join(_message(1, i, 1000 + i, ser_int64(i)) for i in range(3))
    data = zeros_compressed(compression, size, frame_size=frame_size)
    chunk = _rec(6, struct.pack("<QQQI", 2000, 3000, declared, 0) + _str(compression)
                 + struct.pack("<Q", len(data)) + data)  # fmt: skip
    path.write_bytes(_head() + good + chunk + _tail())
    return path


BOMBS = [
    # (compression, inflated size, declared size, zstd frame says its size)
    ("zstd", 4 * GIB, 4 * GIB, False),  # the attack's 131 kB chunk
    ("zstd", 4 * GIB, 1000, True),  # the frame's own size, not the record's
    ("zstd", 4 * GIB, 1000, False),  # lies about its size
    ("lz4", 1 * GIB, 1 * GIB, False),
    ("lz4", 1 * GIB, 1000, False),
]


@pytest.mark.slow
@pytest.mark.parametrize("compression,size,declared,frame_size", BOMBS)
def test_a_chunk_that_inflates_to_gibs_is_damage_within_512_mb(
    tmp_path: Path, cfg: Path, compression: str, size: int, declared: int, frame_size: bool
) -> None:
    bag = bomb_mcap(tmp_path / "bomb.mcap", compression, size, declared, frame_size)
    out = tmp_path / "out.jsonl"
    r = cli("replay", str(cfg), str(bag), "-o", str(out), "--quiet", timeout=120)
    line = assert_one_located_line(r["err"], str(bag))
    assert r["rc"] == 1, r
    assert "byte" in line and "chunk" in line, line
    records = list(iter_records(str(out)))
    assert records[-1].get("what") == "replay_damaged"
    assert "replayed 3 messages" in r["out"]
    assert r["peak"] < PEAK, f"peak {r['peak'] / 2**20:.0f} MB"


def test_the_chunk_cap_and_ratio_are_the_configs_limits(
    tmp_path: Path, cfg: Path, capsys: Any
) -> None:
    import numpy as np
    import zstandard

    # 2 MiB of 2-bit noise (about 4x in zstd): under the default cap and ratio, over a
    # cap of 1 MB, and over a ratio of 2
    noise = np.random.default_rng(0).integers(0, 4, 2 << 20).astype(np.uint8).tobytes()
    data = zstandard.ZstdCompressor().compress(noise)
    chunk = _rec(6, struct.pack("<QQQI", 0, 0, len(noise), 0) + _str("zstd")
                 + struct.pack("<Q", len(data)) + data)  # fmt: skip
    bag = tmp_path / "b.mcap"
    bag.write_bytes(_head() + _message(1, 0, 1000, ser_int64(1)) + chunk + _tail())
    rc, err = in_process(capsys, "replay", str(cfg), str(bag), "--quiet")
    # inflated: noise is no records (damage, but not a bound)
    assert rc == 1 and "chunk at byte" in err and "limits." not in err, err
    cfg.write_text(CONFIG + "limits: {replay_chunk_mb: 1}\n")
    rc, err = in_process(capsys, "replay", str(cfg), str(bag), "--quiet")
    assert rc == 1 and "limits.replay_chunk_mb 1," in assert_one_located_line(err, str(bag))
    cfg.write_text(CONFIG + "limits: {replay_ratio: 2}\n")
    rc, err = in_process(capsys, "replay", str(cfg), str(bag), "--quiet")
    line = assert_one_located_line(err, str(bag))
    assert rc == 1 and "inflates to more than" in line and "limits.replay_ratio 2)" in line
    assert "replayed 1 messages" in LAST_OUT[0]


# ----------------------------------------------------------------- metadata.yaml


def small_bag(path: Path, plugin: StoragePlugin = StoragePlugin.MCAP, n: int = 5) -> Path:
    with Writer(path, version=9, storage_plugin=plugin) as w:
        c = w.add_connection("/x", "std_msgs/msg/Int64", typestore=TS)
        for i in range(n):
            w.write(c, 1000 + i, ser_int64(i))
    return path


@pytest.mark.slow
def test_a_huge_metadata_yaml_is_one_located_line_within_512_mb(tmp_path: Path, cfg: Path) -> None:
    bag = small_bag(tmp_path / "bag")
    meta = bag / "metadata.yaml"
    text = meta.read_text()
    # 30 MB of topics: the attack's 52 MB file reached 1.75 GB
    entry = (
        "\n  - topic_metadata: {name: /t%d, type: std_msgs/msg/Int64, "
        "serialization_format: cdr, offered_qos_profiles: ''}\n    message_count: 0"
    )
    extra = "".join(entry % i for i in range(300_000))
    meta.write_text(
        text.replace("topics_with_message_count:", "topics_with_message_count:" + extra, 1)
    )
    assert meta.stat().st_size > 30e6
    r = cli("replay", str(cfg), str(bag), "--quiet", timeout=120)
    line = assert_one_located_line(r["err"], str(meta))
    assert r["rc"] == 1 and "larger than" in line, line
    assert r["peak"] < PEAK, f"peak {r['peak'] / 2**20:.0f} MB"


METADATA_EDITS = [
    # (what replaces 'topics_with_message_count:' or the files, the words of the error)
    ("relative_file_paths:\n  - ../../etc/passwd.mcap", "file name"),
    ("relative_file_paths:\n  - /dev/zero", "file name"),
    ("relative_file_paths: 7", "relative_file_paths"),
    ("topics_with_message_count: [1, 2]", "topics_with_message_count"),
    ("topics_with_message_count:\n  - topic_metadata: {name: 5, type: []}", "topic_metadata"),
    (
        "topics_with_message_count:\n  - {topic_metadata: {name: /x, type: t}, message_count: x}",
        "message_count",
    ),  # fmt: skip
]


@pytest.mark.parametrize("edit,words", METADATA_EDITS)
def test_a_metadata_yaml_of_the_wrong_shape_is_one_located_line(
    tmp_path: Path, cfg: Path, capsys: Any, edit: str, words: str
) -> None:
    bag = small_bag(tmp_path / "bag")
    meta = bag / "metadata.yaml"
    info = meta.read_text().split("rosbag2_bagfile_information:\n", 1)[1]
    import yaml

    doc = yaml.safe_load(info)
    key = edit.split(":", 1)[0]
    doc.pop(key, None)
    body = yaml.safe_dump(doc) + edit + "\n"
    meta.write_text(
        "rosbag2_bagfile_information:\n" + "".join("  " + ln + "\n" for ln in body.splitlines())
    )
    rc, err = in_process(capsys, "replay", str(cfg), str(bag), "--quiet")
    line = assert_one_located_line(err, str(meta))
    assert rc == 1 and words in line, line


@pytest.mark.parametrize("name", ["x.mcap", "x.db3"])
def test_a_fifo_named_like_a_bag_is_refused_not_waited_on(
    tmp_path: Path, cfg: Path, name: str
) -> None:
    fifo = tmp_path / name
    os.mkfifo(fifo)
    r = cli("replay", str(cfg), str(fifo), "--quiet", timeout=60)
    assert r["rc"] == 1 and "regular file" in assert_one_located_line(r["err"], str(fifo))


# ----------------------------------------------------------------- sqlite3 rows


def db3(tmp_path: Path) -> Path:
    """A real rosbag2 sqlite3 bag (5 messages on /x), its tables rebuilt without NOT
    NULL and type constraints: sqlite3 lets a hostile file hold anything anywhere."""
    bag = small_bag(tmp_path / "bag", StoragePlugin.SQLITE3)
    (f,) = bag.glob("*.db3")
    con = sqlite3.connect(f)
    for table in ("messages", "topics"):
        cols = ", ".join(r[1] for r in con.execute(f"PRAGMA table_info({table})"))
        con.executescript(
            f"CREATE TABLE loose ({cols}); INSERT INTO loose SELECT * FROM {table};"
            f"DROP TABLE {table}; ALTER TABLE loose RENAME TO {table};"
        )
    con.commit()
    con.close()
    return f


def hostile(tmp_path: Path, *sql: str) -> Path:
    f = db3(tmp_path)
    con = sqlite3.connect(f)
    for q in sql:
        con.execute(q)
    con.commit()
    con.close()
    return f


def row(topic: str, t: str, data: str) -> str:
    return f"INSERT INTO messages (topic_id, timestamp, data) VALUES ({topic}, {t}, {data})"


X7 = "x'0001000007000000" + "00" * 4 + "'"  # std_msgs/Int64 7
DAMAGE = [
    # (the edit, the words of the damage); the 5 good messages are at t_ns 1000..1004
    # and how many are replayed before it (sqlite3 sorts NULL first, text after numbers)
    (row("1", "2000", "NULL"), "its data is NULL", 5),
    (row("1", "'soon'", "x'00'"), "its timestamp is 'soon'", 5),
    (row("1", "NULL", "x'00'"), "its timestamp is None", 0),
    (row("1", "-5", X7), "negative", 0),
    (row("1", "1e30", X7), "its timestamp is 1e+30", 5),
    (row("1", "2000", "'text'"), "its data is str", 5),
    ("DROP TABLE messages", "no such table", 0),
]


@pytest.mark.parametrize("sql,words,before", DAMAGE)
def test_a_hostile_sqlite_row_is_damage_at_its_place(
    tmp_path: Path, cfg: Path, capsys: Any, sql: str, words: str, before: int
) -> None:
    f = hostile(tmp_path, sql)
    out = tmp_path / "out.jsonl"
    rc, err = in_process(capsys, "replay", str(cfg), str(f), "--quiet", "-o", str(out))
    line = assert_one_located_line(err, str(f))
    assert rc == 1 and "damaged" in line and words in line, line
    records = list(iter_records(str(out)))
    assert records[-1].get("what") == "replay_damaged"
    assert f"replayed {before} messages" in LAST_OUT[0], LAST_OUT[0]


ROW_1 = "row 1 of table topics is ("  # the row the check refused, by number
REFUSED = [
    ("UPDATE topics SET name = NULL", ROW_1),
    ("UPDATE topics SET type = 7", ROW_1),
    ("UPDATE topics SET id = 'one'", ROW_1),
    ("DROP TABLE topics", "no such table: topics"),
]


@pytest.mark.parametrize("sql,words", REFUSED)
def test_a_hostile_topics_table_is_one_located_line(
    tmp_path: Path, cfg: Path, capsys: Any, sql: str, words: str
) -> None:
    f = hostile(tmp_path, sql)
    rc, err = in_process(capsys, "replay", str(cfg), str(f), "--quiet")
    line = assert_one_located_line(err, str(f))
    assert rc == 1 and words in line, line
    if words == ROW_1:
        assert line.endswith("): not (whole number, name, type)"), line


@pytest.mark.parametrize(
    "sql",
    [
        row("1.0", "2000", X7),  # sqlite3 compares 1.0 equal to the topic id 1
        "UPDATE message_definitions SET encoded_message_definition = x'ff00'",
    ],
)
def test_oddities_that_still_read(tmp_path: Path, cfg: Path, capsys: Any, sql: str) -> None:
    f = hostile(tmp_path, sql)
    rc, err = in_process(capsys, "replay", str(cfg), str(f), "--quiet")
    assert rc == 0 and not errors(err), err


def test_rows_of_no_topic_are_counted_not_lost_silently(
    tmp_path: Path, cfg: Path, capsys: Any
) -> None:
    f = hostile(tmp_path, row("NULL", "2000", X7), row("99", "2001", X7))
    rc, _ = in_process(capsys, "replay", str(cfg), str(f), "--quiet")
    out = LAST_OUT[0]
    assert rc == 0 and "replayed 5 messages" in out
    assert "2 message rows name no topic" in out, out


# ----------------------------------------------------------------- JSON-lines traces

TRACE_LINES = [
    (b'{"t_ns": 1, "record": ' + b"[" * 100_000 + b"]" * 100_000 + b"}\n", "nested"),
    (b'{"t_ns": 1, "name": "x", "value": 1}\n\xff\xfe\n', "UTF-8"),
    (
        b'{"t_ns": 1, "name": "x", "value": 1}\n{"t_ns": 2, "record": {"a": "'
        + b"y" * (3 << 20)
        + b'"}}\n',
        "larger than",
    ),  # fmt: skip
]


@pytest.mark.parametrize("data,words", TRACE_LINES, ids=["deep", "utf8", "long"])
def test_a_hostile_trace_line_is_damage_at_its_line(
    tmp_path: Path, cfg: Path, capsys: Any, data: bytes, words: str
) -> None:
    trace = tmp_path / "t.jsonl"
    trace.write_bytes(data)
    rc, err = in_process(capsys, "replay", str(cfg), str(trace), "--quiet")
    line = assert_one_located_line(err, str(trace))
    assert rc == 1 and "line " in line and words in line, line


def test_a_deeply_nested_record_in_a_bag_is_located(tmp_path: Path, cfg: Path, capsys: Any) -> None:
    with Writer(tmp_path / "bag", version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/x", "std_msgs/msg/Int64", typestore=TS)
        r = w.add_connection("/safety_supervisor/records", "std_msgs/msg/String", typestore=TS)
        w.write(c, 1000, ser_int64(1))
        w.write(r, 1001, ser_string("[" * 100_000 + "]" * 100_000))
    rc, err = in_process(capsys, "replay", str(cfg), str(tmp_path / "bag"), "--quiet")
    line = assert_one_located_line(err, "bag")
    assert rc == 1 and "t_ns 1001" in line and "nested" in line, line


# ----------------------------------------------------------------- the fuzzers


def valid_mcap(compression: str) -> bytes:
    """A real rosbag2-style MCAP from the mcap writer: several chunks, indexes, summary."""
    import io

    from mcap.writer import CompressionType
    from mcap_ros2.writer import Writer as McapWriter

    buf = io.BytesIO()
    w = McapWriter(buf, chunk_size=300, compression=CompressionType[compression.upper()])
    int64 = w.register_msgdef("std_msgs/msg/Int64", "int64 data")
    # a string before the field read: its length decides where the field is
    status = w.register_msgdef("acme_msgs/msg/Status", "string note\nfloat64 level")
    for i in range(40):
        w.write_message("/x", int64, {"data": i}, log_time=100 * i)
        w.write_message(
            "/status", status, {"note": "n" * (i % 7), "level": i / 4}, log_time=100 * i + 50
        )
    w.finish()
    return buf.getvalue()


VALID = {c: valid_mcap(c) for c in ("zstd", "lz4", "none")}


def _offsets(data: bytes) -> list[int]:
    """Where each top-level record of a valid MCAP file starts."""
    out, pos = [], 8
    while pos + 9 <= len(data) - 8:
        out.append(pos)
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    return out


RECORDS = {c: _offsets(d) for c, d in VALID.items()}
BOMB = {c: zeros_compressed(c, 256 << 20) for c in ("zstd", "lz4")}
HUGE = [2**64 - 1, 2**63, 2**32, 1 << 40, 0]


@st.composite
def mutated_mcap(draw: st.DrawFn) -> bytes:
    kind = draw(st.sampled_from(sorted(VALID)))
    data = bytearray(VALID[kind])
    for _ in range(draw(st.integers(1, 4))):
        how = draw(st.sampled_from(["flip", "truncate", "u64", "u32", "bomb", "op", "length"]))
        if not data:
            break
        at = draw(st.integers(0, len(data) - 1))
        record = draw(st.sampled_from(RECORDS[kind]))
        if how == "op" and record < len(data):
            data[record] = draw(st.integers(0, 255))
        elif how == "length" and record + 9 <= len(data):
            n = draw(st.one_of(st.sampled_from(HUGE), st.integers(0, 64)))
            data[record + 1 : record + 9] = struct.pack("<Q", n)
        elif how == "flip":
            data[at] ^= 1 << draw(st.integers(0, 7))
        elif how == "truncate":
            del data[at:]
        elif how == "u64" and at + 8 <= len(data):
            data[at : at + 8] = struct.pack("<Q", draw(st.sampled_from(HUGE)))
        elif how == "u32" and at + 4 <= len(data):
            data[at : at + 4] = struct.pack(
                "<I", draw(st.sampled_from([2**32 - 1, 2**31, 1 << 20]))
            )
        elif how == "bomb":
            kind = draw(st.sampled_from(["zstd", "lz4"]))
            z = BOMB[kind]
            data[at:at] = _rec(6, struct.pack("<QQQI", 0, 0, 1000, 0) + _str(kind)
                               + struct.pack("<Q", len(z)) + z)  # fmt: skip
    return bytes(data)


def _never_exit_3(cfg: Path, path: Path, measure: bool = True) -> None:
    """What replay does with a recording, in this process without compiling a monitor
    (the readers and their batches): only a one-line UserError, within PEAK bytes
    (measured with tracemalloc, which numpy reports to, unless ``measure`` is off)."""
    from monitors.errors import UserError
    from supervisor.config import load_config
    from supervisor.tools.replay.sources import open_recordings

    if measure:
        tracemalloc.start()
    try:
        try:
            rec = open_recordings([path], load_config(cfg))
            rec.summary()
            for _ in rec.events():
                pass
        except UserError as e:
            assert "\n" not in str(e) and str(path) in str(e), str(e)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert not measure or peak < PEAK, f"peak {peak / 2**20:.0f} MB"


@settings(
    max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(data=mutated_mcap())
def test_fuzz_mutated_mcap_is_never_exit_3(
    tmp_path: Path, cfg: Path, capsys: Any, data: bytes
) -> None:
    path = tmp_path / "f.mcap"
    path.write_bytes(data)
    _never_exit_3(cfg, path)


BASE: list[bytes] = []  # the loosened sqlite3 bag, made once
SQL_VALUES = st.one_of(
    st.none(),
    st.integers(-(2**63), 2**63 - 1),
    st.floats(allow_nan=True),
    st.text(max_size=5),
    st.binary(max_size=12),
)


@settings(
    max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(rows=st.lists(st.tuples(st.one_of(st.sampled_from([1, 2, 99]), SQL_VALUES),
                               SQL_VALUES, SQL_VALUES), max_size=6))  # fmt: skip
def test_fuzz_hostile_sqlite_rows_are_never_exit_3(
    tmp_path: Path, cfg: Path, capsys: Any, rows: list[tuple[Any, Any, Any]]
) -> None:
    f = tmp_path / "h.db3"
    if not BASE:
        BASE.append(db3(tmp_path / "base").read_bytes())
    f.write_bytes(BASE[0])
    con = sqlite3.connect(f)
    con.executemany("INSERT INTO messages (topic_id, timestamp, data) VALUES (?, ?, ?)", rows)
    con.commit()
    con.close()
    _never_exit_3(cfg, f, measure=False)  # rows are small: speed


@pytest.mark.slow
def test_the_real_cli_on_mutated_bags_smoke(tmp_path: Path, cfg: Path) -> None:
    # A few fixed mutations through the installed command, each in a limited child.
    data = VALID["zstd"]
    cases = {
        "cut": data[: len(data) // 2],
        "flip": data[:200] + bytes([data[200] ^ 0xFF]) + data[201:],
        "length": data[:8] + struct.pack("<BQ", data[8], 2**63) + data[17:],
        "crc": zlib.compress(data),  # not an MCAP at all
    }
    for name, content in cases.items():
        path = tmp_path / f"{name}.mcap"
        path.write_bytes(content)
        r = cli("replay", str(cfg), str(path), "--quiet", timeout=120)
        assert r["rc"] in (0, 1), (name, r)
        assert "Traceback" not in r["err"] and len(errors(r["err"])) <= 1, (name, r)
        assert r["peak"] < PEAK, (name, r["peak"])


def test_report_with_a_bomb_bag_reads_up_to_the_damage(
    tmp_path: Path, cfg: Path, capsys: Any
) -> None:
    # report --bag reads the bag with replay's readers: the bomb is a note on the page
    trace = tmp_path / "t.jsonl"
    trace.write_text(
        "".join(f'{{"t_ns": {1000 + i}, "name": "x", "value": {i * 60}}}\n' for i in range(3))
    )
    log = tmp_path / "log.jsonl"
    rc, err = in_process(capsys, "replay", str(cfg), str(trace), "--quiet", "-o", str(log))
    assert rc == 0, err
    bag = bomb_mcap(tmp_path / "bomb.mcap", "zstd", 1 * GIB, 1 * GIB, False)
    page = tmp_path / "r.html"
    args = ["report", str(log), "--bag", str(bag), "--config", str(cfg), "-o", str(page)]
    rc, err = in_process(capsys, *args, "--quiet")
    assert rc == 0, err
    assert "Traceback" not in err and "internal error" not in err
    html = page.read_text()
    assert "bomb.mcap" in html and "more than 67108864" in html


def test_a_huge_topic_id_is_read_without_a_table_of_its_size(
    tmp_path: Path, cfg: Path, capsys: Any
) -> None:
    f = hostile(tmp_path, "UPDATE topics SET id = 4611686018427387904",
                "UPDATE messages SET topic_id = 4611686018427387904")  # fmt: skip
    rc, err = in_process(capsys, "replay", str(cfg), str(f), "--quiet")
    assert rc == 0 and "replayed 5 messages" in LAST_OUT[0], err


def _loose_then(tail: bytes) -> tuple[bytes, int]:
    """Three good messages outside any chunk, then ``tail``; the bytes and where
    ``tail`` starts."""
    good = _head() + b"".join(_message(1, i, 1000 + i, ser_int64(i)) for i in range(3))
    return good + tail, len(good)


@pytest.mark.parametrize(
    "tail,words",
    [
        (_rec(0, b""), "the record at byte {at} has opcode 0, which MCAP never uses"),
        (b"\x05\x00", "the file ends early"),
        (_rec(5, b"\0" * 30)[:20], "the record at byte {at} is cut short: the file ends early"),
    ],
)
def test_a_damaged_mcap_record_after_loose_messages_is_one_line_with_where(
    tmp_path: Path, cfg: Path, capsys: Any, tail: bytes, words: str
) -> None:
    data, at = _loose_then(tail)
    bag = tmp_path / "loose.mcap"
    bag.write_bytes(data)
    rc, err = in_process(capsys, "replay", str(cfg), str(bag), "--quiet")
    line = assert_one_located_line(err, str(bag))
    where = f"(after byte {at}, 3 messages read, the last at t_ns 1002)"
    assert rc == 1 and line.endswith(f"damaged: {words.format(at=at)} {where}"), line
    assert "replayed 3 messages" in LAST_OUT[0], LAST_OUT[0]
