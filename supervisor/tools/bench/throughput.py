"""The throughput experiment: one publisher, the daemon and plain rclpy receivers
on the same stream, and the overhead of eq. 1 of the thesis."""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path
from typing import Any

from supervisor.tools.bench.errors import BenchError
from supervisor.tools.bench.plan import Plan
from supervisor.tools.bench.session import Helper, Session, cpu_seconds


def throughput(
    s: Session,
    plan: Plan,
    rate: float,
    seconds: float,
    naive: bool,
    *,
    burst: int = 0,
    wd_usec: int | None = None,
) -> dict[str, Any]:
    work = Path(tempfile.mkdtemp(prefix=f"throughput-{rate:g}-{burst}-", dir=s.tmp))
    config = plan.write_config(work / "config.yaml", work / "violations.jsonl", latency=False)
    spec = json.dumps(plan.topics)
    daemon = s.daemon(config, work, wd_usec)
    baselines = {
        "rclpy wait-set": s.child("rclpy wait-set", "waitset", "--spec", spec, workdir=work)
    }
    if naive:
        baselines["rclpy executor"] = s.child(
            "rclpy executor", "executor", "--spec", spec, workdir=work
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
        workdir=work,
    )
    everyone = (daemon, pub, *baselines.values())
    try:
        daemon.wait_ready(60)
        daemon.watch_pings()
        pub.wait_event("matched", 60, everyone)
        for b in baselines.values():
            b.wait_event("matched", 60, everyone)  # they see the publisher too
        pids = {"daemon": daemon.pid, **{k: b.pid for k, b in baselines.items()}}
        cpu0 = {k: cpu_seconds(p) for k, p in pids.items()}
        go = time.monotonic()
        pub.send("go")
        done = pub.wait_event("done", seconds * 4 + 30, everyone)
        sent: dict[str, int] = done["sent"]
        drained = _wait_drained(pub, baselines, sent, done["wall"], everyone)
        gap = daemon.longest_ping_gap(go, time.monotonic())
        cpu1 = {k: cpu_seconds(p) for k, p in pids.items()}
        daemon.stop_cleanly()
        stop = daemon.stop_record()
        received = {"daemon": {n: c["messages"] + c["rejected"] for n, c in stop["inputs"].items()}}
        counted_lost = sum(int(c.get("lost", 0)) for c in stop["inputs"].values())
        for name, b in baselines.items():
            b.stop()
            final = b.latest("final") or b.latest("counts")
            if final is None:
                raise BenchError(f"{name}: reported no counts")
            received[name] = final[1]["counts"]
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
        "daemon_counted_lost": counted_lost,
        "receivers": {},
    }
    for name, per_topic in received.items():
        n = sum(int(per_topic.get(t, 0)) for t in sent)
        cpu = cpu1[name] - cpu0[name]
        out["receivers"][name] = {
            "received": n,
            "received_per_topic": per_topic,
            "loss_pct": 100.0 * (total_sent - n) / total_sent,
            "msg_per_s": n / done["seconds"],
            "cpu_s": cpu,
            "cpu_us_per_msg": 1e6 * cpu / n if n else None,
        }
    fastest = max(baselines, key=lambda k: out["receivers"][k]["received"])
    p_standalone = out["receivers"][fastest]["msg_per_s"]
    p_monitor = out["receivers"]["daemon"]["msg_per_s"]
    out["fastest_baseline"] = fastest
    # Eq. 1 of the thesis; the publishing window is the same for both receivers.
    out["overhead_pct"] = 100.0 * (p_standalone - p_monitor) / p_monitor if p_monitor else None
    return out


def _wait_drained(
    pub: Helper,
    baselines: dict[str, Helper],
    sent: dict[str, int],
    done_wall: float,
    everyone: tuple[Helper, ...],
    timeout: float = 30.0,
) -> bool:
    """Until every receiver's counts stop increasing (or equal what was sent).
    The daemon's come from its /diagnostics reports (1 Hz) published after the
    publisher finished, relayed by the publisher process."""
    deadline = time.monotonic() + timeout
    quiet = 0.5  # a baseline reports every 0.1 s: five equal reports
    last: dict[str, tuple[dict[str, int], float]] = {}
    while time.monotonic() < deadline:
        for c in everyone:
            c.check()
        ok = True
        diags = [ev for ev in pub.events("diag") if ev["stamp"] > done_wall]
        if not (
            diags
            and (
                diags[-1]["counts"] == sent
                or (len(diags) >= 2 and diags[-1]["counts"] == diags[-2]["counts"])
            )
        ):
            ok = False
        now = time.monotonic()
        for name, b in baselines.items():
            got = b.latest("counts")
            if got is None:
                ok = False
                continue
            counts = got[1]["counts"]
            prev = last.get(name)
            if prev is None or prev[0] != counts:
                last[name] = (counts, now)
            if counts != sent and now - last[name][1] < quiet:
                ok = False
        if ok:
            return True
        time.sleep(0.05)  # polling interval
    return False
