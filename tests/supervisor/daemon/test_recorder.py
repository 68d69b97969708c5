"""The recorder (run --record): real rosbag2 MCAP bags on disk, read back with rosbags
and with the mcap reader; rotation, a write error, a kill -9; the record: section
(docs/reference/config.md, record)."""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest
import yaml
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from monitors.errors import UserError
from supervisor.config import load_config
from supervisor.daemon.recorder import RECORDS_TOPIC, Recorder, bag_dirs

ROOT = Path(__file__).resolve().parents[3]
TS = get_typestore(Stores.ROS2_JAZZY)
INT64 = "std_msgs/msg/Int64"


def cdr_int64(v: int) -> bytes:
    return bytes(TS.serialize_cdr(TS.types[INT64](data=v), INT64))


def rosbags_messages(bag: Path) -> list[tuple[str, str, int, object]]:
    """(topic, type, timestamp, decoded message) of a complete bag, in time order."""
    with AnyReader([bag], default_typestore=TS) as r:
        return [
            (c.topic, c.msgtype, t, r.deserialize(raw, c.msgtype)) for c, t, raw in r.messages()
        ]


def mcap_file(bag: Path) -> Path:
    (f,) = bag.glob("*.mcap")
    return f


def mcap_messages(path: Path) -> list[tuple[str, str, int, object]]:
    """(topic, schema name, log time, decoded message) with the mcap library's reader."""
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [
            (ch.topic, schema.name, m.log_time, dec)
            for schema, ch, m, dec in reader.iter_decoded_messages(log_time_order=False)
        ]


def cut_short_messages(path: Path) -> list[tuple[str, int, bytes]]:
    """What a linear reader gets from an MCAP file without summary or footer (a
    killed writer): every message up to where the file ends."""
    out = []
    with path.open("rb") as f:
        try:
            for _schema, ch, m in NonSeekingReader(f).iter_messages(log_time_order=False):
                out.append((ch.topic, m.log_time, m.data))
        # EndOfFile or a record cut in the middle: the end (the mcap library raises
        # struct.error for a record cut inside its fixed-size fields)
        except (McapError, struct.error):
            pass
    return out


@pytest.mark.parametrize("n", [10_000, pytest.param(100_000, marks=pytest.mark.slow)])
def test_every_message_and_record_from_several_threads(tmp_path, n):
    inputs = [(f"/in{k}", INT64) for k in range(4)] + [("/text", "std_msgs/msg/String")]
    # room for everything at once: the check is that nothing is lost, whatever the timing
    rec = Recorder(tmp_path / "bags", inputs, queue_messages=2 * n, max_bag_s=1e6)
    base = 1_000_000_000_000
    sent: dict[str, dict[int, int]] = {f"/in{k}": {} for k in range(4)}

    def producer(k: int) -> None:
        for i in range(k, n, 4):
            t = base + i * 50_000 + k  # 20k msg/s, distinct per thread
            rec.message(k, t, cdr_int64(i))
            sent[f"/in{k}"][t] = i

    threads = [threading.Thread(target=producer, args=(k,)) for k in range(4)]
    for th in threads:
        th.start()
    lines = [json.dumps({"event": "violation", "requirement": "r1", "seq": s}) for s in range(20)]
    for s, line in enumerate(lines):
        rec.record(base + s * 1_000_000 + 7, line + "\n")
    rec.message(
        4,
        base + 3,
        bytes(TS.serialize_cdr(TS.types["std_msgs/msg/String"](data="hi"), "std_msgs/msg/String")),
    )
    for th in threads:
        th.join()
    stats = rec.close()
    assert (stats.written, stats.dropped, stats.lost, stats.stopped) == (n + 21, 0, 0, None)
    assert stats.bags == 1
    ((_, bag),) = bag_dirs(tmp_path / "bags")
    off = rec.wall_offset_ns

    with Reader(bag) as r:
        assert r.message_count == n + 21
        assert {c.topic: c.msgtype for c in r.connections} == {
            **dict(inputs),
            RECORDS_TOPIC: "std_msgs/msg/String",
        }
    got = rosbags_messages(bag)
    by_tool = {"rosbags": got, "mcap": mcap_messages(mcap_file(bag))}
    for tool, msgs in by_tool.items():
        assert len(msgs) == n + 21, tool
        records = [(t, m.data) for topic, _, t, m in msgs if topic == RECORDS_TOPIC]
        assert records == [(base + s * 1_000_000 + 7 + off, line) for s, line in enumerate(lines)]
        for topic, msgtype, t, m in msgs:
            if topic.startswith("/in"):
                assert msgtype == INT64
                # one fixed offset: every time difference is the receive times' own
                assert sent[topic][t - off] == m.data, tool
            elif topic == "/text":
                assert (t - off, m.data) == (base + 3, "hi")
    assert [t for _, _, t, _ in got] == sorted(t for _, _, t, _ in got)


def test_rotation_by_size_keeps_the_newest_complete_bags(tmp_path):
    rec = Recorder(tmp_path, [("/x", INT64)], max_bag_bytes=20_000, keep=3, max_bag_s=1e6)
    for i in range(5000):
        rec.message(0, 10_000 + i * 1000, cdr_int64(i))
    stats = rec.close()
    assert stats.bags > 5 and stats.written == 5000
    bags = bag_dirs(tmp_path)
    assert [n for n, _ in bags] == list(range(stats.bags - 2, stats.bags + 1))
    values = []
    for _, bag in bags:
        assert (bag / "metadata.yaml").is_file()
        assert mcap_file(bag).stat().st_size < 40_000  # 20 kB and the index
        values += [m.data for _, _, _, m in rosbags_messages(bag)]
    assert values == list(range(5000 - len(values), 5000))  # the newest, none missing


def test_rotation_by_time_names_bags_by_start_time(tmp_path):
    rec = Recorder(tmp_path, [("/x", INT64)], max_bag_s=1.0, keep=100)
    t0 = 5_000_000_000
    for i in range(551):  # 5.5 s at 100 Hz
        rec.message(0, t0 + i * 10_000_000, cdr_int64(i))
        if i == 250:
            rec.record(t0 + i * 10_000_000 + 1, '{"event":"supervisor"}')
    stats = rec.close()
    bags = bag_dirs(tmp_path)
    assert stats.bags == len(bags) == 6
    seen = 0
    for k, (_, bag) in enumerate(bags):
        msgs = rosbags_messages(bag)
        times = [t for _, _, t, _ in msgs]
        assert max(times) - min(times) < 1_000_000_000
        assert min(times) == t0 + k * 1_000_000_000 + rec.wall_offset_ns
        start = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(min(times) // 1_000_000_000))
        assert bag.name.startswith(start)
        seen += len(msgs)
    assert seen == 552

    # A restart goes on numbering in the same directory, and keep counts the old bags.
    again = Recorder(tmp_path, [("/x", INT64)], keep=4)
    again.message(0, time.monotonic_ns(), cdr_int64(1))
    again.close()
    assert [n for n, _ in bag_dirs(tmp_path)] == [4, 5, 6, 7]


def test_a_type_without_description_is_left_out_once(tmp_path):
    warnings: list[str] = []
    odd = ("/odd", "nope_msgs/msg/Nothing")
    rec = Recorder(tmp_path, [("/x", INT64), odd, odd], on_warning=warnings.append)
    for i in range(10):
        rec.message(0, 1000 + i, cdr_int64(i))
        rec.message(1, 1000 + i, b"\x00\x01\x00\x00rawdata")
    stats = rec.close()
    assert (stats.written, stats.skipped, stats.stopped) == (10, 10, None)
    assert len(warnings) == 1 and "/odd" in warnings[0] and "nope_msgs/msg/Nothing" in warnings[0]
    ((_, bag),) = bag_dirs(tmp_path)
    assert [m.data for _, _, _, m in rosbags_messages(bag)] == list(range(10))


def test_inputs_sharing_a_topic_share_its_connection(tmp_path):
    # two variables read from one topic (speed and yaw from /odom)
    rec = Recorder(tmp_path, [("/odom", INT64), ("/odom", INT64), ("/y", INT64)])
    rec.message(0, 1, cdr_int64(1))
    rec.message(1, 2, cdr_int64(2))
    rec.message(2, 3, cdr_int64(3))
    assert rec.close().written == 3
    ((_, bag),) = bag_dirs(tmp_path)
    assert [(topic, m.data) for topic, _, _, m in rosbags_messages(bag)] == [
        ("/odom", 1),
        ("/odom", 2),
        ("/y", 3),
    ]


def test_an_installed_type_outside_rosbags_store_is_described_from_its_msg_files(tmp_path):
    share = tmp_path / "prefix" / "share" / "robot_msgs" / "msg"
    share.mkdir(parents=True)
    (share / "Reading.msg").write_text("std_msgs/Header header\nrobot_msgs/Range[] ranges\n")
    (share / "Range.msg").write_text("float64 min\nfloat64 max\nstring label\n")
    rec = Recorder(
        tmp_path / "bags",
        [("/reading", "robot_msgs/msg/Reading")],
        msg_prefixes=[tmp_path / "prefix"],
    )
    ts = get_typestore(Stores.ROS2_JAZZY)
    for name in ("Range", "Reading"):
        ts.register(
            get_types_from_msg((share / f"{name}.msg").read_text(), f"robot_msgs/msg/{name}")
        )
    Reading, Range = ts.types["robot_msgs/msg/Reading"], ts.types["robot_msgs/msg/Range"]
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    msg = Reading(
        header=Header(stamp=Time(sec=1, nanosec=2), frame_id="base"),
        ranges=[Range(min=0.5, max=2.0, label="front")],
    )
    rec.message(0, 1, bytes(ts.serialize_cdr(msg, "robot_msgs/msg/Reading")))
    assert rec.close().written == 1
    ((_, bag),) = bag_dirs(tmp_path / "bags")
    ((_, msgtype, _, got),) = rosbags_messages(bag)  # AnyReader: the bag's own msgdef
    assert msgtype == "robot_msgs/msg/Reading"
    assert (got.header.frame_id, got.ranges[0].label, got.ranges[0].max) == ("base", "front", 2.0)
    ((_, _, _, dec),) = mcap_messages(mcap_file(bag))
    assert dec.ranges[0].label == "front"


def test_a_full_queue_drops_and_counts_and_close_stops_taking(tmp_path):
    warnings: list[str] = []
    rec = Recorder(
        tmp_path, [("/x", INT64)], queue_messages=100, poll_s=3600, on_warning=warnings.append
    )
    for i in range(1000):
        rec.message(0, i, cdr_int64(i))
    rec.record(2000, '{"event":"violation"}')  # records have a reserve beyond the bound
    stats = rec.close()
    assert (stats.written, stats.dropped) == (101, 900)
    assert any("900 messages dropped" in w for w in warnings)
    rec.message(0, 5000, cdr_int64(1))
    assert rec.stats().lost == 1
    meta = yaml.safe_load((bag_dirs(tmp_path)[0][1] / "metadata.yaml").read_text())
    custom = meta["rosbag2_bagfile_information"]["custom_data"]
    assert custom == {"safety_supervisor.dropped_messages": "900"}


def _child(script: str) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(script)],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_a_write_error_stops_the_recording_once_and_never_the_caller(tmp_path):
    # RLIMIT_FSIZE makes the kernel fail the write with EFBIG, as a full disk fails
    # it with ENOSPC: a real failed write() at a point the recorder does not choose.
    child = _child(
        f"""
        import json, resource, time
        from supervisor.daemon.recorder import Recorder
        resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))
        stops = []
        rec = Recorder({str(tmp_path)!r}, [("/x", "std_msgs/msg/Int64")], on_stopped=stops.append,
                       flush_s=0.05)
        data = b"\\x00\\x01\\x00\\x00" + bytes(1000)
        i = 0
        deadline = time.monotonic() + 20
        # Once the writer process is up (its first flush): a first batch of what
        # queued while it started would pass the limit before any chunk is flushed.
        while rec.stats().written == 0 and time.monotonic() < deadline:
            rec.message(0, time.monotonic_ns(), data)
            time.sleep(0.01)
        while not stops and time.monotonic() < deadline:
            rec.message(0, time.monotonic_ns(), data)
            i += 1
            time.sleep(0.001)
        after = []
        for _ in range(20000):
            t0 = time.perf_counter_ns()
            rec.message(0, time.monotonic_ns(), data)
            after.append(time.perf_counter_ns() - t0)
        rec.record(time.monotonic_ns(), "{{}}")
        time.sleep(0.2)
        stats = rec.close()
        after.sort()
        print(json.dumps({{"stops": stops, "median_ns": after[len(after) // 2],
                          "stats": stats.__dict__}}))
        """
    )
    out, err = child.communicate(timeout=60)
    assert child.returncode == 0, err
    result = json.loads(out)
    (reason,) = result["stops"]
    assert reason.startswith("recording stopped: File too large")
    assert result["stats"]["stopped"] == reason and result["stats"]["lost"] >= 20001
    assert result["median_ns"] < 20_000  # no waiting, no exception: returns at once
    ((_, bag),) = bag_dirs(tmp_path)
    msgs = cut_short_messages(mcap_file(bag))
    assert 0 < len(msgs) <= result["stats"]["written"]
    assert [t for _, t, _ in msgs] == sorted(t for _, t, _ in msgs)


def _gone(pid: int, timeout: float) -> bool:
    """Whether ``pid`` (not our child) ended within ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.02)
    return False


@pytest.mark.slow
def test_kill_9_of_the_daemon_leaves_a_closed_bag(tmp_path):
    # The writer process sees EOF when the daemon dies and closes the bag itself.
    child = _child(
        f"""
        import sys, time
        from supervisor.daemon.recorder import Recorder
        rec = Recorder({str(tmp_path)!r}, [("/x", "std_msgs/msg/Int64")], flush_s=0.1)
        print(rec.writer_pid, flush=True)
        i = 0
        for burst in range(1000):
            for _ in range(500):
                rec.message(0, i, b"\\x00\\x01\\x00\\x00" + i.to_bytes(8, "little"))
                i += 1
            if burst == 5:
                while rec.stats().written < i:
                    time.sleep(0.01)
                print(i, flush=True)
            time.sleep(0.01)
        """
    )
    assert child.stdout is not None
    writer = int(child.stdout.readline())
    sent = int(child.stdout.readline())
    time.sleep(0.3)
    child.send_signal(signal.SIGKILL)
    child.wait(10)
    assert _gone(writer, 20)
    ((_, bag),) = bag_dirs(tmp_path)
    assert (bag / "metadata.yaml").exists()
    with Reader(bag) as r:
        assert r.message_count >= sent == 3000
    values = [m.data for _, _, _, m in rosbags_messages(bag)]
    assert values == list(range(len(values)))  # what was sent, in order, none corrupted
    assert [d for _, _, d in cut_short_messages(mcap_file(bag))] == [
        b"\x00\x01\x00\x00" + v.to_bytes(8, "little") for v in values
    ]


def test_kill_9_of_the_writer_leaves_a_file_readable_up_to_its_last_flushed_chunk(tmp_path):
    stops: list[str] = []
    rec = Recorder(tmp_path, [("/x", INT64)], flush_s=0.1, on_stopped=stops.append)
    for i in range(3000):
        rec.message(0, i, cdr_int64(i))
    deadline = time.monotonic() + 20
    while rec.stats().written < 3000 and time.monotonic() < deadline:
        time.sleep(0.01)
    ((_, bag),) = bag_dirs(tmp_path)

    def on_disk() -> int:
        """Messages in the file as a reader sees it (none before the file is made)."""
        return sum(len(cut_short_messages(f)) for f in bag.glob("*.mcap"))

    # the writer's flush (every flush_s): all of it is in the file
    while on_disk() < 3000 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert on_disk() == 3000, "the writer's flush did not come"
    os.kill(rec.writer_pid, signal.SIGKILL)
    while not stops and time.monotonic() < deadline:
        time.sleep(0.01)
    (reason,) = stops
    assert "killed by signal 9" in reason and "last flushed chunk" in reason
    for i in range(10_000):  # counted, never queued, never raising
        rec.message(0, 5000 + i, cdr_int64(i))
    stats = rec.close()
    assert stats.lost >= 10_000 and stats.stopped == reason and stops == [reason]
    ((_, bag),) = bag_dirs(tmp_path)
    assert not (bag / "metadata.yaml").exists()
    msgs = cut_short_messages(mcap_file(bag))
    assert len(msgs) == 3000
    assert [(t, d) for _, t, d in msgs] == [
        (i + rec.wall_offset_ns, cdr_int64(i)) for i in range(3000)
    ]


@pytest.mark.slow
def test_a_stalled_writer_never_stalls_the_caller(tmp_path):
    # The writer stopped (SIGSTOP): the pipe fills, then the queue; message() keeps
    # returning and counts what does not fit, and after SIGCONT the rest is written.
    warnings: list[str] = []
    rec = Recorder(tmp_path, [("/x", INT64)], queue_messages=1000, on_warning=warnings.append)
    rec.message(0, 0, cdr_int64(0))
    deadline = time.monotonic() + 20
    while rec.stats().written == 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    os.kill(rec.writer_pid, signal.SIGSTOP)
    try:
        n = 200_000
        t0 = time.monotonic()
        for i in range(1, n + 1):
            rec.message(0, i, cdr_int64(i) + bytes(100))
        took = time.monotonic() - t0
        time.sleep(0.2)  # the sender's last batch, into the full pipe
        assert rec.stats().dropped > 0
    finally:
        os.kill(rec.writer_pid, signal.SIGCONT)
    assert took < 10  # sanity only: no call waited for the writer
    stats = rec.close()
    assert stats.stopped is None and stats.lost == 0
    assert stats.written + stats.dropped == n + 1
    assert any("messages dropped" in w for w in warnings)
    ((_, bag),) = bag_dirs(tmp_path)
    values = [int.from_bytes(d[4:12], "little") for _, _, d in cut_short_messages(mcap_file(bag))]
    assert len(values) == stats.written and values == sorted(values)


# -- the record: section ----------------------------------------------------------------

BASE = """\
component: sw
step: {policy: periodic, period_ms: 100}
variables:
  p: {type: bool, topic: /p, msg: std_msgs/msg/Bool}
requirements:
  - id: r1
    text: sw shall always satisfy p
    on_violation: [halt]
mitigations:
  halt: {publish: {topic: /halt, msg: std_msgs/msg/Bool, value: {data: true}}}
"""


def _load(tmp_path, record: str):
    p = tmp_path / "c.yaml"
    p.write_text(BASE + record)
    return load_config(p)


def test_record_section_defaults(tmp_path):
    assert _load(tmp_path, "").record is None
    cfg = _load(tmp_path, "record:\n  path: /var/lib/safety-supervisor/bags\n")
    r = cfg.record
    assert r is not None and r.path == "/var/lib/safety-supervisor/bags"
    assert (r.max_bag_mb, r.max_bag_s, r.keep, r.queue_messages) == (100.0, 300.0, 20, 100_000)
    assert r.line == len(BASE.splitlines()) + 1
    r = _load(
        tmp_path, "record: {max_bag_mb: 0.5, max_bag_s: 60, keep: 3, queue_messages: 10}\n"
    ).record
    assert r is not None and r.path is None
    assert (r.max_bag_bytes, r.max_bag_s, r.keep, r.queue_messages) == (1 << 19, 60.0, 3, 10)


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("  path: 5", "record.path must be a directory path"),
        ("  path: ''", "record.path must be a directory path"),
        ("  max_bag_mb: 0", "record.max_bag_mb must be positive"),
        ("  max_bag_mb: big", "record.max_bag_mb must be a number, got 'big'"),
        ("  max_bag_s: -1", "record.max_bag_s must be positive"),
        ("  max_bag_s: .inf", "finite"),
        ("  keep: 0", "record: keep must be a whole number from 1 to 1000000, got '0'"),
        ("  keep: 2.5", "record: keep must be a whole number"),
        ("  queue_messages: true", "record: queue_messages must be a whole number"),
    ],
)
def test_record_section_errors_at_their_line(tmp_path, line, message):
    body = f"record:\n{line}\n" if "path" in line else f"record:\n  path: bags\n{line}\n"
    with pytest.raises(UserError) as e:
        _load(tmp_path, body)
    assert message in str(e.value)
    assert e.value.line == len(BASE.splitlines()) + len(body.splitlines())


def test_record_section_unknown_key_suggests(tmp_path):
    with pytest.raises(UserError) as e:
        _load(tmp_path, "record:\n  path: bags\n  kep: 3\n")
    assert "unknown key 'kep' in record" in str(e.value) and "did you mean 'keep'?" in str(e.value)
    assert e.value.line == len(BASE.splitlines()) + 3
    with pytest.raises(UserError) as e:
        _load(tmp_path, "record: bags\n")
    assert "record must be a mapping" in str(e.value)


def _offered(bag: Path) -> dict[str, tuple[int, list[tuple[str, str]]]]:
    """metadata.yaml's topics: message count and (reliability, durability) offered."""
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["ros_distro"] == "jazzy"
    return {
        t["topic_metadata"]["name"]: (
            t["message_count"],
            [
                (q["reliability"], q["durability"])
                for q in t["topic_metadata"]["offered_qos_profiles"]
            ],
        )
        for t in info["topics_with_message_count"]
    }


def test_offered_qos_goes_with_its_topic_and_a_change_starts_a_new_bag(tmp_path):
    rclpy_qos = pytest.importorskip("rclpy.qos")
    latched = rclpy_qos.QoSProfile(
        depth=1,
        reliability=rclpy_qos.ReliabilityPolicy.RELIABLE,
        durability=rclpy_qos.DurabilityPolicy.TRANSIENT_LOCAL,
    )
    volatile = rclpy_qos.QoSProfile(depth=10)
    best_effort = rclpy_qos.qos_profile_sensor_data
    rec = Recorder(tmp_path, [("/a", INT64), ("/b", INT64), ("/c", INT64), ("/a", INT64)])
    rec.offered_qos(0, [latched])
    rec.offered_qos(3, [latched])  # the same topic through its second input: no change
    rec.message(0, 1, cdr_int64(1))
    rec.message(1, 2, cdr_int64(2))  # QoS not known yet: written with none
    rec.offered_qos(1, [volatile, best_effort])  # two publishers: a new bag from here
    rec.message(1, 3, cdr_int64(3))
    rec.offered_qos(1, [best_effort, volatile])  # the graph's order varies: no change
    rec.message(3, 4, cdr_int64(4))
    stats = rec.close()
    assert (stats.written, stats.lost, stats.bags) == (4, 0, 2)
    first, second = (bag for _, bag in bag_dirs(tmp_path))
    latching = [("reliable", "transient_local")]
    # /c had neither QoS nor a message: listed with none, as rosbag2 lists a topic
    none = {RECORDS_TOPIC: (0, []), "/c": (0, [])}
    assert _offered(first) == {"/a": (1, latching), "/b": (1, []), **none}
    both = sorted([("reliable", "volatile"), ("best_effort", "volatile")])
    second_topics = _offered(second)
    assert sorted(second_topics["/b"][1]) == both
    assert second_topics == {"/a": (1, latching), "/b": (1, second_topics["/b"][1]), **none}
    assert [m.data for _, _, _, m in rosbags_messages(first) + rosbags_messages(second)] == [
        1,
        2,
        3,
        4,
    ]
    # MCAP channel metadata: the same profiles, as the YAML text rosbag2's plugin reads
    with mcap_file(second).open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    channels = {c.topic: c.metadata for c in summary.channels.values()}
    assert (
        sorted(
            (q["reliability"], q["durability"])
            for q in yaml.safe_load(channels["/b"]["offered_qos_profiles"])
        )
        == both
    )
