"""Recordings read back for replay (supervisor/tools/replay/sources.py): real rosbag2
bags in both storage formats and metadata versions, files given directly, an MCAP file
left without metadata.yaml, several bags merged, damaged files (everything before the
damage, then the located error), type mismatches and JSON-lines traces."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from monitors.errors import UserError
from supervisor.config import load_config
from supervisor.tools.replay.sources import RECORDS_TOPIC, open_recordings

TS = get_typestore(Stores.ROS2_JAZZY)
CUSTOM = "acme_msgs/msg/Status"
TS.register(get_types_from_msg("int32 mode\nstring note\nfloat64 level\n", CUSTOM))

CONFIG = """\
component: Robot
step: {policy: periodic, period_ms: 100}
variables:
  x: {type: int64, topic: /x, msg: std_msgs/Int64}
  vx: {type: double, topic: /cmd_vel, msg: geometry_msgs/msg/Twist, field: linear.x}
  wz: {type: double, topic: /cmd_vel, msg: geometry_msgs/msg/Twist, field: angular.z}
  level: {type: double, topic: /status, msg: acme_msgs/msg/Status, field: level}
  mode: {type: int64, topic: /status, msg: acme_msgs/msg/Status, field: mode}
  halted: {type: bool, topic: /halted, msg: std_msgs/msg/Bool, initial: false}
  near: {type: bool, define: x < 5}
requirements:
  - {id: R1, text: Robot shall always satisfy x < 100}
"""


def config(tmp_path, text=CONFIG):
    p = tmp_path / "c.yaml"
    p.write_text(text)
    return load_config(p)


def ser(msgtype, **fields):
    return TS.serialize_cdr(TS.types[msgtype](**fields), msgtype)


def twist(vx, wz):
    v3 = TS.types["geometry_msgs/msg/Vector3"]
    return ser("geometry_msgs/msg/Twist", linear=v3(vx, 0.0, 0.0), angular=v3(0.0, 0.0, wz))


def standard_messages(n=6, t0=1_000):
    """(t_ns, topic, type, payload) and the events they should give, in time order."""
    msgs, events = [], []
    for i in range(n):
        t = t0 + 100 * i
        msgs.append((t, "/x", "std_msgs/msg/Int64", ser("std_msgs/msg/Int64", data=i * 7 - 3)))
        events.append((t, "/x", [("x", i * 7 - 3)]))
        msgs.append(
            (t + 10, "/extra", "std_msgs/msg/String", ser("std_msgs/msg/String", data="no"))
        )
        msgs.append((t + 20, "/cmd_vel", "geometry_msgs/msg/Twist", twist(i * 0.5, -i * 0.25)))
        events.append((t + 20, "/cmd_vel", [("vx", i * 0.5), ("wz", -i * 0.25)]))
        status = ser(CUSTOM, mode=i, note="n" * i, level=i / 3)  # a string before level
        msgs.append((t + 30, "/status", CUSTOM, status))
        events.append((t + 30, "/status", [("level", i / 3), ("mode", i)]))
    rec = {"event": "marker", "what": "start"}
    msgs.append(
        (
            t0 + 5,
            RECORDS_TOPIC,
            "std_msgs/msg/String",
            ser("std_msgs/msg/String", data=json.dumps(rec)),
        )
    )
    events.insert(1, (t0 + 5, "record", rec))
    return sorted(msgs, key=lambda m: m[0]), events


def write_bag(path, msgs, version=9, plugin=StoragePlugin.MCAP, order=None):
    conns = {}
    with Writer(path, version=version, storage_plugin=plugin) as w:
        for t, topic, typ, data in order or msgs:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, typ, typestore=TS)
            w.write(conns[topic], t, data)
    return path


def read(paths, cfg, progress=None):
    rec = open_recordings([Path(p) for p in paths], cfg)
    return rec, list(rec.events(progress=progress))


def read_until_error(paths, cfg):
    rec = open_recordings([Path(p) for p in paths], cfg)
    got = []
    with pytest.raises(UserError) as err:
        for ev in rec.events():
            got.append(ev)
    return got, err.value


def approx_events(events):
    return [(t, k, pytest.approx(v) if isinstance(v, list) else v) for t, k, v in events]


FORMATS = [
    (8, StoragePlugin.SQLITE3),
    (9, StoragePlugin.SQLITE3),
    (8, StoragePlugin.MCAP),
    (9, StoragePlugin.MCAP),
]


@pytest.mark.parametrize("version,plugin", FORMATS, ids=lambda f: str(getattr(f, "name", f)))
def test_bag_gives_every_config_value_in_receive_order(tmp_path, version, plugin):
    cfg = config(tmp_path)
    msgs, expected = standard_messages()
    bag = write_bag(tmp_path / "bag", msgs, version, plugin)
    rec, events = read([bag], cfg)
    assert events == expected
    assert isinstance(events[0][2][0][1], int) and isinstance(events[2][2][0][1], float)
    summary = rec.summary()
    assert "ignored (not in the config): /extra" in summary
    # /halted has an initial value: a warning, not an error
    assert any("/halted" in w and "never" not in w for w in rec.warnings)
    assert rec.total == len([m for m in msgs if m[1] != "/extra"])


@pytest.mark.parametrize("plugin", [StoragePlugin.SQLITE3, StoragePlugin.MCAP])
def test_batches_hold_the_same_values_as_columns(tmp_path, plugin):
    cfg = config(tmp_path)
    msgs, expected = standard_messages(50)
    bag = write_bag(tmp_path / "bag", msgs, 9, plugin)
    rec = open_recordings([bag], cfg)
    batches = list(rec.batches(chunk=7))
    t = np.concatenate([b.t_ns for b in batches])
    assert t.tolist() == [e[0] for e in expected]
    vx = np.concatenate([b.values["vx"][b.rows("/cmd_vel")] for b in batches])
    assert vx.tolist() == [e[2][0][1] for e in expected if e[1] == "/cmd_vel"]
    assert vx.dtype == np.float64
    x = np.concatenate([b.values["x"][b.rows("/x")] for b in batches])
    assert x.dtype == np.int64 and x.tolist() == [e[2][0][1] for e in expected if e[1] == "/x"]
    # level lies after a string: read in bulk from each message's string length
    level = np.concatenate([b.values["level"][b.rows("/status")] for b in batches])
    assert level.tolist() == [e[2][0][1] for e in expected if e[1] == "/status"]


SEQ = "acme_msgs/msg/Samples"
TS.register(get_types_from_msg("uint8 kind\nfloat64[] samples\nint16 count\nfloat64 mean\n", SEQ))


@pytest.mark.parametrize("plugin", [StoragePlugin.SQLITE3, StoragePlugin.MCAP])
def test_fields_after_a_sequence_decode_in_bulk_as_rosbags_does(tmp_path, plugin):
    cfg = config(
        tmp_path,
        CONFIG.replace(
            "msg: acme_msgs/msg/Status, field: level", f"msg: {SEQ}, field: mean"
        ).replace("msg: acme_msgs/msg/Status, field: mode", f"msg: {SEQ}, field: count"),
    )
    msgs, expected = [], []
    for i in range(40):
        samples = np.arange(i % 3, dtype=np.float64)  # empty ones too
        msgs.append((i, "/status", SEQ, ser(SEQ, kind=i, samples=samples, count=-i, mean=i / 7)))
        expected.append((i, "/status", [("level", i / 7), ("mode", -i)]))
    bag = write_bag(tmp_path / "bag", msgs, 9, plugin)
    assert read([bag], cfg)[1] == expected


def test_messages_written_out_of_order_are_replayed_in_receive_order(tmp_path):
    cfg = config(tmp_path)
    msgs, expected = standard_messages(5)
    bag = write_bag(tmp_path / "bag", msgs, 9, StoragePlugin.MCAP, order=msgs[::-1])
    assert read([bag], cfg)[1] == expected


def test_violations_beside_the_records_topic_are_not_read_twice(tmp_path):
    cfg = config(tmp_path)
    rec = {"event": "violation", "requirement": "R1"}
    text = ser("std_msgs/msg/String", data=json.dumps(rec))
    msgs = [
        (1, RECORDS_TOPIC, "std_msgs/msg/String", text),
        (2, "/safety_supervisor/violations", "std_msgs/msg/String", text),
    ]
    assert read([write_bag(tmp_path / "a", msgs)], cfg)[1] == [(1, "record", rec)]
    assert read([write_bag(tmp_path / "b", msgs[1:])], cfg)[1] == [(2, "record", rec)]


def test_storage_files_given_directly_and_an_mcap_without_metadata(tmp_path):
    cfg = config(tmp_path)
    msgs, expected = standard_messages()
    for plugin, ext in ((StoragePlugin.MCAP, "mcap"), (StoragePlugin.SQLITE3, "db3")):
        bag = write_bag(tmp_path / f"bag_{ext}", msgs, 9, plugin)
        (f,) = bag.glob(f"*.{ext}")
        assert read([f], cfg)[1] == expected
    # a recorder killed before writing metadata.yaml: the directory and the file
    bag = tmp_path / "bag_mcap"
    (bag / "metadata.yaml").unlink()
    assert read([bag], cfg)[1] == expected
    assert read([next(bag.glob("*.mcap"))], cfg)[1] == expected


def test_several_bags_merge_in_receive_order(tmp_path):
    cfg = config(tmp_path)
    msgs, expected = standard_messages(20)
    # the rotated pieces of one recording, and an interleaved second recording
    a = write_bag(tmp_path / "a", msgs[:30], 9, StoragePlugin.MCAP)
    b = write_bag(tmp_path / "b", msgs[30:], 8, StoragePlugin.SQLITE3)
    assert read([b, a], cfg)[1] == expected
    c = write_bag(tmp_path / "c", msgs[0::2], 9, StoragePlugin.MCAP)
    d = write_bag(tmp_path / "d", msgs[1::2], 9, StoragePlugin.SQLITE3)
    rec = open_recordings([c, d], cfg)
    assert list(rec.events()) == expected
    batches = list(rec.batches(chunk=5))
    assert np.concatenate([x.t_ns for x in batches]).tolist() == [e[0] for e in expected]


def test_progress_reports_messages_read_and_the_total(tmp_path):
    cfg = config(tmp_path)
    msgs, expected = standard_messages(10)
    bag = write_bag(tmp_path / "bag", msgs, 9, StoragePlugin.MCAP)
    seen = []
    read([bag], cfg, progress=lambda n, total: seen.append((n, total)))
    wanted = len([m for m in msgs if m[1] != "/extra"])
    assert seen[-1] == (wanted, wanted)
    # a bare MCAP file: the counts of its summary's statistics
    seen.clear()
    read([next(bag.glob("*.mcap"))], cfg, progress=lambda n, total: seen.append((n, total)))
    assert seen[-1] == (wanted, wanted)


def test_a_recorded_type_other_than_the_configs_is_a_one_line_error(tmp_path):
    cfg = config(tmp_path)
    bag = write_bag(
        tmp_path / "bag", [(1, "/x", "std_msgs/msg/Int32", ser("std_msgs/msg/Int32", data=1))]
    )
    with pytest.raises(UserError) as err:
        open_recordings([bag], cfg)
    text = str(err.value)
    assert "\n" not in text and str(bag) in text
    assert "/x" in text and "std_msgs/msg/Int32" in text and "std_msgs/msg/Int64" in text


def test_a_field_the_recorded_type_lacks_is_an_error(tmp_path):
    cfg = config(tmp_path, CONFIG.replace("field: level", "field: levels"))
    msgs, _ = standard_messages(1)
    bag = write_bag(tmp_path / "bag", msgs)
    with pytest.raises(UserError, match="no field 'levels'"):
        list(open_recordings([bag], cfg).events())


def test_a_missing_input_without_initial_is_a_warning_that_says_so(tmp_path):
    cfg = config(tmp_path)
    bag = write_bag(
        tmp_path / "bag", [(1, "/x", "std_msgs/msg/Int64", ser("std_msgs/msg/Int64", data=1))]
    )
    rec, events = read([bag], cfg)
    assert events == [(1, "/x", [("x", 1)])]
    text = "\n".join(rec.warnings)
    assert "/cmd_vel (vx, wz)" in text and "never" in text


def many_int64(n):
    msgs = [
        (1000 + 10 * i, "/x", "std_msgs/msg/Int64", ser("std_msgs/msg/Int64", data=i))
        for i in range(n)
    ]
    return msgs, [(t, "/x", [("x", i)]) for i, (t, *_) in enumerate(msgs)]


@pytest.mark.parametrize(
    "plugin,ext", [(StoragePlugin.MCAP, "mcap"), (StoragePlugin.SQLITE3, "db3")]
)
@pytest.mark.slow
def test_a_truncated_bag_gives_everything_before_the_damage_then_the_place(tmp_path, plugin, ext):
    cfg = config(tmp_path)
    msgs, expected = many_int64(60_000)  # several MCAP chunks, many sqlite pages
    bag = write_bag(tmp_path / "bag", msgs, 9, plugin)
    (f,) = bag.glob(f"*.{ext}")
    data = f.read_bytes()
    f.write_bytes(data[: len(data) // 2])
    got, err = read_until_error([bag], cfg)
    assert 0 < len(got) < len(expected)
    assert got == expected[: len(got)]
    text = str(err)
    assert "\n" not in text and str(f) in text and "damaged" in text
    assert f"t_ns {got[-1][0]}" in text or f"t_ns {expected[len(got)][0]}" in text


def test_an_mcap_cut_inside_its_first_chunk_is_an_error_naming_the_file(tmp_path):
    cfg = config(tmp_path)
    msgs, _ = many_int64(100)
    bag = write_bag(tmp_path / "bag", msgs, 9, StoragePlugin.MCAP)
    (f,) = bag.glob("*.mcap")
    f.write_bytes(f.read_bytes()[:40])
    (bag / "metadata.yaml").unlink()
    with pytest.raises(UserError, match="not a readable MCAP file"):
        open_recordings([f], cfg)


def test_a_message_that_does_not_decode_ends_the_stream_at_it(tmp_path):
    cfg = config(tmp_path)
    msgs, expected = standard_messages(4)
    bad_at = next(i for i, m in enumerate(msgs) if m[1] == "/status" and m[0] > 1200)
    t_bad = msgs[bad_at][0]
    msgs[bad_at] = (t_bad, "/status", CUSTOM, b"\x00\x01\x00\x00\xff\xff")  # cut short
    bag = write_bag(tmp_path / "bag", msgs, 9, StoragePlugin.MCAP)
    got, err = read_until_error([bag], cfg)
    assert got == [e for e in expected if e[0] < t_bad]
    assert f"t_ns {t_bad}" in str(err) and "does not decode as acme_msgs/msg/Status" in str(err)


def test_a_record_that_is_not_json_is_located(tmp_path):
    cfg = config(tmp_path)
    msgs = [
        (1, "/x", "std_msgs/msg/Int64", ser("std_msgs/msg/Int64", data=4)),
        (2, RECORDS_TOPIC, "std_msgs/msg/String", ser("std_msgs/msg/String", data="{oops")),
    ]
    got, err = read_until_error([write_bag(tmp_path / "bag", msgs)], cfg)
    assert got == [(1, "/x", [("x", 4)])]
    assert "t_ns 2" in str(err) and "not a JSON record" in str(err)


def test_a_json_lines_trace(tmp_path):
    cfg = config(tmp_path)
    trace = tmp_path / "t.jsonl"
    lines = [
        {"t_ns": 0, "record": {"event": "marker", "what": "start"}},
        {"t_ns": 10, "name": "x", "value": 3},
        {"t_ns": 20, "name": "vx", "value": 1},
        {"t_ns": 20, "name": "wz", "value": -0.5},
        {"t_ns": 30, "name": "halted", "value": True},
    ]
    trace.write_text("\n".join(json.dumps(x) for x in lines) + "\n\n")
    rec, events = read([trace], cfg)
    assert events == [
        (0, "record", {"event": "marker", "what": "start"}),
        (10, "/x", [("x", 3)]),
        (20, "/cmd_vel", [("vx", 1.0)]),
        (20, "/cmd_vel", [("wz", -0.5)]),
        (30, "/halted", [("halted", True)]),
    ]
    # merged with a bag
    bag = write_bag(
        tmp_path / "bag", [(15, "/x", "std_msgs/msg/Int64", ser("std_msgs/msg/Int64", data=9))]
    )
    assert [e[0] for e in read([trace, bag], cfg)[1]] == [0, 10, 15, 20, 20, 30]


@pytest.mark.parametrize(
    "line,message",
    [
        ('{"t": 1.5, "name": "x", "value": 1}', 'expected {"t_ns"'),
        ('{"t_ns": 5, "topic": "/x", "value": 1}', 'expected {"t_ns"'),
        ('{"t_ns": 5, "name": "nope", "value": 1}', '"nope" is not a topic variable'),
        ('{"t_ns": 5, "name": "near", "value": true}', '"near" is not a topic variable'),
        ('{"t_ns": 5, "name": "x", "value": 1.5}', "'x' is int64; 1.5 is not"),
        ('{"t_ns": 5, "name": "halted", "value": 1}', "'halted' is bool; 1 is not"),
        ('{"t_ns": -1, "name": "x", "value": 1}', "t_ns must be a whole number"),
        ('{"t_ns": 5, "name": "x", "value": 1', "not JSON"),
        ('{"t_ns": 1, "name": "x", "value": 1}', "t_ns 1 is before the previous line's 2"),
    ],
)
def test_a_bad_trace_line_is_refused_with_its_number(tmp_path, line, message):
    cfg = config(tmp_path)
    trace = tmp_path / "t.jsonl"
    trace.write_text('{"t_ns": 2, "name": "x", "value": 7}\n' + line + "\n")
    got, err = read_until_error([trace], cfg)
    assert got == [(2, "/x", [("x", 7)])]
    assert str(err).startswith(f"{trace}: line 2: ") and message in str(err), str(err)


def test_unknown_inputs_are_refused(tmp_path):
    cfg = config(tmp_path)
    with pytest.raises(UserError, match="no such file"):
        open_recordings([tmp_path / "nothing"], cfg)
    (tmp_path / "x.csv").write_text("t,x\n")
    with pytest.raises(UserError, match="unknown recording format"):
        open_recordings([tmp_path / "x.csv"], cfg)
    (tmp_path / "empty").mkdir()
    with pytest.raises(UserError, match="not a rosbag2 bag"):
        open_recordings([tmp_path / "empty"], cfg)
    (tmp_path / "junk.mcap").write_bytes(b"junk" * 10)
    with pytest.raises(UserError, match="not a readable MCAP file"):
        open_recordings([tmp_path / "junk.mcap"], cfg)


@pytest.mark.slow
@pytest.mark.parametrize("plugin", [StoragePlugin.MCAP, StoragePlugin.SQLITE3])
def test_a_million_fixed_size_messages_decode_in_bulk(tmp_path, plugin):
    cfg = config(tmp_path)
    n = 1_000_000
    payloads = [ser("std_msgs/msg/Int64", data=i) for i in range(n)]
    with Writer(tmp_path / "bag", version=9, storage_plugin=plugin) as w:
        c = w.add_connection("/x", "std_msgs/msg/Int64", typestore=TS)
        for i, p in enumerate(payloads):
            w.write(c, 10 * i, p)
    rec = open_recordings([tmp_path / "bag"], cfg)
    x = np.concatenate([b.values["x"] for b in rec.batches()])
    assert np.array_equal(x, np.arange(n))
    shutil.rmtree(tmp_path / "bag")


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_an_mcap_file_from_another_writer_with_compressed_chunks(tmp_path, compression):
    # mcap_ros2's writer: chunk compression (rosbag2's zstd presets), and schemas,
    # channels and indexes laid out by a different implementation than rosbags'
    from mcap.writer import CompressionType
    from mcap_ros2.writer import Writer as McapWriter

    cfg = config(tmp_path)
    path = tmp_path / "other.mcap"
    with path.open("wb") as f:
        w = McapWriter(f, chunk_size=200, compression=CompressionType[compression.upper()])
        int64 = w.register_msgdef("std_msgs/msg/Int64", "int64 data")
        twist = w.register_msgdef(
            "geometry_msgs/msg/Twist",
            "Vector3 linear\nVector3 angular\n" + "=" * 80 + "\nMSG: geometry_msgs/Vector3\n"
            "float64 x\nfloat64 y\nfloat64 z\n",
        )
        for i in range(30):
            w.write_message("/x", int64, {"data": i}, log_time=100 * i)
            v = {
                "linear": {"x": i / 2, "y": 0.0, "z": 0.0},
                "angular": {"x": 0.0, "y": 0.0, "z": -i},
            }
            w.write_message("/cmd_vel", twist, v, log_time=100 * i + 50)
        w.finish()
    expected = []
    for i in range(30):
        expected += [
            (100 * i, "/x", [("x", i)]),
            (100 * i + 50, "/cmd_vel", [("vx", i / 2), ("wz", -i)]),
        ]
    assert read([path], cfg)[1] == expected
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 3])  # inside the chunks, before the summary
    got, err = read_until_error([path], cfg)
    assert 0 < len(got) < len(expected) and got == expected[: len(got)]
    assert str(path) in str(err)
