"""Replay of the storage and compression rosbag2 itself writes (tests/data/bags/):
zstd per file and per message, split bags, bags without metadata.yaml, metadata
versions 1-9, a declared serialisation other than CDR. Every value is checked against
an independent reader: the sqlite3 module, zstandard and rosbags' CDR deserialiser."""

from __future__ import annotations

import os
import re
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
import zstandard
from rosbags.typesys import Stores, get_typestore

from monitors.errors import UserError
from supervisor.config import load_config
from supervisor.tools.replay.sources import open_recordings

BAGS = Path(__file__).resolve().parents[3] / "data" / "bags"
TS = get_typestore(Stores.ROS2_JAZZY)
LOG = "rcl_interfaces/msg/Log"

CONFIG = """\
component: Robot
step: {policy: periodic, period_ms: 100}
variables:
  lvl: {type: int64, topic: /rosout, msg: rcl_interfaces/msg/Log, field: level}
  sec: {type: int64, topic: /rosout, msg: rcl_interfaces/msg/Log, field: stamp.sec}
requirements:
  - {id: R1, text: Robot shall always satisfy lvl < 100}
"""

CDR_CONFIG = """\
component: Robot
step: {policy: periodic, period_ms: 100}
variables:
  i: {type: int64, topic: /test_topic, msg: test_msgs/msg/BasicTypes, field: int32_value}
requirements:
  - {id: R1, text: Robot shall always satisfy i < 100}
"""


def config(tmp_path: Path, text: str = CONFIG):
    p = tmp_path / "c.yaml"
    p.write_text(text)
    return load_config(p)


def replay(paths: list[Path], cfg) -> list[tuple[int, str, list[tuple[str, object]]]]:
    rec = open_recordings(paths, cfg)
    return [ev for ev in rec.events() if ev[1] != "record"]


def db3_of(f: Path, tmp_path: Path) -> Path:
    """The sqlite3 file itself: a ``.db3.zstd`` decompressed by zstandard."""
    if f.suffix != ".zstd":
        return f
    out = tmp_path / f"indep-{f.stem}"
    with f.open("rb") as src, out.open("wb") as dst:
        zstandard.ZstdDecompressor().copy_stream(src, dst)
    return out


def expected_rosout(files: list[Path], tmp_path: Path) -> list[tuple[int, str, list]]:
    """/rosout's (t_ns, level, stamp.sec), read with the sqlite3 module, payloads
    zstd-decompressed where they carry zstd's magic, decoded by rosbags."""
    rows: list[tuple[int, bytes]] = []
    for f in files:
        con = sqlite3.connect(f"file:{db3_of(f, tmp_path)}?immutable=1", uri=True)
        rows += con.execute(
            "SELECT m.timestamp, m.data FROM messages m JOIN topics t ON t.id = m.topic_id "
            "WHERE t.name = '/rosout'"
        ).fetchall()
        con.close()
    out = []
    for t, data in sorted(rows, key=lambda r: r[0]):
        if data[:4] == b"\x28\xb5\x2f\xfd":
            data = zstandard.ZstdDecompressor().decompressobj().decompress(data)
        msg = TS.deserialize_cdr(data, LOG)
        out.append((t, "/rosout", [("lvl", msg.level), ("sec", msg.stamp.sec)]))
    return out


def natural(files: list[Path]) -> list[Path]:
    return sorted(
        files, key=lambda f: [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", f.name)]
    )


def test_a_split_bag_compressed_per_file_without_metadata_replays_every_file(tmp_path):
    d = BAGS / "sqlite3" / "file_compression_no_metadata"
    files = natural(list(d.glob("*.db3.zstd")))
    expected = expected_rosout(files, tmp_path)
    assert len(expected) == 129 + 121 + 120 + 22
    cfg = config(tmp_path)
    assert replay([d], cfg) == expected
    assert replay(files, cfg) == expected
    assert replay([files[1]], cfg) == expected_rosout([files[1]], tmp_path)


def test_a_bag_compressed_per_file_with_its_metadata_opens(tmp_path):
    # rosbag2's compressed_bag: metadata v4 says zstd per FILE; its one file is empty
    d = BAGS / "sqlite3" / "compressed_bag"
    assert replay([d], config(tmp_path)) == []


def test_a_bag_compressed_per_message_replays_as_a_dir_a_file_and_a_list(tmp_path):
    d = BAGS / "sqlite3" / "message_compression_no_metadata"
    files = natural(list(d.glob("*.db3")))
    expected = expected_rosout(files, tmp_path)
    assert len(expected) == 758
    cfg = config(tmp_path)
    assert replay([d], cfg) == expected
    assert replay(files, cfg) == expected
    # a .db3 given alone: its payloads are recognised by zstd's magic
    assert replay([files[2]], cfg) == expected_rosout([files[2]], tmp_path)


def message_bag(tmp_path: Path, version: int = 4) -> tuple[Path, list[Path]]:
    """A copy of message_compression_no_metadata with rosbag2's own reindexed
    metadata.yaml (version 4, compression_mode MESSAGE), its file paths made the
    files' names as rosbag2 records them, its version edited to ``version``."""
    src = BAGS / "sqlite3" / "message_compression_no_metadata"
    bag = tmp_path / "bag"
    bag.mkdir()
    files = [bag / f.name for f in natural(list(src.glob("*.db3")))]
    for f in files:
        shutil.copy(src / f.name, f)
    meta = (src / "reindexed-metadata.yaml.txt").read_text()
    assert "compression_mode: MESSAGE" in meta and "  version: 4\n" in meta
    meta = meta.replace("message_compression/", "")
    (bag / "metadata.yaml").write_text(meta.replace("  version: 4\n", f"  version: {version}\n"))
    return bag, files


def test_a_bag_whose_metadata_says_message_compression_replays(tmp_path):
    bag, files = message_bag(tmp_path)
    assert replay([bag], config(tmp_path)) == expected_rosout(files, tmp_path)


@pytest.mark.parametrize("version", range(1, 10))
def test_metadata_versions_1_to_9_replay_alike(tmp_path, version):
    # the corpus has versions 4 to 8; the others are rosbag2's v4 file, version edited
    bag, files = message_bag(tmp_path, version)
    expected = expected_rosout(files, tmp_path)
    assert len(expected) == 758
    assert replay([bag], config(tmp_path)) == expected


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_serialization_other_than_cdr_is_refused_in_one_line(tmp_path, storage):
    d = BAGS / storage / "wrong_rmw_test"
    with pytest.raises(UserError) as err:
        replay([d], config(tmp_path, CDR_CONFIG))
    text = str(err.value)
    assert "\n" not in text and "wrong_format" in text and "cdr" in text
    assert str(d) in text


def test_a_cut_file_compressed_bag_is_damage_not_a_traceback(tmp_path):
    f = BAGS / "sqlite3" / "file_compression_no_metadata" / "file_compression_0.db3.zstd"
    cut = tmp_path / f.name
    cut.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    with pytest.raises(UserError) as err:
        replay([cut], config(tmp_path))
    text = str(err.value)
    assert "\n" not in text and str(cut) in text
    assert f"damaged: zstd data cut short at byte {cut.stat().st_size}" in text


def test_replay_leaves_a_wal_mode_bag_as_it_was_even_read_only(tmp_path):
    # rosbag2 writes its sqlite3 files in WAL mode; opening one read-only the usual
    # way creates -shm and -wal files beside it, and fails in a read-only directory
    src = BAGS / "sqlite3" / "message_compression_no_metadata"
    bag = tmp_path / "bag"
    shutil.copytree(src, bag)
    files = natural(list(bag.glob("*.db3")))
    expected = expected_rosout(files, tmp_path)
    before = sorted(p.name for p in bag.iterdir())
    assert replay([bag], config(tmp_path)) == expected
    assert sorted(p.name for p in bag.iterdir()) == before
    bag.chmod(0o555)
    try:
        if not os.access(bag, os.W_OK):  # root writes anyway: nothing more to see
            assert replay([bag], config(tmp_path)) == expected
            assert sorted(p.name for p in bag.iterdir()) == before
    finally:
        bag.chmod(0o755)


def replay_until_error(paths: list[Path], cfg) -> tuple[list, UserError]:
    rec = open_recordings(paths, cfg)
    got = []
    with pytest.raises(UserError) as err:
        for ev in rec.events():
            if ev[1] != "record":
                got.append(ev)
    return got, err.value


@pytest.mark.parametrize("cut", [4096 * 3, 4096 * 7 + 1000, 4096 * 12 + 2048, 4096 * 19 + 10])
def test_a_db3_cut_anywhere_is_read_up_to_the_damage_then_says_the_byte(tmp_path, cut):
    bag, files = message_bag(tmp_path)
    expected = expected_rosout(files, tmp_path)
    f = files[1]
    f.write_bytes(f.read_bytes()[:cut])
    got, err = replay_until_error([bag], config(tmp_path))
    assert len(got) < len(expected)
    assert got == expected[: len(got)]
    text = str(err)
    assert "\n" not in text and str(f) in text
    assert f"damaged: the file is cut short at byte {cut}" in text
    # then why sqlite stopped, if it did, and where: the messages read and the last time
    assert re.search(
        rf"cut short at byte {cut}( \(.+\))?; \d+ messages read(, the last at t_ns \d+)?$", text
    ), text


@pytest.mark.parametrize("quarter", [1, 2, 3])
def test_an_mcap_cut_inside_its_only_chunk_is_damage_at_a_byte(tmp_path, quarter):
    # rosbag2's cdr_test: its schemas, channels and messages are in one chunk
    src = BAGS / "mcap" / "cdr_test"
    bag = tmp_path / "bag"
    shutil.copytree(src, bag)
    f = bag / "cdr_test_0.mcap"
    data = f.read_bytes()
    at = data.index(b"\x06", 8)  # the chunk record, right after the header
    length = int.from_bytes(data[at + 1 : at + 9], "little")
    assert data.count(b"\x06") >= 1 and at + 9 + length < len(data)
    f.write_bytes(data[: at + 9 + length * quarter // 4])
    with pytest.raises(UserError) as err:
        list(open_recordings([bag], config(tmp_path, CDR_CONFIG)).events())
    text = str(err.value)
    assert "\n" not in text and str(f) in text and "not defined" not in text
    assert "damaged" in text and f"the record at byte {at} is cut short" in text


def test_an_mcap_cut_after_its_data_is_still_damage(tmp_path):
    # every message is read, but the file is not whole: said, not passed over
    src = BAGS / "mcap" / "cdr_test"
    bag = tmp_path / "bag"
    shutil.copytree(src, bag)
    f = bag / "cdr_test_0.mcap"
    data = f.read_bytes()
    f.write_bytes(data[: len(data) - 40])
    _, err = replay_until_error([bag], config(tmp_path, CDR_CONFIG))
    text = str(err)
    assert "\n" not in text and "damaged" in text and f"cut short at byte {len(data) - 40}" in text


INT_CONFIG = """\
component: Robot
step: {policy: periodic, period_ms: 100}
variables:
  x: {type: int64, topic: /x, msg: std_msgs/msg/Int64}
requirements:
  - {id: R1, text: Robot shall always satisfy x < 1000000}
"""


def test_an_mcap_compressed_per_file_replays_as_the_plain_one(tmp_path):
    # no such bag in rosbag2's resources: one written by rosbags, then compressed by
    # zstandard as rosbag2's zstd file compressor does (one .mcap.zstd per file)
    from rosbags.rosbag2 import StoragePlugin, Writer

    bag = tmp_path / "bag"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/x", "std_msgs/msg/Int64", typestore=TS)
        for i in range(500):
            w.write(
                c,
                1000 + i,
                bytes(
                    TS.serialize_cdr(TS.types["std_msgs/msg/Int64"](data=i), "std_msgs/msg/Int64")
                ),
            )
    cfg = config(tmp_path, INT_CONFIG)
    expected = replay([bag], cfg)
    assert [e[2] for e in expected] == [[("x", i)] for i in range(500)]
    (plain,) = bag.glob("*.mcap")
    packed = plain.with_name(plain.name + ".zstd")
    with plain.open("rb") as src, packed.open("wb") as dst:
        zstandard.ZstdCompressor().copy_stream(src, dst)
    plain.unlink()
    meta = bag / "metadata.yaml"
    text = meta.read_text().replace(plain.name, packed.name)
    text = text.replace("compression_format: ''", "compression_format: zstd")
    meta.write_text(text.replace("compression_mode: ''", "compression_mode: FILE"))
    assert "compression_mode: FILE" in meta.read_text()
    assert replay([bag], cfg) == expected
    assert replay([packed], cfg) == expected


INT64_CONFIG = """\
component: Robot
step: {policy: periodic, period_ms: 100}
variables:
  x: {type: int64, topic: /x, msg: std_msgs/msg/Int64, field: data}
requirements:
  - {id: R1, text: Robot shall always satisfy x < 1000}
"""


def test_an_unchunked_mcap_replays_by_log_time_as_the_mcap_reader_says(tmp_path):
    # Messages outside any chunk (an MCAP writer without chunking), written out of
    # log-time order and with publish times that differ: replay orders them by log
    # time, as the reference reader in log-time order does.
    from mcap.reader import make_reader
    from mcap.writer import Writer

    bag = tmp_path / "loose.mcap"
    log_times = [5_000, 1_000, 3_000, 3_000, 9_000, 2_000, 7_000]
    with bag.open("wb") as f:
        w = Writer(f, use_chunking=False)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("std_msgs/msg/Int64", "ros2msg", b"int64 data")
        cid = w.register_channel("/x", "cdr", sid)
        for k, t in enumerate(log_times):
            data = TS.serialize_cdr(TS.types["std_msgs/msg/Int64"](data=k), "std_msgs/msg/Int64")
            w.add_message(cid, log_time=t, data=data, publish_time=10**9 - t, sequence=k)
        w.finish()
    with bag.open("rb") as f:
        expected = [
            (m.log_time, TS.deserialize_cdr(m.data, "std_msgs/msg/Int64").data)
            for _, _, m in make_reader(f).iter_messages(log_time_order=True)
        ]
    got = [(t, dict(values)["x"]) for t, _, values in replay([bag], config(tmp_path, INT64_CONFIG))]
    assert got == expected


@pytest.mark.parametrize("kind", ["the monitor's build", "zstd per file", "a cut db3"])
def test_a_full_temporary_directory_is_one_line_naming_it(tmp_path, kind):
    # The monitor is built, a compressed file inflated and a damaged sqlite3 file copied
    # in TMPDIR: on a full disk each ended replay in an internal error (exit 3), and a
    # fleet replay's bag as "failed: internal error". A tmpfs of one page, in a mount
    # namespace of the command's own (unshare), gone with it.
    if kind == "a cut db3":
        src = natural(list((BAGS / "sqlite3" / "message_compression_no_metadata").glob("*.db3")))
        bag = tmp_path / "cut.db3"
        bag.write_bytes(src[0].read_bytes()[: src[0].stat().st_size * 2 // 3])
    else:
        bag = BAGS / "sqlite3" / "file_compression_no_metadata" / "file_compression_0.db3.zstd"
    config = tmp_path / "c.yaml"
    config.write_text(
        CONFIG + "  - {id: R2, text: Robot shall always satisfy sec >= 0}\n"
    )  # every variable used, as the command's checks ask
    replay = [sys.executable, "-m", "supervisor", "replay", str(config), str(bag), "--quiet"]
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}
    if kind != "the monitor's build":  # built and cached first: the bag's own file then
        warm = subprocess.run(replay, capture_output=True, text=True, env=env, timeout=300)
        assert warm.returncode in (0, 1) and "internal error" not in warm.stderr, warm.stderr
    full = tmp_path / "full"
    full.mkdir()
    script = f"mount -t tmpfs -o size=4k tmpfs {full} && exec " + " ".join(replay)
    r = subprocess.run(
        ["unshare", "--mount", "sh", "-c", script], capture_output=True, text=True,
        env={**env, "TMPDIR": str(full)}, timeout=300,
    )  # fmt: skip
    assert r.returncode == 1, (r.returncode, r.stderr)
    said = r.stderr.strip().splitlines()
    assert len(said) == 1 and said[0].startswith(str(full)), r.stderr
    assert "No space left on device" in said[0] and "TMPDIR" in said[0], r.stderr
    if kind == "the monitor's build":
        assert "cannot build the monitor here" in said[0], r.stderr
    else:
        assert said[0].startswith(f"{full}: cannot "), r.stderr


def test_records_that_cannot_be_written_fail_the_replay_in_one_line(tmp_path):
    # -o on a full disk: the records were lost, stderr had a line per record ("only in
    # the journal", which replay has not) and the replay exited 0.
    bag = BAGS / "sqlite3" / "file_compression_no_metadata" / "file_compression_0.db3.zstd"
    config = tmp_path / "c.yaml"
    config.write_text(CONFIG + "  - {id: R2, text: Robot shall always satisfy sec >= 0}\n")
    full = tmp_path / "full"
    full.mkdir()
    out = full / "out.jsonl"
    script = (
        f"mount -t tmpfs -o size=4k tmpfs {full} && "
        f"dd if=/dev/zero of={full}/fill bs=4k count=1 2>/dev/null; exec {sys.executable} "
        f"-m supervisor replay {config} {bag} -o {out} --quiet"
    )
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}
    r = subprocess.run(
        ["unshare", "--mount", "sh", "-c", script], capture_output=True, text=True, env=env,
        timeout=300,
    )  # fmt: skip
    assert r.returncode == 1, (r.returncode, r.stderr)
    said = r.stderr.strip().splitlines()
    assert len(said) == 1 and said[0].startswith(f"{out}: "), r.stderr
    assert "No space left on device" in said[0] and "journal" not in said[0], r.stderr
