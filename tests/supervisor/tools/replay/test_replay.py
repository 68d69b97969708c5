"""``replay`` end to end on real rosbag2 files written with rosbags: both storage
formats, extra topics, the fast path against message-by-message stepping, damage,
what-if between two configs.  (Reading is tested in test_replay_sources.py; the
daemon's own recording in test_record_replay.py.)"""

from __future__ import annotations

import json
import random
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from mitigations.violationlog.reader import iter_records
from supervisor.tools.replay.session import compare, replay_files

TS = get_typestore(Stores.ROS2_JAZZY)
MS = 1_000_000

CONFIG = """\
component: R
step: {{policy: {policy}, stale_after_ms: 150{trigger}}}
variables:
  speed: {{type: double, topic: /speed, msg: std_msgs/msg/Float64}}
  count: {{type: int64, topic: /count, msg: std_msgs/msg/UInt64}}
  vx:    {{type: double, topic: /cmd, msg: geometry_msgs/msg/Twist, field: linear.x}}
  wz:    {{type: double, topic: /cmd, msg: geometry_msgs/msg/Twist, field: angular.z}}
requirements:
  - id: limit
    text: R shall always satisfy speed <= {limit}
    on_violation: [note]
    policy: {{reset: after_mitigation}}
  - id: counting
    text: R shall always satisfy count < 1000
    on_violation: [note]
    policy: {{debounce_steps: 3, cooldown_ms: 50, reset: after_mitigation}}
  - id: turn
    text: R shall always satisfy vx * wz >= -1.0
    on_violation: [note]
    policy: {{latch: true, repeat_ms: 100}}
on_stale: [note]
mitigations:
  note: {{log: {{message: violated}}}}
"""


def config(tmp: Path, name: str = "c.yaml", policy: str = "on_message", limit: float = 2.0) -> Path:
    trigger = ", trigger: speed" if policy == "on_trigger" else ""
    p = tmp / name
    p.write_text(CONFIG.format(policy=policy, trigger=trigger, limit=limit))
    return p


def messages(seed: int, n: int) -> list[tuple[int, str, Any]]:
    """A robot's run: speed, a counter (now and then too big for int64), a twist
    (two variables), an extra topic; silences (stale inputs), NaN speeds."""
    rng = random.Random(seed)
    t, out = 10**9, []
    for _ in range(n):
        t += rng.randint(1, 20) * MS // 2
        if rng.random() < 0.01:
            t += 200 * MS
        topic = rng.choice(["/speed", "/speed", "/count", "/cmd", "/extra"])
        if topic == "/speed":
            value: Any = rng.choice([float("nan")] + [round(rng.uniform(0, 2.6), 2)] * 60)
        elif topic == "/count":
            value = rng.choice([2**64 - 1] + [rng.randint(0, 1100)] * 50)
        elif topic == "/cmd":
            value = (round(rng.uniform(-1.5, 1.5), 2), round(rng.uniform(-1.5, 1.5), 2))
        else:
            value = "noise"
        out.append((t, topic, value))
    return out


def write_bag(
    path: Path, msgs: list[tuple[int, str, Any]], plugin: str = "MCAP", version: int = 9
) -> Path:
    types = {
        "/speed": "std_msgs/msg/Float64",
        "/count": "std_msgs/msg/UInt64",
        "/cmd": "geometry_msgs/msg/Twist",
        "/extra": "std_msgs/msg/String",
    }
    with Writer(path, version=version, storage_plugin=StoragePlugin[plugin]) as w:
        conns = {t: w.add_connection(t, ty, typestore=TS) for t, ty in types.items()}
        for t, topic, value in msgs:
            cls = TS.types[types[topic]]
            if topic == "/cmd":
                v3 = TS.types["geometry_msgs/msg/Vector3"]
                msg = cls(linear=v3(x=value[0], y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=value[1]))
            else:
                msg = cls(data=value)
            w.write(conns[topic], t, bytes(TS.serialize_cdr(msg, types[topic])))
    return path


def decisions(path: Path) -> list[dict[str, Any]]:
    drop = ("ts", "_ts", "prev_sha256", "seq", "line_sha256")
    return [{k: v for k, v in r.items() if k not in drop} for r in iter_records(str(path))]


@pytest.mark.slow
@pytest.mark.parametrize("policy", ["on_message", "on_trigger"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_bulk_stepping_writes_what_message_by_message_writes(tmp_path, policy, seed):
    bag = write_bag(tmp_path / "bag", messages(seed, 6000))
    cfg = config(tmp_path, policy=policy)
    fast = replay_files(cfg, [bag], tmp_path / "fast.jsonl", None, fast=True)
    exact = replay_files(cfg, [bag], tmp_path / "exact.jsonl", None, fast=False)
    assert fast["error"] is None and exact["error"] is None
    got, want = decisions(tmp_path / "fast.jsonl")[1:], decisions(tmp_path / "exact.jsonl")[1:]
    kinds = {r["event"] for r in want} | {r.get("what") for r in want}
    assert {
        "violation",
        "reset",
        "mitigation",
        "input_stale",
        "input_nan",
        "input_rejected",
    } <= kinds
    assert got == want
    assert fast["ticks"] == exact["ticks"] > 1000


@pytest.mark.parametrize(("plugin", "version"), [("MCAP", 9), ("SQLITE3", 8), ("SQLITE3", 9)])
def test_violations_are_exactly_the_ticks_where_the_requirement_fails(tmp_path, plugin, version):
    """An oracle of its own: on_message, reset after each violation, no debounce:
    'limit' is reported at every tick where speed > 2.0 (NaN: every comparison is
    false, so a NaN speed violates too)."""
    msgs = messages(7, 3000)
    bag = write_bag(tmp_path / "bag", msgs, plugin, version)
    out = tmp_path / "out.jsonl"
    result = replay_files(config(tmp_path), [bag], out, None)
    assert any("ignored (not in the config): /extra" in n for n in result["notes"])
    ticks, tick, seen = [], -1, set()
    speed = float("nan")
    for _t, topic, value in msgs:
        if topic == "/extra" or (topic == "/count" and value >= 2**63):
            continue  # not an input / rejected (too big for int64): no step
        seen.add(topic)
        if topic == "/speed":
            speed = value
        if len(seen) < 3:  # nothing is stepped before every input has a value
            continue
        tick += 1
        if not speed <= 2.0:
            ticks.append(tick)
    got = [
        r["tick"]
        for r in iter_records(str(out))
        if r.get("requirement") == "limit" and r["event"] == "violation"
    ]
    assert got == ticks and len(ticks) > 20
    assert all(r["dry_run"] for r in iter_records(str(out)) if r["event"] == "mitigation")


@pytest.mark.slow
def test_a_truncated_bag_is_replayed_up_to_the_damage(tmp_path):
    # rosbags writes chunks of 1 MiB: several of them, the file cut in the 3rd or 4th
    bag = write_bag(tmp_path / "bag", messages(3, 80000))
    mcap = next(bag.glob("*.mcap"))
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) * 6 // 10])
    out = tmp_path / "out.jsonl"
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "replay", str(config(tmp_path)), str(bag), "-o",
         str(out), "--quiet"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert run.returncode == 1
    errors = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(errors) == 1 and str(mcap.name) in errors[0] and "Traceback" not in run.stderr
    records = list(iter_records(str(out)))
    assert any(r["event"] == "violation" for r in records)
    assert records[-1].get("what") == "replay_damaged"
    replayed = int(run.stdout.split()[1].replace(",", ""))
    assert 20000 < replayed < 80000


@pytest.mark.slow
def test_what_if_reports_exactly_the_difference(tmp_path):
    msgs = messages(5, 4000)
    bag = write_bag(tmp_path / "bag", msgs)
    a = config(tmp_path, "a.yaml", limit=2.0)
    b = config(tmp_path, "b.yaml", limit=1.5)
    result = compare(a, b, [bag], None)
    rows = {r["id"]: r for r in result["requirements"]}
    assert rows["counting"]["only_a"] == rows["counting"]["only_b"] == []
    assert rows["turn"]["only_a"] == rows["turn"]["only_b"] == []
    limit = rows["limit"]
    assert limit["only_a"] == []
    # B (1.5) also reports the ticks whose speed is in (1.5, 2.0]
    exact_a = replay_files(a, [bag], tmp_path / "a.jsonl", None)
    exact_b = replay_files(b, [bag], tmp_path / "b.jsonl", None)
    va = {
        r["tick"]
        for r in iter_records(str(tmp_path / "a.jsonl"))
        if r.get("requirement") == "limit" and r["event"] == "violation"
    }
    vb = {
        r["tick"]
        for r in iter_records(str(tmp_path / "b.jsonl"))
        if r.get("requirement") == "limit" and r["event"] == "violation"
    }
    assert limit["only_b"] == sorted(vb - va) and len(limit["only_b"]) > 10
    assert exact_a["ticks"] == exact_b["ticks"]
    assert "B" in limit["first"] or limit["first"] == "same tick"
    # and the command prints it, as JSON too
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "replay", str(a), "--compare", str(b), str(bag),
         "--json"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    printed = {r["id"]: r for r in json.loads(run.stdout)["requirements"]}
    assert printed["limit"]["only_b"] == limit["only_b"]


def test_json_lines_traces_replay(tmp_path):
    trace = tmp_path / "t.jsonl"
    lines = []
    t = 10**9
    for k in range(200):
        t += 10 * MS
        lines.append({"t_ns": t, "name": "speed", "value": 2.5 if k == 150 else 1.0})
        lines.append({"t_ns": t + 1, "name": "count", "value": k})
        lines.append({"t_ns": t + 2, "name": "vx", "value": 0.5})
        lines.append({"t_ns": t + 3, "name": "wz", "value": 0.5})
    trace.write_text("\n".join(json.dumps(x) for x in lines) + "\n")
    out = tmp_path / "out.jsonl"
    # on_message steps at each of the 4 messages while speed is 2.5; on_trigger once
    for policy, expected in (("on_message", 4), ("on_trigger", 1)):
        result = replay_files(config(tmp_path, policy=policy), [trace], out, None)
        limit = next(r for r in result["requirements"] if r["id"] == "limit")
        assert limit["violations"] == expected, policy
