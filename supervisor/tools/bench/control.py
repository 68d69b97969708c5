"""Soak of the control socket: random hostile clients for minutes while an operator's
reset must be answered within 1 s throughout.

``python -m supervisor.tools.bench.control [--minutes 10] [--clients 16]
[--http-clients 16] [--no-ui] [CONFIG]`` starts ``safety-supervisor run`` (sRobot by default, its control socket in the
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

Unless ``--no-ui``, the same run also starts ``safety-supervisor ui`` on the
daemon's control socket and domain and attacks its HTTP port with
``--http-clients`` threads (:mod:`supervisor.tools.bench.httpsoak`), while the
operator's reset is also sent the page's way every 250-500 ms: an HTTP answer
within 1 s, relayed from the daemon, and one ``reset`` record with ``via: ui`` per
reset the daemon took.  Both processes must stay alive, print no traceback, and
the summary has their memory and descriptors before and after.
docs/BENCHMARKS.md, "Control socket and UI soak".
"""

from __future__ import annotations

import argparse
import http.client
import json
import random
import socket
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from supervisor import children, data
from supervisor.config.load import load_config
from supervisor.tools.bench.errors import BenchError
from supervisor.tools.bench.httpsoak import HTTP_KINDS, Attacker, SoakUi, listen_overflows
from supervisor.tools.bench.numbers import percentiles
from supervisor.tools.bench.scale import fd_count, proc_memory
from supervisor.tools.bench.session import Daemon, Session, session
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


def _ms(values: list[float]) -> dict[str, float | None]:
    return {k: None if v is None else round(v * 1000, 2) for k, v in percentiles(values).items()}


def _tracebacks(path: Path) -> int:
    try:
        return path.read_text(errors="replace").count("Traceback")
    except OSError:
        return 0


class HttpProbe:
    """The operator's reset through the UI every 250-500 ms, on a thread of its own:
    ``{}`` or ``{"requirement": ID}`` as the page sends them, timed to its answer."""

    def __init__(self, ui: SoakUi, requirements: list[str], stop: threading.Event) -> None:
        self.ui = ui
        self.requirements = requirements
        self.stop = stop
        self.latencies: list[float] = []
        self.answers: Counter[str] = Counter()
        self.misses: list[str] = []
        self.sent = 0
        self.thread = threading.Thread(target=self._run, name="http-probe", daemon=True)

    def _run(self) -> None:
        rnd = random.Random(1)
        while not self.stop.is_set():
            body = rnd.choice([{}, {"requirement": rnd.choice(self.requirements)}])
            p0 = time.monotonic()
            self.sent += 1
            try:
                status, answer = self.ui.reset(body, 5.0)
            except (OSError, http.client.HTTPException, ValueError) as e:
                self.misses.append(f"{type(e).__name__}: {e}")
            else:
                took = time.monotonic() - p0
                message = str(answer.get("message", ""))
                if status != 200:
                    self.misses.append(f"HTTP {status}: {message}")
                else:
                    self.latencies.append(took)
                    self.answers[_kind(answer.get("ok") is True, message)] += 1
                    if took > ANSWER_LIMIT_S:
                        self.misses.append(f"answered after {took:.3f} s")
            self.stop.wait(max(0.0, rnd.uniform(0.25, 0.5) - (time.monotonic() - p0)))

    def summary(self) -> dict[str, Any]:
        return {
            "sent": self.sent,
            "answered": len(self.latencies),
            "answers": dict(self.answers),
            "missed": len(self.misses),
            "misses": self.misses[:10],
            "latency_ms": _ms(self.latencies),
        }


def _kind(ok: bool, message: str) -> str:
    """The daemon's answer as the UI relays it (its message; the UI adds no other)."""
    if ok:
        return "accepted"
    if message.startswith("not reset: rate limited"):
        return "rate"
    if message.startswith("not reset:"):
        return "still_violated"
    return "other"


def _soak_config(config: Path, work: Path, sock: str, max_resets: int | None) -> Path:
    """The given config with its control socket in the bench's temp dir."""
    cfg = work / "soak.yaml"
    control_cfg = f"\ncontrol:\n  socket: {sock}\n"
    if max_resets is not None:
        control_cfg += f"  max_resets: {max_resets}\n"
    cfg.write_text(config.read_text().rstrip("\n") + control_cfg)
    return cfg


def _start(
    s: Session, config: Path, max_resets: int | None, ui_on: bool
) -> tuple[str, Daemon, SoakUi | None]:
    """The daemon, ready and its watchdog pings watched, and unless ``ui_on`` is false
    the UI listening on its control socket; the socket's path, the daemon, the UI."""
    work = s.tmp / "daemon"
    work.mkdir()
    sock = str(work / "c.sock")
    cfg = _soak_config(config, work, sock, max_resets)
    d = s.daemon(cfg, work, watchdog_usec=2_000_000)
    d.wait_ready(120)
    d.watch_pings()
    ui: SoakUi | None = None
    if ui_on:
        (s.tmp / "ui").mkdir()
        ui = SoakUi(s, s.tmp / "ui", sock)
        ui.wait_listening()
    return sock, d, ui


class _Attackers:
    """The hostile clients of both channels and what each of their connections came to."""

    def __init__(self, sock: str, ui: SoakUi | None, stop: threading.Event) -> None:
        self.sock = sock
        self.ui = ui
        self.stop = stop
        self.outcomes: Counter[str] = Counter()
        self.http_outcomes: Counter[str] = Counter()
        self.got_through: list[str] = []
        self.lock = threading.Lock()

    def threads(self, clients: int, http_clients: int) -> list[threading.Thread]:
        threads = [
            threading.Thread(target=self._control, args=(i,), daemon=True) for i in range(clients)
        ]
        if self.ui is not None:
            threads += [
                threading.Thread(target=self._http, args=(1000 + i,), daemon=True)
                for i in range(http_clients)
            ]
        return threads

    def _control(self, seed: int) -> None:
        rnd = random.Random(seed)
        while not self.stop.is_set():
            kind = rnd.choice(KINDS)
            result = _attack(self.sock, kind, rnd)
            with self.lock:
                self.outcomes[f"{kind}:{result}"] += 1

    def _http(self, seed: int) -> None:
        assert self.ui is not None
        a = Attacker(self.ui, seed, self.stop)
        while not self.stop.is_set():
            kind = a.rnd.choice(HTTP_KINDS)
            result, through = a.attack(kind)
            with self.lock:
                self.http_outcomes[f"{kind}:{result}"] += 1
                if through:
                    self.got_through.append(kind)


class _ControlProbe:
    """The operator's reset over the control socket every ``probe_ms``, timed, with
    both processes' peak RSS sampled between resets."""

    def __init__(self) -> None:
        self.latencies: list[float] = []
        self.answers: Counter[str] = Counter()
        self.misses: list[str] = []
        self.peak_rss = 0
        self.ui_peak = 0

    def run(
        self,
        sock: str,
        daemon_pid: int,
        ui: SoakUi | None,
        stop: threading.Event,
        end: float,
        probe_ms: int,
    ) -> None:
        while time.monotonic() < end:
            p0 = time.monotonic()
            try:
                answer = request(sock, {"command": "reset", "via": "operator"}, 5.0)
            except UserError as e:
                self.misses.append(str(e))
            else:
                took = time.monotonic() - p0
                self.latencies.append(took)
                self.answers["accepted" if answer["ok"] else str(answer.get("refused"))] += 1
                if took > ANSWER_LIMIT_S:
                    self.misses.append(f"answered after {took:.3f} s")
            self.peak_rss = max(self.peak_rss, proc_memory(daemon_pid)["rss_kb"] or 0)
            if ui is not None:
                self.ui_peak = max(self.ui_peak, proc_memory(ui.child.pid)["rss_kb"] or 0)
            stop.wait(max(0.0, probe_ms / 1000 - (time.monotonic() - p0)))

    def summary(self) -> dict[str, Any]:
        return {
            "sent": len(self.latencies)
            + sum(1 for m in self.misses if not m.startswith("answered")),
            "answered": len(self.latencies),
            "answers": dict(self.answers),
            "missed": len(self.misses),
            "misses": self.misses[:10],
            "latency_ms": _ms(self.latencies),
        }


def _http_part(
    ui: SoakUi,
    probe: HttpProbe,
    attackers: _Attackers,
    http_clients: int,
    ui_start: tuple[dict[str, Any], int | None] | None,
    ui_peak: int,
    overflows: tuple[int | None, int | None],
) -> dict[str, Any]:
    """The UI's side of the soak; stops the UI (SIGTERM: it stops its server and node)."""
    ui_alive = ui.child.alive()
    ui_end = (proc_memory(ui.child.pid), fd_count(ui.child.pid))
    ui_exit = ui.child.stop(10)
    before, after = overflows
    http_outcomes = attackers.http_outcomes
    return {
        **probe.summary(),
        "attackers": http_clients,
        "attack_connections": sum(http_outcomes.values()),
        "attack_outcomes": dict(sorted(http_outcomes.items())),
        "got_through": len(attackers.got_through),
        "server_errors": sum(n for k, n in http_outcomes.items() if k.endswith(":500")),
        # machine-wide: other programs' full accept queues count too
        "listen_overflows": None if before is None or after is None else after - before,
        "alive_at_end": ui_alive,
        "exit_status": ui_exit,
        "tracebacks": _tracebacks(ui.stderr_path()),
        "rss_kb": {
            "start": ui_start[0]["rss_kb"] if ui_start else None,
            "end": ui_end[0]["rss_kb"],
            "peak": ui_peak,
        },
        "fds": {"start": ui_start[1] if ui_start else None, "end": ui_end[1]},
    }


def _under_attack(
    threads: list[threading.Thread],
    probe: HttpProbe | None,
    stop: threading.Event,
    operator: Callable[[float], None],
) -> float:
    """Starts the attackers and the UI's probe, runs the operator's probe from the
    start time until it returns, then stops and joins them all; the start time."""
    t0 = time.monotonic()
    for t in threads:
        t.start()
    if probe is not None:
        probe.thread.start()
    operator(t0)
    stop.set()
    if probe is not None:
        probe.thread.join(15)
    for t in threads:
        t.join(60)  # an attack holds its connection at most until the stop
    return t0


def _refused(records: list[dict[str, Any]]) -> Counter[str]:
    """Refused resets by reason, from the records that summarise them."""
    refused: Counter[str] = Counter()
    for r in records:
        if r.get("what") == "reset_refused":
            refused.update(r["refused"])
    return refused


def _stopped_log(d: Daemon) -> tuple[list[dict[str, Any]], bool]:
    """Stops the daemon; its log's records and whether ``logs --verify`` accepts it."""
    d.stop_cleanly()
    records = d.records()
    verify = children.run(
        [sys.executable, "-m", "supervisor", "logs", "--verify", str(d.log)],
        env=children.child_env(),
        timeout=120,
    )
    return records, verify.returncode == 0


def _with_ui_resets(http_part: dict[str, Any], resets: list[dict[str, Any]]) -> dict[str, Any]:
    """``http_part`` with the resets the UI's probe expects and those recorded."""
    # every reset the daemon took from the UI is a record naming it; only the
    # probe sends resets that can pass the UI's checks (httpsoak's docstring)
    http_part["resets_expected"] = sum(
        http_part["answers"].get(k, 0) for k in ("accepted", "still_violated")
    )
    http_part["resets_recorded"] = sum(1 for r in resets if r.get("via") == "ui")
    return http_part


def _channels(control: dict[str, Any], http_part: dict[str, Any] | None) -> dict[str, Any]:
    """Both channels' operator resets side by side."""
    return {
        name: {
            "sent": c["sent"],
            "answered": c["answered"],
            "p50_ms": c["latency_ms"]["p50"],
            "p99_ms": c["latency_ms"]["p99"],
            "max_ms": c["latency_ms"]["max"],
            "misses": c["missed"],
        }
        for name, c in (("control", control), ("http", http_part))
        if c is not None
    }


def soak(
    config: Path,
    minutes: float,
    clients: int,
    probe_ms: int,
    ui_on: bool,
    http_clients: int,
    max_resets: int | None = None,
) -> dict[str, Any]:
    requirements = [r.id for r in load_config(config).requirements]
    with session(None) as s:
        sock, d, ui = _start(s, config, max_resets, ui_on)
        start_mem, start_fds = proc_memory(d.pid), fd_count(d.pid)
        ui_start = (proc_memory(ui.child.pid), fd_count(ui.child.pid)) if ui else None
        overflows_before = listen_overflows()
        stop = threading.Event()
        attackers = _Attackers(sock, ui, stop)
        threads = attackers.threads(clients, http_clients)
        probe = HttpProbe(ui, requirements, stop) if ui is not None else None
        operator = _ControlProbe()
        t0 = _under_attack(
            threads,
            probe,
            stop,
            lambda t0: operator.run(sock, d.pid, ui, stop, t0 + minutes * 60, probe_ms),
        )
        end_mem, end_fds = proc_memory(d.pid), fd_count(d.pid)
        overflows_after = listen_overflows()
        ping_gap = d.longest_ping_gap(t0, time.monotonic())
        daemon_alive = d.alive()
        http_part: dict[str, Any] | None = None
        if ui is not None and probe is not None:
            http_part = _http_part(
                ui,
                probe,
                attackers,
                http_clients,
                ui_start,
                operator.ui_peak,
                (overflows_before, overflows_after),
            )
        records, log_verifies = _stopped_log(d)
        refused = _refused(records)
        resets = [r for r in records if r.get("event") == "reset"]
        control = operator.summary()
        result: dict[str, Any] = {
            "minutes": minutes,
            "max_resets": max_resets,
            "attackers": clients,
            "probes": control["sent"],
            "answered": control["answered"],
            "answers": control["answers"],
            "missed": control["missed"],
            "misses": control["misses"],
            "latency_ms": control["latency_ms"],
            "attack_connections": sum(attackers.outcomes.values()),
            "attack_outcomes": dict(sorted(attackers.outcomes.items())),
            "refused_summarised": dict(refused),
            "resets_recorded": len(resets),
            "control_failed": sum(1 for r in records if r.get("what") == "control_failed"),
            "rss_kb": {
                "start": start_mem["rss_kb"],
                "end": end_mem["rss_kb"],
                "peak": operator.peak_rss,
            },
            "fds": {"start": start_fds, "end": end_fds},
            "longest_ping_gap_s": None if ping_gap is None else round(ping_gap, 3),
            "daemon_alive_at_end": daemon_alive,
            "daemon_tracebacks": _tracebacks(d.stderr_path),
            "log_verifies": log_verifies,
        }
        if http_part is not None:
            result["http"] = _with_ui_resets(http_part, resets)
        result["channels"] = _channels(control, http_part)
        return result


def passed(result: dict[str, Any]) -> bool:
    """Every probe answered in time, both processes alive and quiet, the log intact."""
    ok = (
        result["missed"] == 0
        and result["log_verifies"]
        and not result["control_failed"]
        and result["daemon_alive_at_end"]
        and not result["daemon_tracebacks"]
    )
    h = result.get("http")
    if h is not None:
        ok = ok and (
            h["missed"] == 0
            and h["answered"] > 0
            and not h["got_through"]
            and not h["server_errors"]
            and h["alive_at_end"]
            and h["exit_status"] == 0
            and not h["tracebacks"]
            and h["resets_recorded"] == h["resets_expected"]
        )
    return ok


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m supervisor.tools.bench.control")
    p.add_argument("config", nargs="?", type=Path, default=data.example("srobot.yaml"))
    p.add_argument("--minutes", type=float, default=10.0)
    p.add_argument("--clients", type=int, default=16, help="attacking threads (default 16)")
    p.add_argument("--probe-ms", type=int, default=250, help="operator reset period")
    p.add_argument(
        "--ui",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also soak the ui's HTTP port and reset through it (default on)",
    )
    p.add_argument(
        "--http-clients", type=int, default=16, help="attacking HTTP threads (default 16)"
    )
    p.add_argument(
        "--max-resets",
        type=int,
        default=None,
        help="control.max_resets of the soak's daemon (default: the config's; at 1 per "
        "second most operator resets are answered 'rate limited')",
    )
    args = p.parse_args(argv)
    try:
        result = soak(
            args.config,
            args.minutes,
            args.clients,
            args.probe_ms,
            args.ui,
            args.http_clients,
            args.max_resets,
        )
    except (BenchError, UserError) as e:
        print(f"soak: {e}", file=sys.stderr)
        return 1
    print(json.dumps(result, indent=2))
    return 0 if passed(result) else 1


if __name__ == "__main__":
    sys.exit(main())
