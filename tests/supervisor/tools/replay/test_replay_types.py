"""Types for replay from wherever they are (supervisor/inputs/rostypes.py): rosbag2's
own bags with stub, missing and service-event definitions replay with the installed
interface packages, values checked against rclpy's deserialize_message (the C
type support, an independent decoder); a bag type that differs from the installed
one is said; a type found nowhere is one line; the recorder still describes
installed types."""

from __future__ import annotations

import json
import shutil
import sqlite3
import struct
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_typestore

from supervisor.config import load_config
from supervisor.inputs.rostypes import installed_types, load_msg_types, msg_search_prefixes
from supervisor.tools.replay.sources import open_recordings

BAGS = Path(__file__).resolve().parents[3] / "data" / "bags"

TALKER = """\
component: Robot
step: {policy: periodic, period_ms: 100}
variables:
  level: {type: int64, topic: /rosout, msg: rcl_interfaces/msg/Log, field: level}
  line: {type: int64, topic: /rosout, msg: rcl_interfaces/msg/Log, field: line}
requirements:
  - {id: R1, text: Robot shall always satisfy level < 100 & line < 100000}
"""

SERVICE = """\
component: Robot
step: {policy: periodic, period_ms: 100}
variables:
  i64: {type: int64, service: /test_service1, srv: test_msgs/srv/BasicTypes, call: request, field: int64_value, initial: 0}
  f64: {type: double, service: /test_service1, srv: test_msgs/srv/BasicTypes, call: request, field: float64_value, initial: 0.0}
requirements:
  - {id: R1, text: Robot shall always satisfy i64 < 1000000 & f64 < 1000000.0}
"""


def installed_hash(name: str) -> str | None:
    """The REP-2011 hash rosidl computed for ``name``, as the installed package ships
    it (``type_hashes`` of ``share/<pkg>/<kind>/<Base>.json``)."""
    pkg, kind, short = name.split("/")
    base = short.split("_", 1)[0]
    for prefix in msg_search_prefixes():
        path = prefix / "share" / pkg / kind / f"{base}.json"
        if path.is_file():
            hashes = json.loads(path.read_text())["type_hashes"]
            return next((h["hash_string"] for h in hashes if h["type_name"] == name), None)
    return None


def _config(tmp_path: Path, text: str) -> Any:
    p = tmp_path / "c.yaml"
    p.write_text(text)
    return load_config(p)


def _raw(bag: Path, topic: str) -> list[tuple[int, bytes]]:
    """(receive time, payload) of ``topic``, read with sqlite3 or mcap directly."""
    out: list[tuple[int, bytes]] = []
    for f in sorted(bag.glob("*.db3")):
        con = sqlite3.connect(f"file:{f}?immutable=1", uri=True)
        out += con.execute(
            "SELECT timestamp, data FROM messages JOIN topics ON topics.id = topic_id "
            "WHERE name = ? ORDER BY timestamp",
            (topic,),
        ).fetchall()
        con.close()
    for f in sorted(bag.glob("*.mcap")):
        with f.open("rb") as fh:
            out += [
                (m.log_time, m.data)
                for _s, c, m in make_reader(fh).iter_messages()
                if c.topic == topic
            ]
    return sorted(out)


def _values(events: list[Any], topic: str) -> list[tuple[int, dict[str, Any]]]:
    # a response event gives a request variable nothing
    return [(t, dict(v)) for t, k, v in events if k == topic and v]


def _replay(tmp_path: Path, cfg_text: str, bag: Path) -> subprocess.CompletedProcess[str]:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(cfg_text)
    return subprocess.run(
        [sys.executable, "-m", "supervisor", "replay", str(cfg), str(bag), "-o",
         str(tmp_path / "out.jsonl"), "--quiet"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_talker_bags_decode_all_ten_messages_as_rclpy_does(tmp_path: Path, storage: str) -> None:
    from rcl_interfaces.msg import Log
    from rclpy.serialization import deserialize_message

    # a copy: sqlite opens talker.db3 (WAL mode) with a -shm file beside it
    bag = tmp_path / "talker"
    shutil.copytree(BAGS / storage / "talker", bag)
    rec = open_recordings([bag], _config(tmp_path, TALKER))
    got = _values(list(rec.events()), "/rosout")
    raw = _raw(bag, "/rosout")
    assert len(raw) == 10
    expected = []
    for t, data in raw:
        m = deserialize_message(data, Log)
        expected.append((t, {"level": m.level, "line": m.line}))
    assert got == expected
    run = _replay(tmp_path, TALKER, bag)
    assert run.returncode == 0, run.stderr
    assert "replayed 10 messages" in run.stdout


def test_a_sqlite_bag_without_definitions_uses_the_installed_types(tmp_path: Path) -> None:
    from rclpy.serialization import deserialize_message
    from test_msgs.srv import BasicTypes

    bag = tmp_path / "bag"
    shutil.copytree(BAGS / "sqlite3" / "bag_with_topics_and_service_events", bag)
    con = sqlite3.connect(next(bag.glob("*.db3")))
    con.execute("DROP TABLE message_definitions")
    con.commit()
    con.close()
    rec = open_recordings([bag], _config(tmp_path, SERVICE))
    got = _values(list(rec.events()), "/test_service1/_service_event")
    expected = [
        (t, {"i64": ev.request[0].int64_value, "f64": ev.request[0].float64_value})
        for t, d in _raw(bag, "/test_service1/_service_event")
        if (ev := deserialize_message(d, BasicTypes.Event)).request
    ]
    assert expected and got == expected


@pytest.mark.parametrize(
    "bag",
    [
        "sqlite3/bag_with_topics_and_service_events",
        "mcap/bag_with_topics_and_service_events",
    ],
)
def test_service_events_rosbag2_recorded_decode_as_rclpy_does(tmp_path: Path, bag: str) -> None:
    from rclpy.serialization import deserialize_message
    from test_msgs.srv import BasicTypes

    path = BAGS / bag
    if path.is_dir() and not any(path.glob("metadata.yaml")):
        path = next(path.glob("*.*3")) if any(path.glob("*.db3")) else next(path.glob("*.mcap"))
    rec = open_recordings([path], _config(tmp_path, SERVICE))
    got = _values(list(rec.events()), "/test_service1/_service_event")
    expected = []
    for t, data in _raw(path if path.is_dir() else path.parent, "/test_service1/_service_event"):
        ev = deserialize_message(data, BasicTypes.Event)
        if ev.request:  # a request event carries the request; response events do not
            expected.append(
                (t, {"i64": ev.request[0].int64_value, "f64": ev.request[0].float64_value})
            )
    assert expected and len(got) == len(expected)
    for (tg, vg), (te, ve) in zip(got, expected, strict=True):
        assert tg == te and vg["i64"] == ve["i64"] and vg["f64"] == pytest.approx(ve["f64"])


ADD_TWO_INTS = """\
component: Robot
step: {policy: periodic, period_ms: 100}
variables:
  a: {type: int64, service: /add_two_ints, srv: example_interfaces/srv/AddTwoInts, call: request, field: a, initial: 0}
  b: {type: int64, service: /add_two_ints, srv: example_interfaces/srv/AddTwoInts, call: request, field: b, initial: 0}
  s: {type: int64, service: /add_two_ints, srv: example_interfaces/srv/AddTwoInts, call: response, field: sum, initial: 0}
requirements:
  - {id: R1, text: Robot shall always satisfy a + b < 1000 & s < 1000}
"""


def _add_two_ints(data: bytes) -> dict[str, int]:
    """An AddTwoInts_Event decoded by hand from its CDR layout (little endian after
    the 4-byte header): ServiceEventInfo (uint8, Time at 4, char[16] at 12, int64 at
    32), then sequence<Request, 1> at 40 and sequence<Response, 1>."""
    assert data[:4] == b"\x00\x01\x00\x00"
    body = data[4:]
    (n_req,) = struct.unpack_from("<I", body, 40)
    out: dict[str, int] = {}
    at = 44
    if n_req:
        out["a"], out["b"] = struct.unpack_from("<qq", body, 48)
        at = 64
    (n_resp,) = struct.unpack_from("<I", body, at)
    if n_resp:
        (out["s"],) = struct.unpack_from("<q", body, (at + 4 + 7) // 8 * 8)
    return out


@pytest.mark.parametrize(
    "bag",
    [
        "mcap/only_services/only_services.mcap",
        "mcap/topics_and_services/topics_and_services.mcap",
        "sqlite3/topics_and_services/topics_and_services.db3",
    ],
)
def test_service_events_of_a_package_not_installed_decode_from_the_bags_srv_text(
    tmp_path: Path, bag: str
) -> None:
    # example_interfaces is not installed: the .srv text rosbag2 stored is the type
    path = BAGS / bag
    rec = open_recordings([path], _config(tmp_path, ADD_TWO_INTS))
    got = _values(list(rec.events()), "/add_two_ints/_service_event")
    expected = [
        (t, v)
        for t, d in _raw(path.parent, "/add_two_ints/_service_event")
        if (v := _add_two_ints(d))
    ]
    assert len(expected) >= 6 and got == expected
    assert any("s" in v for _t, v in expected) and any("a" in v for _t, v in expected)


def test_built_service_and_action_types_hash_as_rosidl_generated_them() -> None:
    # The installed packages ship rosidl's REP-2011 hashes: the types built from the
    # .action text must hash the same, field for field.  (rosbags reads char and byte
    # as uint8, so types holding them, service events among them through
    # ServiceEventInfo's char[16], hash otherwise: those are checked by decoding.)
    names = [
        "test_msgs/action/Fibonacci_Goal",
        "test_msgs/action/Fibonacci_FeedbackMessage",
        "test_msgs/action/Fibonacci_SendGoal_Request",
        "test_msgs/action/Fibonacci_SendGoal_Response",
        "test_msgs/action/Fibonacci_GetResult_Response",
    ]
    for name in names:
        store = get_typestore(Stores.EMPTY)
        store.register(installed_types(name))
        shipped = installed_hash(name)
        assert shipped is not None, name
        assert store.hash_rihs01(name) == shipped, name


def test_a_bag_type_that_differs_from_the_installed_one_is_said_and_not_used(
    tmp_path: Path,
) -> None:
    from rcl_interfaces.msg import Log
    from rclpy.serialization import deserialize_message

    bag = tmp_path / "talker"
    shutil.copytree(BAGS / "sqlite3" / "talker", bag)
    con = sqlite3.connect(bag / "talker.db3")
    # a definition that parses but is not the installed Log: the bag is wrong about it
    con.execute(
        "UPDATE message_definitions SET encoded_message_definition = ? WHERE topic_type = ?",
        ("builtin_interfaces/Time stamp\nuint32 level\nstring name\n", "rcl_interfaces/msg/Log"),
    )
    con.commit()
    con.close()
    rec = open_recordings([bag], _config(tmp_path, TALKER))
    got = _values(list(rec.events()), "/rosout")
    expected = [
        (t, {"level": (m := deserialize_message(d, Log)).level, "line": m.line})
        for t, d in _raw(bag, "/rosout")
    ]
    assert got == expected
    said = [w for s in rec.sources for w in s.warnings if "rcl_interfaces/msg/Log" in w]
    assert len(said) == 1 and "installed" in said[0] and "RIHS01_" in said[0], said
    run = _replay(tmp_path, TALKER, bag)
    assert run.returncode == 0, run.stderr
    assert "rcl_interfaces/msg/Log" in run.stdout + run.stderr


def test_a_type_found_nowhere_is_one_line_naming_its_package(tmp_path: Path) -> None:
    bag = tmp_path / "talker"
    shutil.copytree(BAGS / "sqlite3" / "talker", bag)
    con = sqlite3.connect(bag / "talker.db3")
    con.execute("UPDATE topics SET type = 'acme_msgs/msg/Log' WHERE name = '/rosout'")
    con.execute("DROP TABLE message_definitions")
    con.commit()
    con.close()
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace("rcl_interfaces/msg/Log", "acme_msgs/msg/Log"))
    run = _replay(tmp_path, TALKER.replace("rcl_interfaces/msg/Log", "acme_msgs/msg/Log"), bag)
    assert run.returncode == 1
    lines = [x for x in run.stderr.splitlines() if x.strip()]
    assert len(lines) == 1, run.stderr
    assert "acme_msgs/msg/Log" in lines[0] and "ros-jazzy-acme-msgs" in lines[0], lines
    assert "Traceback" not in run.stderr


def test_the_recorder_still_describes_installed_types_rosbags_lacks() -> None:
    store = get_typestore(Stores.ROS2_JAZZY)
    assert "test_msgs/msg/BasicTypes" not in store.types
    load_msg_types(store, "test_msgs/msg/Nested")
    assert "test_msgs/msg/BasicTypes" in store.types  # used by Nested, loaded with it
    assert [f for f, _ in store.fielddefs["test_msgs/msg/Nested"][1]] == ["basic_types_value"]
    assert installed_hash("test_msgs/msg/Nested")  # the package is there, its .msg read
    with pytest.raises(LookupError, match="acme_msgs/msg/Nope"):
        load_msg_types(store, "acme_msgs/msg/Nope")
