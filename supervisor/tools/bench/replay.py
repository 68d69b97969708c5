"""The replay experiment: rosbag2 bags written for the bench's config, replayed in
this process (``safety-supervisor replay``'s own code), messages per second per case;
and the monitor alone, one ``tick()`` per tick against ``tick_batch``.

Cases (docs/reference/commands.md#bench): fixed-size messages in MCAP and in sqlite3,
the same with a violating round every ``VIOLATE_EVERY`` ticks (each violation ends a
bulk step), ``--exact`` (message by message), and a variable-size message (LaserScan,
whose ``range_min`` follows a string and whose sequences vary in length).
"""

from __future__ import annotations

import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NamedTuple

from supervisor.tools.bench.plan import SROBOT_VIOLATING, Plan

RECORDED_RATE = 20_000  # msg/s of the bags' receive times (the daemon's 20k goal)
VIOLATE_EVERY = 1000  # ticks between two violating rounds in the "violations" case
SCAN_CONFIG = """\
component: Scan
step: {policy: on_message}
variables:
  range_min: {type: double, topic: /scan, msg: sensor_msgs/msg/LaserScan, field: range_min}
requirements:
  - id: r1
    text: Scan shall always satisfy range_min >= 0.0
    on_violation: [record]
mitigations:
  record: {log: {message: violated}}
logging: {violations: LOG}
"""


def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def _default(ts: Any, msgtype: str, override: dict[str, Any]) -> Any:
    """A message of ``msgtype`` with every field zero or empty except ``override``
    (nested dicts for nested fields); rosbags' classes have no defaults."""
    import numpy as np
    from rosbags.interfaces import Nodetype

    def dtype(name: str) -> Any:
        return np.uint8 if name in ("byte", "char", "octet") else np.dtype(name)

    def base(name: str) -> Any:
        if name in ("string", "wstring"):
            return ""
        if name == "bool":
            return False
        return 0.0 if name.startswith("float") else 0

    kwargs: dict[str, Any] = {}
    for name, (kind, payload) in ts.fielddefs[msgtype][1]:
        if name in override and not isinstance(override[name], dict):
            kwargs[name] = override[name]
        elif kind == Nodetype.NAME:
            kwargs[name] = _default(ts, payload, override.get(name, {}))
        elif kind == Nodetype.BASE:
            kwargs[name] = base(payload[0])
        else:  # an array (fixed length) or a sequence (empty)
            (ekind, epayload), length = payload
            n = length if kind == Nodetype.ARRAY else 0
            if ekind == Nodetype.BASE and epayload[0] not in ("string", "wstring"):
                kwargs[name] = np.zeros(n, dtype=dtype(epayload[0]))
            elif ekind == Nodetype.BASE:
                kwargs[name] = [""] * n
            else:
                kwargs[name] = [_default(ts, epayload, {}) for _ in range(n)]
    return ts.types[msgtype](**kwargs)


def _nested(path: str, value: Any) -> dict[str, Any]:
    out: Any = value
    for part in reversed(path.split(".")):
        out = {part: out}
    return out


def _payload(ts: Any, msgtype: str, field: str, value: Any) -> bytes:
    leaf = _leaf(ts, msgtype, field)
    if leaf == "bool":
        value = bool(value)
    elif leaf.startswith("float"):
        value = float(value)
    else:
        value = int(value)
    msg = _default(ts, msgtype, _nested(field, value))
    return bytes(ts.serialize_cdr(msg, msgtype))


def _leaf(ts: Any, msgtype: str, field: str) -> str:
    *parents, last = field.split(".")
    for part in parents:
        msgtype = dict(ts.fielddefs[msgtype][1])[part][1]
    return str(dict(ts.fielddefs[msgtype][1])[last][1][0])


def write_rounds(
    path: Path,
    plan: Plan,
    messages: int,
    storage: str,
    *,
    violating: dict[str, Any] | None = None,
    every: int = VIOLATE_EVERY,
) -> int:
    """A bag of whole rounds of the plan's topics (the trigger last: one tick each),
    ``RECORDED_RATE`` msg/s apart; every ``every``-th round the ``violating`` values.
    Returns the messages written."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = _typestore()
    topics = plan.topics
    k = len(topics)
    nominal = [
        _payload(ts, t["msg"], t["field"] or "data", plan.nominal[t["name"]]) for t in topics
    ]
    bad = nominal
    if violating is not None:
        bad = [
            _payload(
                ts,
                t["msg"],
                t["field"] or "data",
                violating.get(t["name"], plan.nominal[t["name"]]),
            )
            for t in topics
        ]
    rounds = max(1, messages // k)
    step = 1_000_000_000 // RECORDED_RATE
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as w:
        # Fields of one topic are one connection (the daemon's subscriptions).
        by_topic: dict[str, Any] = {}
        for t in topics:
            if t["topic"] not in by_topic:
                by_topic[t["topic"]] = w.add_connection(t["topic"], t["msg"], typestore=ts)
        conns = [by_topic[t["topic"]] for t in topics]
        write = w.write
        t_ns = 1_000_000_000
        for r in range(rounds):
            data = bad if violating is not None and r % every == every - 1 else nominal
            for i in range(k):
                write(conns[i], t_ns, data[i])
                t_ns += step
    return rounds * k


def write_scans(path: Path, messages: int) -> int:
    """LaserScan messages with frame ids and ``ranges`` of varying length, so the
    offset of ``range_min`` (after the frame id) changes from message to message."""
    import numpy as np
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = _typestore()
    msgtype = "sensor_msgs/msg/LaserScan"
    variants = [
        bytes(
            ts.serialize_cdr(
                _default(
                    ts,
                    msgtype,
                    {
                        "header": {"frame_id": "laser" + "_" * i},
                        "range_min": 0.1 * (i + 1),
                        "range_max": 30.0,
                        "ranges": np.linspace(0.5, 10.0, i, dtype=np.float32),
                    },
                ),
                msgtype,
            )
        )
        for i in range(13)  # 13: a prime, so sizes do not repeat with the same period as rounds
    ]
    step = 1_000_000_000 // RECORDED_RATE
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/scan", msgtype, typestore=ts)
        write = w.write
        for i in range(messages):
            write(c, 1_000_000_000 + i * step, variants[i % len(variants)])
    return messages


def violating_state(plan: Plan) -> dict[str, Any] | None:
    """The latency experiment's violating state (state_req103) when the config has the
    sRobot's inputs, else None (then the violations case is left out)."""
    names = {t["name"] for t in plan.topics}
    return dict(SROBOT_VIOLATING) if set(SROBOT_VIOLATING) <= names else None


@contextmanager
def _tmpdir(where: Path | None) -> Iterator[Path]:
    d = Path(tempfile.mkdtemp(prefix="replay-", dir=where))
    try:
        yield d
    finally:
        shutil.rmtree(d, ignore_errors=True)


class _Case(NamedTuple):
    """One replay measured: its bag, the config replaying it, and how the bag is written."""

    label: str
    config: Path
    bag: Path
    fast: bool
    write: Callable[[Path], int]


def _cases(
    plan: Plan, messages: int, tmp: Path, scan_config: Path, violating: dict[str, Any] | None
) -> list[_Case]:
    """The cases in the order they run; the ``--exact`` one reuses the first bag."""
    cases = [
        _Case(
            "fixed-size, MCAP",
            plan.path,
            tmp / "fixed-mcap",
            True,
            lambda p: write_rounds(p, plan, messages, "mcap"),
        ),
        _Case(
            "fixed-size, sqlite3",
            plan.path,
            tmp / "fixed-sqlite3",
            True,
            lambda p: write_rounds(p, plan, messages, "sqlite3"),
        ),
    ]
    if violating is not None:
        cases += [
            _Case(
                f"violations every {VIOLATE_EVERY} ticks, MCAP",
                plan.path,
                tmp / "violations-mcap",
                True,
                lambda p: write_rounds(p, plan, messages, "mcap", violating=violating),
            ),
            _Case(
                f"violations every {VIOLATE_EVERY} ticks, sqlite3",
                plan.path,
                tmp / "violations-sqlite3",
                True,
                lambda p: write_rounds(p, plan, messages, "sqlite3", violating=violating),
            ),
        ]
    cases += [
        _Case(
            "--exact (message by message), MCAP",
            plan.path,
            tmp / "fixed-mcap",
            False,
            lambda p: 0,
        ),
        _Case(
            "variable-size (LaserScan range_min), MCAP",
            scan_config,
            tmp / "scan-mcap",
            True,
            lambda p: write_scans(p, messages),
        ),
    ]
    return cases


def _replay_case(case: _Case, messages: int, say: Callable[[str], None]) -> dict[str, Any]:
    """Writes the case's bag unless an earlier case did, replays it; its numbers."""
    from supervisor.tools.replay.session import replay_files

    label, config, bag, fast, write = case
    if not bag.exists():
        say(f"replay: writing {messages} messages ({label})")
        start = time.perf_counter()
        write(bag)
        written_s = time.perf_counter() - start
    else:
        written_s = None
    say(f"replay: {label}")
    r = replay_files(config, [bag], None, None, fast=fast)
    if r.get("error"):
        from supervisor.tools.bench.errors import BenchError

        raise BenchError(f"replay of {bag.name}: {r['error']}")
    return {
        "case": label,
        "storage": "sqlite3" if bag.name.endswith("-sqlite3") else "mcap",
        "config": str(config),
        "fast": fast,
        "messages": r["messages"],
        "ticks": r["ticks"],
        "violations": sum(q["violations"] for q in r["requirements"]),
        "seconds": r["seconds"],
        "rate": r["rate"],
        "bag_mb": _size(bag) / 1e6,
        "write_s": written_s,
    }


def replay_bench(
    plan: Plan,
    messages: int,
    say: Callable[[str], None],
    *,
    where: Path | None = None,
    min_seconds: float = 1.0,
) -> dict[str, Any]:
    """Every case's messages/s (the replay's own clock: reading, decoding and stepping,
    not compiling), and the monitor's ticks/s one by one and in batches."""
    out: dict[str, Any] = {"messages": messages, "recorded_rate": RECORDED_RATE, "cases": []}
    violating = violating_state(plan)
    with _tmpdir(where) as tmp:
        scan_config = tmp / "scan.yaml"
        scan_config.write_text(SCAN_CONFIG.replace("LOG", str(tmp / "scan-violations.jsonl")))
        for case in _cases(plan, messages, tmp, scan_config, violating):
            out["cases"].append(_replay_case(case, messages, say))
    out["by_storage"] = by_storage(out["cases"])
    say("replay: monitor ticks/s, tick() against tick_batch")
    out["monitor"] = monitor_rates(plan.path, min_seconds=min_seconds)
    return out


def by_storage(cases: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Messages/s of the bulk-stepping cases per storage (the two readers are separate
    code with separate goals, docs/BENCHMARKS.md): lowest, highest, case count."""
    out: dict[str, dict[str, float]] = {}
    for c in cases:
        if c["fast"]:
            rates = out.setdefault(c["storage"], {"min": c["rate"], "max": c["rate"], "cases": 0})
            rates["min"] = min(rates["min"], c["rate"])
            rates["max"] = max(rates["max"], c["rate"])
            rates["cases"] += 1
    return out


def monitor_rates(config: Path, *, min_seconds: float = 1.0) -> dict[str, float]:
    from monitors.backends.throughput import spec_rates
    from supervisor.tools.bench.monitor import spec_from_config

    return spec_rates(spec_from_config(config), min_seconds=min_seconds)


def _size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
