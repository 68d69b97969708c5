"""The throughput experiment: one publisher, the daemon and plain rclpy receivers
on the same stream, and the overhead of eq. 1 of the thesis."""

from __future__ import annotations

import json
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from supervisor.tools.bench.errors import BenchError
from supervisor.tools.bench.plan import Plan
from supervisor.tools.bench.session import Daemon, Helper, Session, cpu_seconds


def throughput(
    s: Session,
    plan: Plan,
    rate: float,
    seconds: float,
    naive: bool,
    *,
    burst: int = 0,
    wd_usec: int | None = None,
    record: bool = False,
    on_go: Callable[[float], None] | None = None,
    before_stop: Callable[[], None] | None = None,
    on_ready: Callable[[int], None] | None = None,
    ready_timeout: float = 60.0,
) -> dict[str, Any]:
    """One run; ``record``: the daemon runs with ``--record DIR`` (in the run's dir);
    ``on_go``: called with the monotonic time the publisher was told to go, so another
    experiment can act during the publishing (the UI experiment kills its UI halfway);
    it must not block, the publisher's ``done`` is waited for after it; ``before_stop``:
    called once the receivers drained and the CPU figures were read, before the daemon
    is stopped (the UI experiment waits there for what the daemon still publishes);
    ``on_ready``: called with the daemon's pid once it is ready, before the receivers
    match (``bench --scale`` and ``--soak`` read its memory from there); ``ready_timeout``:
    how long its start may take (it builds its monitor: minutes for a large set)."""
    work = Path(tempfile.mkdtemp(prefix=f"throughput-{rate:g}-{burst}-", dir=s.tmp))
    config = plan.write_config(work / "config.yaml", work / "violations.jsonl", latency=False)
    record_dir = work / "record"
    extra = ("--record", str(record_dir)) if record else ()
    daemon = s.daemon(config, work, wd_usec, extra)
    baselines, pub = _start_clients(s, plan, work, rate, seconds, naive=naive, burst=burst)
    everyone = (daemon, pub, *baselines.values())
    try:
        _ready_and_matched(daemon, pub, baselines, ready_timeout, on_ready)
        pids = {"daemon": daemon.pid, **{k: b.pid for k, b in baselines.items()}}
        cpu0 = {k: cpu_seconds(p) for k, p in pids.items()}
        go = time.monotonic()
        pub.send("go")
        if on_go is not None:
            on_go(go)
        done = pub.wait_event("done", seconds * 4 + 30, everyone)
        sent: dict[str, int] = done["sent"]
        drained = _wait_drained(pub, baselines, sent, done["wall"], everyone)
        gap = daemon.longest_ping_gap(go, time.monotonic())
        cpu1 = {k: cpu_seconds(p) for k, p in pids.items()}
        if before_stop is not None:
            before_stop()
        cpu_exit = daemon.stop_cleanly()
        stop = daemon.stop_record()
        closed = _record_closed(daemon.records()) if record else None
        received = {"daemon": {n: c["messages"] + c["rejected"] for n, c in stop["inputs"].items()}}
        received.update(_stopped_baselines(baselines))
    finally:
        for c in everyone:
            c.kill()
    total_sent = sum(sent.values())
    out: dict[str, Any] = {
        "offered": rate,
        "seconds": done["seconds"],
        "sent": total_sent,
        "sent_per_topic": sent,
        "achieved": done["achieved"],
        "drained": drained,
        "daemon_violations": stop.get("violations"),
        "burst": burst,
        "watchdog_usec": wd_usec,
        "longest_ping_gap_ms": None if gap is None else 1000 * gap,
        "daemon_counted_lost": sum(int(c.get("lost", 0)) for c in stop["inputs"].values()),
        "daemon_loss": daemon_loss(sent, stop["inputs"]),
        "record": None,
    }
    if record:
        on_disk = sum(p.stat().st_size for p in record_dir.rglob("*") if p.is_file())
        out["record"] = {**(closed or {}), "mb_on_disk": on_disk / 1e6}
    out["receivers"] = _receivers(received, sent, done["seconds"], cpu0, cpu1)
    _add_cpu_to_exit(out["receivers"]["daemon"], cpu_exit - cpu0["daemon"])
    _overhead(out, list(baselines))
    return out


def _ready_and_matched(
    daemon: Daemon,
    pub: Helper,
    baselines: dict[str, Helper],
    ready_timeout: float,
    on_ready: Callable[[int], None] | None,
) -> None:
    """Waits for the daemon to be ready (its pings watched from then) and for the
    publisher and every baseline to match."""
    everyone = (daemon, pub, *baselines.values())
    daemon.wait_ready(ready_timeout)
    if on_ready is not None:
        on_ready(daemon.pid)
    daemon.watch_pings()
    pub.wait_event("matched", 60, everyone)
    for b in baselines.values():
        b.wait_event("matched", 60, everyone)  # they see the publisher too


def _stopped_baselines(baselines: dict[str, Helper]) -> dict[str, dict[str, Any]]:
    """Stops the baseline receivers; each one's last counts by topic."""
    received: dict[str, dict[str, Any]] = {}
    for name, b in baselines.items():
        b.stop()
        final = b.latest("final") or b.latest("counts")
        if final is None:
            raise BenchError(f"{name}: reported no counts")
        received[name] = final[1]["counts"]
    return received


def _add_cpu_to_exit(d: dict[str, Any], cpu_s_to_exit: float) -> None:
    """The daemon's CPU up to its exit: its shutdown too (the recorder's last writes)."""
    d["cpu_s_to_exit"] = cpu_s_to_exit
    n = d["received"]
    d["cpu_us_per_msg_to_exit"] = 1e6 * d["cpu_s_to_exit"] / n if n else None


def _receivers(
    received: dict[str, dict[str, Any]],
    sent: dict[str, int],
    seconds: float,
    cpu0: dict[str, float],
    cpu1: dict[str, float],
) -> dict[str, dict[str, Any]]:
    """Each receiver's count, loss, rate and CPU over the publishing window."""
    total_sent = sum(sent.values())
    out = {}
    for name, per_topic in received.items():
        n = sum(int(per_topic.get(t, 0)) for t in sent)
        cpu = cpu1[name] - cpu0[name]
        out[name] = {
            "received": n,
            "received_per_topic": per_topic,
            "loss_pct": 100.0 * (total_sent - n) / total_sent,
            "msg_per_s": n / seconds,
            "cpu_s": cpu,
            "cpu_us_per_msg": 1e6 * cpu / n if n else None,
        }
    return out


def _start_clients(
    s: Session,
    plan: Plan,
    work: Path,
    rate: float,
    seconds: float,
    *,
    naive: bool,
    burst: int,
) -> tuple[dict[str, Helper], Helper]:
    """The plain rclpy receivers (by name) and the publisher, started."""
    spec = json.dumps(plan.topics)
    # The baselines take the scan too (bench --scan), as the daemon does.
    scan = plan.scan
    keys = ("name", "topic", "msg", "field")
    everything = json.dumps([*plan.topics, {k: scan[k] for k in keys}]) if scan else spec
    baselines = {
        "rclpy wait-set": s.child("rclpy wait-set", "waitset", "--spec", everything, workdir=work)
    }
    if naive:
        baselines["rclpy executor"] = s.child(
            "rclpy executor", "executor", "--spec", everything, workdir=work
        )
    pub = s.child(
        "publisher",
        "publisher",
        "--spec",
        spec,
        "--values",
        json.dumps(plan.nominal),
        "--rate",
        str(rate),
        "--seconds",
        str(seconds),
        "--receivers",
        str(1 + len(baselines)),
        "--diagnostics",
        "--daemon-node",
        plan.daemon_node,
        "--burst",
        str(burst),
        *(("--scan", json.dumps(scan)) if scan else ()),
        workdir=work,
    )
    return baselines, pub


def _overhead(out: dict[str, Any], baselines: list[str]) -> None:
    """Eq. 1 of the thesis against the fastest plain receiver; the publishing window
    is the same for every receiver."""
    fastest = max(baselines, key=lambda k: out["receivers"][k]["received"])
    p_standalone = out["receivers"][fastest]["msg_per_s"]
    p_monitor = out["receivers"]["daemon"]["msg_per_s"]
    out["fastest_baseline"] = fastest
    out["overhead_pct"] = 100.0 * (p_standalone - p_monitor) / p_monitor if p_monitor else None


def daemon_summary(row: dict[str, Any]) -> dict[str, Any]:
    """The daemon's figures of one :func:`throughput` run that every part reports:
    what was sent and received, lost (and counted lost), violations, CPU, ping gap."""
    d = row["receivers"]["daemon"]
    return {
        "sent": row["sent"],
        "achieved": row["achieved"],
        "received": d["received"],
        "lost": row["sent"] - d["received"],
        "loss_pct": d["loss_pct"],
        "counted_lost": row["daemon_counted_lost"],
        "violations": row["daemon_violations"],
        "drained": row["drained"],
        "cpu_us_per_msg": d["cpu_us_per_msg"],
        "longest_ping_gap_ms": row["longest_ping_gap_ms"],
    }


def _record_closed(records: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The numbers of the daemon's ``record_closed`` record (written, dropped, ...)."""
    for r in reversed(records):
        if r.get("event") == "supervisor" and r.get("what") == "record_closed":
            keys = ("written", "dropped", "skipped", "lost", "bags")
            return {k: r.get(k) for k in keys}
    return None


# A receiver's counts must stay unchanged this long before what it has not taken is
# taken for lost. A reliable reader that missed samples gets them again only after
# the writer's next heartbeat (Fast DDS: every 3 s by default), and meanwhile holds
# back every later sample: under a flood the daemon's counts were measured flat for
# 2 s, then up by a thousand (docs/reference/commands.md#bench).
QUIET_S = 5.0


def _wait_drained(
    pub: Helper,
    baselines: dict[str, Helper],
    sent: dict[str, int],
    done_wall: float,
    everyone: tuple[Helper, ...],
    timeout: float = 30.0,
) -> bool:
    """Until every receiver has taken all that was sent, or its counts stayed the
    same for QUIET_S. The daemon's come from its /diagnostics reports (1 Hz)
    published after the publisher finished, relayed by the publisher process;
    taken + counted lost == sent also ends its wait (nothing more can come)."""
    deadline = time.monotonic() + timeout
    changed: dict[str, tuple[Any, float]] = {}

    def quiet(name: str, counts: Any, now: float) -> bool:
        prev = changed.get(name)
        if prev is None or prev[0] != counts:
            changed[name] = prev = (counts, now)
        return now - prev[1] >= QUIET_S

    while time.monotonic() < deadline:
        for c in everyone:
            c.check()
        now = time.monotonic()
        ok = True
        diags = [ev for ev in pub.events("diag") if ev["stamp"] > done_wall]
        if not diags:
            ok = False
        else:
            got, lost = diags[-1]["counts"], diags[-1].get("lost", {})
            accounted = all(got.get(t, 0) + lost.get(t, 0) >= n for t, n in sent.items())
            if not accounted and not quiet("daemon", (got, lost), now):
                ok = False
        for name, b in baselines.items():
            latest = b.latest("counts")
            if latest is None:
                ok = False
                continue
            counts = latest[1]["counts"]
            if counts != sent and not quiet(name, counts, now):
                ok = False
        if ok:
            return True
        time.sleep(0.05)  # polling interval
    return False


def daemon_loss(sent: dict[str, int], inputs: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """What the daemon did not take (sent - received), per category, from its ``stop``
    record: ``gaps`` (counted lost: gaps in a publisher's sequence numbers),
    ``before_first`` (numbers below the first one heard, not counted by the daemon:
    they may predate the match; the bench's publisher starts after matching, so
    here they are lost) and ``after_last`` (above the last one heard: no later
    number reveals them; docs/reference/ros-interfaces.md#lost-messages). The bench
    publishes each topic from one writer numbered from 1, so the categories add up
    to sent - received exactly; ``agree`` says they did."""
    total = {"missing": 0, "gaps": 0, "before_first": 0, "after_last": 0}
    per_topic: dict[str, dict[str, int]] = {}
    agree = True
    for name, n in sent.items():
        st = inputs.get(name, {})
        streams = st.get("by_publisher") or []
        row = {
            "missing": n - int(st.get("messages", 0)) - int(st.get("rejected", 0)),
            "gaps": int(st.get("lost", 0)),
            # Nothing heard: every message is above the last number heard (none, 0).
            "before_first": min((int(p["first"]) for p in streams), default=1) - 1,
            "after_last": n - max((int(p["last"]) for p in streams), default=0),
        }
        cats = row["gaps"] + row["before_first"] + row["after_last"]
        if cats != row["missing"] or min(row.values()) < 0:
            agree = False
        per_topic[name] = row
        for k, v in row.items():
            total[k] += v
    return {**total, "agree": agree, "per_topic": per_topic}
