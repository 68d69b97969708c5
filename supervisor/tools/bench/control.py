"""Soak of the control socket: random hostile clients for minutes while an operator's
reset must be answered within 1 s throughout.

``python -m supervisor.tools.bench.control [--minutes 10] [--clients 16] [CONFIG]``
starts ``safety-supervisor run`` (sRobot by default, its control socket in the
bench's temp dir, the watchdog on) and runs ``--clients`` threads, each opening
connection after connection of a random kind: random bytes, deep JSON, over-long
lines, partial lines, idle and slow clients, bursts of connections, resets with
bad fields and valid resets.  Every ``--probe-ms`` the operator's reset is sent
with the ``reset`` command's own client; its latency is timed and anything but an
answer within 1 s is a miss.  Reported as one JSON object: resets probed,
answered, missed, latency percentiles, attack connections by kind, the daemon's
RSS and descriptors at start and end, the longest gap between watchdog pings, and
whether the daemon's log verifies and its control socket never failed.
docs/reference/ros-interfaces.md, "Control socket".
"""

from __future__ import annotations

import argparse
import json
import random
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from supervisor import data
from supervisor.tools.bench.numbers import percentiles
from supervisor.tools.bench.scale import fd_count, proc_memory
from supervisor.tools.bench.session import session
from supervisor.tools.reset import request

ANSWER_LIMIT_S = 1.0  # what an operator's reset must never exceed
KINDS = ("bytes", "deep", "long", "partial", "idle", "slow", "burst", "fields", "reset")


def _attack(sock: str, kind: str, rnd: random.Random) -> str:
    """One hostile connection (several for ``burst``); the outcome's name."""
    conns: list[socket.socket] = []
    try:
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        conns.append(s)
        s.settimeout(10)
        s.connect(sock)
        if kind == "bytes":
            s.sendall(rnd.randbytes(rnd.randint(1, 8000)))
        elif kind == "deep":
            s.sendall(rnd.choice([b"[", b'{"a":']) * rnd.randint(100, 50000) + b"\n")
        elif kind == "long":
            s.sendall(b'{"command": "reset", "via": "' + b"v" * rnd.randint(4000, 200000))
        elif kind == "partial":
            s.sendall(b'{"command": "re')
            s.shutdown(socket.SHUT_WR)
        elif kind == "idle":
            time.sleep(rnd.uniform(0.1, 3.0))  # holds a connection, says nothing
        elif kind == "slow":
            for b in b'{"command": "reset"}\n':
                s.sendall(bytes([b]))
                time.sleep(rnd.uniform(0.05, 0.3))
        elif kind == "burst":
            for _ in range(rnd.randint(10, 100)):
                c = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                conns.append(c)
                c.settimeout(10)
                c.connect(sock)
        elif kind == "fields":
            field = rnd.choice(["command", "requirement", "via", "client", "x"])
            value = rnd.choice([None, 1, [1], {"a": 1}, "\x1b[2J", "r" * 300, True])
            s.sendall(json.dumps({"command": "reset", field: value}).encode() + b"\n")
        else:
            s.sendall(b'{"command": "reset", "via": "soak"}\n')
        s.recv(65536)
        return "answered_or_closed"
    except TimeoutError:
        return "client_timeout"
    except OSError as e:
        return type(e).__name__
    finally:
        for c in conns:
            c.close()


def soak(config: Path, minutes: float, clients: int, probe_ms: int) -> dict[str, Any]:
    with session(None) as s:
        work = s.tmp / "daemon"
        work.mkdir()
        sock = str(work / "c.sock")
        cfg = work / "soak.yaml"
        cfg.write_text(config.read_text().rstrip("\n") + f"\ncontrol:\n  socket: {sock}\n")
        d = s.daemon(cfg, work, watchdog_usec=2_000_000)
        d.wait_ready(120)
        d.watch_pings()
        start_mem, start_fds = proc_memory(d.pid), fd_count(d.pid)
        stop = threading.Event()
        outcomes: Counter[str] = Counter()
        lock = threading.Lock()

        def attacker(seed: int) -> None:
            rnd = random.Random(seed)
            while not stop.is_set():
                kind = rnd.choice(KINDS)
                result = _attack(sock, kind, rnd)
                with lock:
                    outcomes[f"{kind}:{result}"] += 1

        threads = [
            threading.Thread(target=attacker, args=(i,), daemon=True) for i in range(clients)
        ]
        t0 = time.monotonic()
        for t in threads:
            t.start()
        latencies: list[float] = []
        answers: Counter[str] = Counter()
        misses: list[str] = []
        end = t0 + minutes * 60
        peak_rss = 0
        while time.monotonic() < end:
            p0 = time.monotonic()
            try:
                answer = request(sock, {"command": "reset", "via": "operator"}, 5.0)
            except UserError as e:
                misses.append(str(e))
            else:
                took = time.monotonic() - p0
                latencies.append(took)
                answers["accepted" if answer["ok"] else str(answer.get("refused"))] += 1
                if took > ANSWER_LIMIT_S:
                    misses.append(f"answered after {took:.3f} s")
            peak_rss = max(peak_rss, proc_memory(d.pid)["rss_kb"] or 0)
            stop.wait(max(0.0, probe_ms / 1000 - (time.monotonic() - p0)))
        stop.set()
        for t in threads:
            t.join(15)
        end_mem, end_fds = proc_memory(d.pid), fd_count(d.pid)
        ping_gap = d.longest_ping_gap(t0, time.monotonic())
        d.stop_cleanly()
        records = d.records()
        verify = subprocess.run(
            [sys.executable, "-m", "supervisor", "logs", "--verify", str(d.log)],
            capture_output=True,
            text=True,
            timeout=120,
        )
        refused: Counter[str] = Counter()
        for r in records:
            if r.get("what") == "reset_refused":
                refused.update(r["refused"])
        lat = percentiles(latencies)
        return {
            "minutes": minutes,
            "attackers": clients,
            "probes": len(latencies) + sum(1 for m in misses if not m.startswith("answered")),
            "answered": len(latencies),
            "answers": dict(answers),
            "missed": len(misses),
            "misses": misses[:10],
            "latency_ms": {k: None if v is None else round(v * 1000, 2) for k, v in lat.items()},
            "attack_connections": sum(outcomes.values()),
            "attack_outcomes": dict(sorted(outcomes.items())),
            "refused_summarised": dict(refused),
            "resets_recorded": sum(1 for r in records if r.get("event") == "reset"),
            "control_failed": sum(1 for r in records if r.get("what") == "control_failed"),
            "rss_kb": {"start": start_mem["rss_kb"], "end": end_mem["rss_kb"], "peak": peak_rss},
            "fds": {"start": start_fds, "end": end_fds},
            "longest_ping_gap_s": None if ping_gap is None else round(ping_gap, 3),
            "log_verifies": verify.returncode == 0,
        }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m supervisor.tools.bench.control")
    p.add_argument("config", nargs="?", type=Path, default=data.example("srobot.yaml"))
    p.add_argument("--minutes", type=float, default=10.0)
    p.add_argument("--clients", type=int, default=16, help="attacking threads (default 16)")
    p.add_argument("--probe-ms", type=int, default=250, help="operator reset period")
    args = p.parse_args(argv)
    result = soak(args.config, args.minutes, args.clients, args.probe_ms)
    print(json.dumps(result, indent=2))
    ok = result["missed"] == 0 and result["log_verifies"] and not result["control_failed"]
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
