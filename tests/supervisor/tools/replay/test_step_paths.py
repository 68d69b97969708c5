"""One truth for the step policies: the daemon's core, ``replay --exact`` and
replay's fast path decide alike (docs/ARCHITECTURE.md, "where to add a step policy").

Hypothesis draws a step policy with its settings, the requirements' mitigation
policies, and a stream of messages (quiet stretches, silences that turn inputs
stale, NaNs, values a type cannot hold, violations, a topic that carries two
inputs).  The same stream goes

- to the daemon's monitoring core in this process, message by message as the
  receive loop hands them on, with the loop waking at random times as well;
- through ``replay`` of a real MCAP bag, message by message (``--exact``);
- through ``replay``'s fast path (quiet stretches in bulk, ``Runtime.step_rows``);

each with the real compiled monitor, and every record the three write (content and
logical time) must be the same.  The fast path must really have taken rows in bulk
for the message-driven policies, or the property would prove nothing.
"""

from __future__ import annotations

import calendar
import random
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from mitigations.violationlog.reader import iter_records
from mitigations.violationlog.writer import ViolationLog
from supervisor.daemon.core import Core
from supervisor.daemon.runtime import MESSAGE_POLICIES
from supervisor.tools.replay.engine import DryRun
from supervisor.tools.replay.session import loaded, replay_files

TS = get_typestore(Stores.ROS2_JAZZY)
MS = 1_000_000
T0 = 1_700_000_000 * 10**9  # a plausible receive time: records carry it as a date

TYPES = {
    "/speed": "std_msgs/msg/Float64",
    "/count": "std_msgs/msg/UInt64",
    "/cmd": "geometry_msgs/msg/Twist",
}
FIELDS = {"/speed": ["speed"], "/count": ["count"], "/cmd": ["vx", "wz"]}

CONFIG = """\
component: R
step: {step}
variables:
  speed: {{type: double, topic: /speed, msg: std_msgs/msg/Float64}}
  count: {{type: int64, topic: /count, msg: std_msgs/msg/UInt64}}
  vx:    {{type: double, topic: /cmd, msg: geometry_msgs/msg/Twist, field: linear.x}}
  wz:    {{type: double, topic: /cmd, msg: geometry_msgs/msg/Twist, field: angular.z}}
requirements:
  - id: limit
    text: R shall always satisfy speed <= 2.0
    on_violation: [note]
    policy: {p0}
  - id: counting
    text: R shall always satisfy count < 1000
    on_violation: [note]
    policy: {p1}
  - id: turn
    text: upon speed > 1.9 R shall within 3 ticks satisfy wz < 0.5 | vx < -0.9
    on_violation: [note]
    policy: {p2}
on_stale: [note]
mitigations:
  note: {{log: {{message: violated}}}}
"""

# (policy, its step: section without the closing brace)
STEPS = st.one_of(
    st.builds(
        lambda p: ("periodic", f"{{policy: periodic, period_ms: {p}"), st.sampled_from([3, 5, 10])
    ),
    st.just(("on_message", "{policy: on_message")),
    st.builds(
        lambda v: ("on_trigger", f"{{policy: on_trigger, trigger: {v}"),
        st.sampled_from(["speed", "count", "wz"]),
    ),
    st.builds(
        lambda k: ("synchronized", "{policy: synchronized" + (f", max_skew_ms: {k}" if k else "")),
        st.sampled_from([None, 4, 15]),
    ),
)
STALE = st.sampled_from(["}", ", stale_after_ms: 40}", ", stale_after_ms: 120}"])
POLICIES = st.sampled_from(
    [
        "{}",
        "{reset: after_mitigation}",
        "{debounce_steps: 2, reset: after_mitigation}",
        "{debounce_steps: 3, debounce_ms: 4, cooldown_ms: 50, reset: after_mitigation}",
        "{latch: true, repeat_ms: 40}",
        "{reset: {after_ms: 30}}",
        "{escalate: {after_ms: 20, actions: [note]}, reset: after_mitigation}",
        "{confirm: {variable: wz, equals: 0.0, within_ms: 15}, reset: after_mitigation}",
    ]
)


def stream(seed: int, segments: list[str]) -> list[tuple[int, str, Any]]:
    """Messages ``(t, topic, value)``: every topic once, then one stretch per
    segment (``quiet``: values within bounds at short gaps but for one pause
    near a silence limit, now and then; ``calm``: a quiet stretch of 200 without
    the pause, longer than the fast path's least stretch; ``noisy``: violations,
    NaNs, a count too big for int64, silences)."""
    rng = random.Random(seed)
    t = T0
    out: list[tuple[int, str, Any]] = []

    def calm(topic: str) -> Any:
        if topic == "/speed":
            return round(rng.uniform(0.0, 1.8), 2)
        if topic == "/count":
            return rng.randint(0, 900)
        return (round(rng.uniform(-1, 1), 2), round(rng.uniform(-1, 0.4), 2))

    for topic in TYPES:
        t += rng.randint(1, 3) * MS // 2
        out.append((t, topic, calm(topic)))
    for kind in segments:
        # rounds in a random order each: in a quiet stretch no input falls silent
        # for longer than a few messages
        rounds = [rng.sample(["/speed", "/speed", "/count", "/cmd"], 4) for _ in range(40)]
        length = 200 if kind == "calm" else rng.randint(70, 160)
        # a pause near a silence limit (stale_after_ms 40 or 120), within a ns
        pause = None if kind == "calm" else rng.choice([None, rng.randrange(length)])
        for k in range(length):
            t += rng.randint(1, 8) * MS // 2 + rng.randint(0, 999)
            if k == pause:
                t += rng.choice([35, 40, 80, 120, 150]) * MS + rng.randint(-1, 1)
            topic = rounds[k // 4 % 40][k % 4] if kind != "noisy" else rng.choice(rounds[0])
            value = calm(topic)
            if kind == "noisy":
                if rng.random() < 0.03:
                    t += 150 * MS  # a silence: inputs go stale
                r = rng.random()
                if topic == "/speed" and r < 0.04:
                    value = float("nan")
                elif topic == "/speed" and r < 0.3:
                    value = round(rng.uniform(1.8, 2.3), 2)
                elif topic == "/count" and r < 0.05:
                    value = 2**64 - 1  # not an int64: rejected
                elif topic == "/count" and r < 0.3:
                    value = rng.randint(950, 1100)
                elif topic == "/cmd" and r < 0.4:
                    value = (value[0], round(rng.uniform(0.3, 1.0), 2))
            out.append((t, topic, value))
    return out


def values(topic: str, value: Any) -> list[tuple[str, Any]]:
    """The inputs one message sets, as the daemon's receive loop reads them."""
    return list(zip(FIELDS[topic], value if topic == "/cmd" else (value,), strict=True))


def write_bag(path: Path, msgs: list[tuple[int, str, Any]]) -> Path:
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {t: w.add_connection(t, ty, typestore=TS) for t, ty in TYPES.items()}
        for t, topic, value in msgs:
            cls = TS.types[TYPES[topic]]
            if topic == "/cmd":
                v3 = TS.types["geometry_msgs/msg/Vector3"]
                msg = cls(linear=v3(x=value[0], y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=value[1]))
            else:
                msg = cls(data=value)
            w.write(conns[topic], t, bytes(TS.serialize_cdr(msg, TYPES[topic])))
    return path


class Timed:
    """The core's log, each record written with the logical time it was made at
    (replay writes that time as ``recorded_ts``)."""

    def __init__(self, out: ViolationLog) -> None:
        self.out = out
        self.core: Core | None = None

    def _t(self) -> int:
        assert self.core is not None and self.core.now is not None
        return self.core.now

    def violation(self, requirement: str, **f: Any) -> bool:
        return self.out.violation(requirement, at_ns=self._t(), **f)

    def mitigation(self, requirement: str, **f: Any) -> bool:
        return self.out.mitigation(requirement, at_ns=self._t(), **f)

    def reset(self, requirement: str, *, reason: str, **extra: Any) -> bool:
        return self.out.reset(requirement, reason=reason, at_ns=self._t(), **extra)

    def supervisor(self, what: str, **f: Any) -> bool:
        return self.out.supervisor(what, at_ns=self._t(), **f)


def daemon(
    config: Path, msgs: list[tuple[int, str, Any]], wakes: list[int], path: Path
) -> tuple[int, list[dict[str, Any]]]:
    """The daemon's core fed ``msgs`` as its receive loop feeds it (the loop also
    wakes at ``wakes``); (ticks, records)."""
    with loaded(config) as session:
        cfg = session.config
        out = ViolationLog(
            path, cfg.component, cfg.sha256, echo=False, fsync=False, durability=cfg.log_durability
        )
        log = Timed(out)
        core = log.core = Core(session, log, DryRun(log, cfg), warn=lambda _text: None)
        core.start(msgs[0][0])
        pending = sorted(wakes)
        for t, topic, value in msgs:
            while pending and pending[0] <= t:
                core.advance(pending.pop(0))
            core.fields(values(topic, value), t)
        core.advance(msgs[-1][0])  # replay's end: the last message's time
        out.close()
        return session.runtime.tick, records(path)


def records(path: Path) -> list[dict[str, Any]]:
    """Each record's content and logical time; not the writing's own (ts, chain)."""
    drop = ("ts", "_ts", "prev_sha256", "seq", "line_sha256", "dry_run", "recorded_ts")
    out = []
    for r in iter_records(str(path)):
        if r.get("what") == "replay":
            continue  # replay's own first record
        stamp = r.get("recorded_ts")
        if stamp is not None:  # YYYY-mm-ddTHH:MM:SS.nnnnnnnnnZ, replay's logical time
            seconds = calendar.timegm(time.strptime(stamp[:19], "%Y-%m-%dT%H:%M:%S"))
            r["at_ns"] = seconds * 10**9 + int(stamp[20:29])
        out.append({k: v for k, v in r.items() if k not in drop})
    return out


@contextmanager
def bulk_rows() -> Iterator[list[int]]:
    """The rows ``Core.rows`` takes in bulk while in the block (a spy that calls
    through: the stepping is the real one)."""
    taken: list[int] = []
    real = Core.rows

    def spy(self: Core, rows: Any, **kw: Any) -> int:
        n = real(self, rows, **kw)
        taken.append(n)
        return n

    Core.rows = spy  # type: ignore[method-assign]
    try:
        yield taken
    finally:
        Core.rows = real  # type: ignore[method-assign]


@pytest.mark.slow
@settings(
    max_examples=40,
    phases=[Phase.explicit, Phase.reuse, Phase.generate, Phase.shrink],
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(
    step=STEPS,
    stale=STALE,
    policies=st.lists(POLICIES, min_size=3, max_size=3),
    seed=st.integers(0, 2**32),
    segments=st.lists(st.sampled_from(["quiet", "noisy"]), min_size=1, max_size=4),
    wake_seed=st.integers(0, 2**32),
)
def test_daemon_exact_and_fast_replay_write_the_same_records(
    tmp_path_factory, step, stale, policies, seed, segments, wake_seed
):
    d = tmp_path_factory.mktemp("paths")
    config = d / "c.yaml"
    policy, text = step
    config.write_text(
        CONFIG.format(step=text + stale, p0=policies[0], p1=policies[1], p2=policies[2])
    )
    # a calm stretch first: a quiet one can be too short, or paused too early, for
    # the fast path's least stretch (fast.MIN_STRETCH), and then it rightly takes none
    msgs = stream(seed, ["calm", *segments])
    bag = write_bag(d / "bag", msgs)
    rng = random.Random(wake_seed)
    wakes = sorted(rng.randint(msgs[0][0], msgs[-1][0]) for _ in range(rng.randint(0, 200)))

    ticks, online = daemon(config, msgs, wakes, d / "daemon.jsonl")
    exact = replay_files(config, [bag], d / "exact.jsonl", None, fast=False)
    with bulk_rows() as taken:
        fast = replay_files(config, [bag], d / "fast.jsonl", None, fast=True)
    assert exact["error"] is None and fast["error"] is None
    assert exact["messages"] == fast["messages"] == len(msgs)

    assert records(d / "exact.jsonl") == online
    assert records(d / "fast.jsonl") == online
    assert exact["ticks"] == fast["ticks"] == ticks
    if policy in MESSAGE_POLICIES:
        assert sum(taken) > 0, "the fast path stepped nothing in bulk"
    else:
        assert sum(taken) == 0
