"""The UI's load on the daemon: the throughput experiment's daemon at one offered rate,
three times on the same offered stream (docs/reference/commands.md#bench):

1. without a UI;
2. with ``safety-supervisor ui`` (a child process on the session's domain, bound to
   127.0.0.1 on a free port) and ``clients`` open pages: plain HTTP clients reading
   ``/events`` on threads of this process, connected before the daemon starts and
   for the whole run;
3. the same, with the UI killed (SIGKILL) halfway through the publishing and
   started again at once on the same port; the clients reconnect as a browser's
   EventSource does (after the server's ``retry:``).

For each: what the daemon received and lost, its CPU per message and the difference
from the first in %; the events each client received (and the longest time without
one while the publisher ran: status documents come every ``ros.status_ms``, 500 ms by
default); the UI's own CPU per second while it served the clients (from /proc, as the
recording experiment reads its writer); and after the restart, how long until the
clients were connected again and received a status document again. The goal, printed
and not asserted: the UI costs the daemon at most ``GOAL_PCT`` % more CPU per message
and no messages (the UI is a separate process that only reads the daemon's own
topics, docs/reference/commands.md#ui).
"""

from __future__ import annotations

import contextlib
import http.client
import json
import secrets
import socket
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from supervisor.tools.bench.errors import BenchError
from supervisor.tools.bench.numbers import shown as _f
from supervisor.tools.bench.plan import Plan
from supervisor.tools.bench.session import Session, cpu_seconds
from supervisor.tools.bench.throughput import throughput
from supervisor.tools.children import Child

GOAL_PCT = 10.0
CLIENTS = 10
HOST = "127.0.0.1"
CHROMIUM = "/usr/bin/chromium"  # Debian's, as tests/system/test_ui.py uses
READ_TIMEOUT_S = 30.0  # longer than the server's keepalive (10 s): only a dead stream trips it
START_TIMEOUT_S = 60.0
STATUS_AGAIN_TIMEOUT_S = 30.0  # after the run, before the daemon is stopped
DEFAULT_RETRY_S = 3.0  # EventSource's usual default, until the server sends retry:

CASES = ("no ui", "ui + clients", "ui killed and restarted")


class Stream:
    """What one page received from ``/events``: when each stream was opened, and each
    event with the time it arrived."""

    def __init__(self) -> None:
        self.connects: list[float] = []  # monotonic time each stream was opened
        # (monotonic time, type, carries a status document, index into connects)
        self.events: list[tuple[float, str, bool, int]] = []

    def _event(self, data: bytes | str, index: int) -> None:
        try:
            doc = json.loads(data)
        except ValueError:
            doc = {}
        kind = str(doc.get("type", "?")) if isinstance(doc, dict) else "?"
        # A snapshot carries the status too once the UI has one (the latched document).
        status = kind == "status" or (kind == "snapshot" and bool(doc.get("status")))
        self.events.append((time.monotonic(), kind, status, index))

    def counts(self, start: float, end: float) -> dict[str, Any]:
        """Events in all and in ``[start, end]``, and the longest time without one there."""
        inside = [t for t, *_ in self.events if start <= t <= end]
        marks = [start, *inside, end]
        return {
            "events": len(self.events),
            "events_in_run": len(inside),
            "status_events": sum(1 for e in self.events if e[2]),
            "connects": len(self.connects),
            "longest_gap_s": max(b - a for a, b in zip(marks, marks[1:], strict=False)),
        }

    def status_again(self, killed: float) -> tuple[float | None, float | None]:
        """(connected again, first status document again): monotonic times on the
        first stream opened after ``killed``; None when it never was."""
        after = [i for i, t in enumerate(self.connects) if t > killed]
        if not after:
            return None, None
        first = after[0]
        status = next((t for t, _k, st, i in self.events if st and i >= first), None)
        return self.connects[first], status


class SseClient(Stream):
    """One open page's event stream, ``GET /events`` read on a thread of its own and
    opened again after the server's ``retry:`` when it ends or cannot connect."""

    def __init__(self, port: int, name: str) -> None:
        super().__init__()
        self.port = port
        self._retry = DEFAULT_RETRY_S
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._sock: socket.socket | None = None
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            with contextlib.suppress(OSError, http.client.HTTPException):
                self._stream()  # refused while the UI is down, or cut by its death
            self._stop.wait(self._retry)

    def _stream(self) -> None:
        conn = http.client.HTTPConnection(HOST, self.port, timeout=READ_TIMEOUT_S)
        try:
            conn.request("GET", "/events", headers={"Accept": "text/event-stream"})
            with self._lock:
                self._sock = conn.sock  # the response owns it once the headers are read
            if self._stop.is_set():
                return
            r = conn.getresponse()
            if r.status != 200:
                return
            self.connects.append(time.monotonic())
            index = len(self.connects) - 1
            data: list[bytes] = []
            while not self._stop.is_set():
                line = r.readline()
                if not line:
                    return  # the server closed the stream (or died)
                line = line.rstrip(b"\r\n")
                if line.startswith(b"data:"):
                    data.append(line[5:].removeprefix(b" "))
                elif line.startswith(b"retry:"):
                    with contextlib.suppress(ValueError):
                        self._retry = int(line[6:].strip()) / 1000
                elif not line and data:
                    self._event(b"\n".join(data), index)
                    data = []
        finally:
            with self._lock:
                self._sock = None
            conn.close()

    def stop(self) -> None:
        self._stop.set()
        with self._lock:
            if self._sock is not None:
                # Wakes the blocked readline; the thread then sees the stop.
                with contextlib.suppress(OSError):
                    self._sock.shutdown(socket.SHUT_RDWR)
        self._thread.join(READ_TIMEOUT_S)


class ChromiumPage(Stream):
    """The UI's page in headless Chromium (playwright), on a thread of its own: the
    playwright objects belong to the thread that made them. Its EventSource's messages
    are counted from the DevTools protocol (the page's CSP forbids injected scripts);
    the browser reconnects by itself."""

    def __init__(self, port: int) -> None:
        super().__init__()
        self.url = f"http://{HOST}:{port}/"
        self.error: str | None = None
        self._opened = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="chromium", daemon=True)
        self._thread.start()

    @staticmethod
    def available() -> bool:
        import importlib.util

        return Path(CHROMIUM).exists() and importlib.util.find_spec("playwright") is not None

    def _run(self) -> None:
        from playwright.sync_api import sync_playwright

        pw = sync_playwright().start()
        try:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            page = browser.new_page()
            cdp = page.context.new_cdp_session(page)
            cdp.send("Network.enable")
            cdp.on("Network.responseReceived", self._response)
            cdp.on("Network.eventSourceMessageReceived", self._message)
            page.goto(self.url)
            self._opened.set()
            while not self._stop.is_set():
                page.wait_for_timeout(50)  # lets playwright deliver the protocol's events
            browser.close()
        except Exception as e:  # noqa: BLE001 - optional: reported, the bench goes on
            self.error = f"{type(e).__name__}: {e}"
        finally:
            self._opened.set()
            pw.stop()

    def _response(self, ev: dict[str, Any]) -> None:
        # The stream's headers: opened (a refused attempt while the UI is down has none).
        response = ev.get("response", {})
        if str(response.get("url", "")).endswith("/events") and response.get("status") == 200:
            self.connects.append(time.monotonic())

    def _message(self, ev: dict[str, Any]) -> None:
        self._event(str(ev.get("data", "")), len(self.connects) - 1)

    def wait_opened(self, timeout: float) -> None:
        self._opened.wait(timeout)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(START_TIMEOUT_S)


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind((HOST, 0))
        return int(sock.getsockname()[1])


class UiChild:
    """``safety-supervisor ui`` on the session's domain with a token of its own in
    ``work``: without ``--token-file`` it would read the installed one, if any."""

    def __init__(self, s: Session, work: Path, port: int) -> None:
        self.s = s
        self.work = work
        self.port = port
        self.token = work / "ui.token"
        self.token.write_text(secrets.token_hex(32) + "\n")
        self.token.chmod(0o600)
        self.started = 0
        self.child = self.start()

    def start(self) -> Child:
        self.started += 1
        argv = [sys.executable, "-m", "supervisor", "ui", "--bind", f"{HOST}:{self.port}"]
        argv += ["--token-file", str(self.token)]
        self.child = Child(
            "ui",
            argv,
            env=self.s.env,
            cwd=self.work,
            stderr=self.work / f"ui-{self.started}.stderr",
        )
        self.s.children.append(self.child)  # killed with the session whatever happens
        return self.child

    def wait_listening(self, timeout: float = START_TIMEOUT_S) -> None:
        deadline = time.monotonic() + timeout
        while True:
            conn = http.client.HTTPConnection(HOST, self.port, timeout=5)
            try:
                conn.request("GET", "/api/state")
                if conn.getresponse().status == 200:
                    return
            except (OSError, http.client.HTTPException):
                pass
            finally:
                conn.close()
            if not self.child.alive():
                raise BenchError(f"ui exited ({self.child.returncode}): {self.child.last_stderr()}")
            if time.monotonic() > deadline:
                raise BenchError(f"ui: not listening within {timeout:g} s")
            time.sleep(0.1)  # polling: the UI prints nothing when it listens


def _daemon(row: dict[str, Any]) -> dict[str, Any]:
    d = row["receivers"]["daemon"]
    return {
        "sent": row["sent"],
        "achieved": row["achieved"],
        "seconds": row["seconds"],
        "received": d["received"],
        "lost": row["sent"] - d["received"],
        "counted_lost": row["daemon_counted_lost"],
        "loss_agree": row["daemon_loss"]["agree"],
        "loss": row["daemon_loss"],  # the categories, to see a disagreement
        "cpu_s": d["cpu_s"],
        "cpu_us_per_msg": d["cpu_us_per_msg"],
        "longest_ping_gap_ms": row["longest_ping_gap_ms"],
        "drained": row["drained"],
    }


def _spread(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    ordered = sorted(values)
    return {"min": ordered[0], "median": ordered[len(ordered) // 2], "max": ordered[-1]}


class _Load:
    """What the UI goes through while throughput() publishes: its CPU sampled and,
    with ``restart``, a SIGKILL halfway and a restart; ``marks``: when, monotonic."""

    def __init__(self, ui: UiChild, restart: bool, seconds: float, streams: list[Stream]) -> None:
        self.ui = ui
        self.restart = restart
        self.seconds = seconds
        self.streams = streams
        self.marks: dict[str, float] = {}
        self.first_pid = ui.child.pid
        self.done = threading.Event()  # the run is over (or failed): stop acting
        self.sampled = threading.Event()  # the kill and the CPU samples are done
        self.released = threading.Event()  # the UI was stopped: its starting thread may end
        self.sampler: threading.Thread | None = None

    def _during(self, go: float) -> None:
        # On a thread: the kill and the UI's CPU samples happen while throughput()
        # waits for the publisher.
        marks, done, ui, seconds = self.marks, self.done, self.ui, self.seconds
        marks["go"] = go
        marks["ui_cpu0"] = cpu_seconds(self.first_pid)
        if self.restart and not done.wait(max(0.0, go + seconds / 2 - time.monotonic())):
            marks["ui_cpu_at_kill"] = cpu_seconds(self.first_pid)
            marks["killed"] = time.monotonic()
            ui.child.kill()  # SIGKILL to its group, then reaped
            ui.start()
            marks["restarted"] = time.monotonic()
        if not done.wait(max(0.0, go + seconds - time.monotonic())):
            marks["ui_cpu1"] = cpu_seconds(ui.child.pid)
            marks["end"] = time.monotonic()
        self.sampled.set()
        # The restarted UI's parent-death signal fires when the thread that started
        # it ends (supervisor/children.py): this one lives until the UI was stopped.
        self.released.wait()

    def on_go(self, go: float) -> None:
        self.sampler = threading.Thread(
            target=self._during, args=(go,), name="ui-load", daemon=True
        )
        self.sampler.start()

    def before_stop(self) -> None:
        # The daemon still publishes its status: a restart late in a short run is
        # still timed to the clients' first status (``within_run`` says whether the
        # publisher was still running then).
        self.sampled.wait(self.seconds + START_TIMEOUT_S)
        if "killed" not in self.marks:
            return
        deadline = time.monotonic() + STATUS_AGAIN_TIMEOUT_S
        while time.monotonic() < deadline:
            if all(r.status_again(self.marks["killed"])[1] is not None for r in self.streams):
                return
            time.sleep(0.05)  # polling the client threads

    def stop(self) -> int | None:
        """Stops the UI and the clients, a kill under way finished first; the UI's exit
        status (SIGTERM with the streams open: it must exit 0)."""
        self.done.set()
        self.sampled.wait(START_TIMEOUT_S)  # a kill under way finishes before the stop
        exit_code = self.ui.child.stop()
        self.released.set()
        if self.sampler is not None:
            self.sampler.join()
        for r in self.streams:
            r.stop()
        return exit_code


def _wait_connected(streams: list[Stream], page: ChromiumPage | None, clients: int) -> None:
    """Until every stream connected; a page that failed to open is left out."""
    deadline = time.monotonic() + START_TIMEOUT_S
    if page is not None:
        page.wait_opened(START_TIMEOUT_S)
    while not all(r.connects for r in streams):
        if page is not None and page.error is not None:
            streams.remove(page)
            continue
        if time.monotonic() > deadline:
            raise BenchError(f"ui: {clients} clients not connected within {START_TIMEOUT_S:g} s")
        time.sleep(0.05)  # polling the client threads


def _restart(
    readers: list[SseClient], marks: dict[str, float], go: float, end: float, clients: int
) -> dict[str, Any]:
    """How long the restart took and how soon each client had the status again."""
    killed, restarted = marks["killed"], marks["restarted"]
    again = [r.status_again(killed) for r in readers]
    connected = [c - restarted for c, _st in again if c is not None]
    status = [st - restarted for _c, st in again if st is not None]
    return {
        "killed_after_s": killed - go,
        "restart_took_s": restarted - killed,
        "clients_reconnected": len(connected),
        "clients_with_status_again": len(status),
        "connected_again_s": _spread(connected),
        "status_again_s": _spread(status),
        # Status again before the publisher's end: the restart happened while
        # the daemon was monitoring at the offered rate.
        "within_run": bool(status) and len(status) == clients and restarted + max(status) <= end,
        "restarted_ui_cpu_s": marks.get("ui_cpu1"),
    }


def _case(
    s: Session,
    plan: Plan,
    rate: float,
    seconds: float,
    clients: int,
    restart: bool,
    wd_usec: int | None,
    chromium: bool,
) -> dict[str, Any]:
    work = Path(tempfile.mkdtemp(prefix=f"ui-{rate:g}-{int(restart)}-", dir=s.tmp))
    ui = UiChild(s, work, free_port())
    ui.wait_listening()
    readers = [SseClient(ui.port, f"sse-{i}") for i in range(clients)]
    page = ChromiumPage(ui.port) if chromium and ChromiumPage.available() else None
    streams: list[Stream] = [*readers, *([page] if page is not None else [])]
    load = _Load(ui, restart, seconds, streams)
    try:
        _wait_connected(streams, page, clients)
        row = throughput(
            s,
            plan,
            rate,
            seconds,
            False,
            wd_usec=wd_usec,
            on_go=load.on_go,
            before_stop=load.before_stop,
        )
    finally:
        exit_code = load.stop()
    marks = load.marks
    go = marks["go"]
    end = go + row["seconds"]
    per_client = [r.counts(go, end) for r in readers]
    out = _daemon(row)
    out["ui"] = {
        "clients": clients,
        "per_client": per_client,
        "events": _spread([c["events"] for c in per_client]),
        "events_in_run": _spread([c["events_in_run"] for c in per_client]),
        "longest_gap_s": max(c["longest_gap_s"] for c in per_client),
        "exit_code": exit_code,
        "ui_cpu_ms_per_s": None,
        "ui_cpu_ms_per_s_until_kill": None,
        "restart": None,
    }
    if chromium:
        out["ui"]["chromium"] = _page_result(page, go, end, marks.get("restarted"))
    if "ui_cpu1" in marks and not restart:
        out["ui"]["ui_cpu_ms_per_s"] = (
            1e3 * (marks["ui_cpu1"] - marks["ui_cpu0"]) / (marks["end"] - go)
        )
    if restart and "killed" in marks:
        out["ui"]["ui_cpu_ms_per_s_until_kill"] = (
            1e3 * (marks["ui_cpu_at_kill"] - marks["ui_cpu0"]) / (marks["killed"] - go)
        )
        out["ui"]["restart"] = _restart(readers, marks, go, end, clients)
    return out


def _page_result(
    page: ChromiumPage | None, go: float, end: float, restarted: float | None
) -> dict[str, Any]:
    """The Chromium page's counts, as a client's; ``error`` when it could not be opened."""
    if page is None:
        return {"error": f"{CHROMIUM} or playwright is not installed"}
    if page.error is not None:
        return {"error": page.error}
    out: dict[str, Any] = {"error": None, **page.counts(go, end)}
    out["connected_again_s"] = out["status_again_s"] = None
    if restarted is not None:
        connected, status = page.status_again(restarted)
        if connected is not None:
            out["connected_again_s"] = connected - restarted
        if status is not None:
            out["status_again_s"] = status - restarted
    return out


def _pct(new: float | None, old: float | None) -> float | None:
    return None if new is None or not old else 100.0 * (new - old) / old


def ui_load(
    s: Session,
    plan: Plan,
    rate: float,
    seconds: float,
    say: Callable[[str], None],
    *,
    clients: int = CLIENTS,
    wd_usec: int | None = None,
    chromium: bool = False,
) -> dict[str, Any]:
    """The three runs at ``rate`` msg/s for ``seconds``, without the UI first;
    ``chromium``: also one page in headless Chromium in the UI's runs."""
    cases: list[dict[str, Any]] = []
    for name in CASES:
        say(f"ui load, {name}: throughput at {rate:g} msg/s for {seconds:g} s")
        if name == "no ui":
            row = _daemon(throughput(s, plan, rate, seconds, False, wd_usec=wd_usec))
            row["ui"] = None
        else:
            restart = name != "ui + clients"
            row = _case(s, plan, rate, seconds, clients, restart, wd_usec, chromium)
        row["case"] = name
        cases.append(row)
    base = cases[0]
    for row in cases:
        row["cpu_diff_pct"] = _pct(row["cpu_us_per_msg"], base["cpu_us_per_msg"])
        row["lost_diff"] = row["lost"] - base["lost"]
    served, restarted = cases[1]["ui"], cases[2]["ui"]
    again = (restarted["restart"] or {}).get("status_again_s") or {}
    say(
        f"ui load at {rate:g} msg/s: daemon CPU {_f(base['cpu_us_per_msg'])} us/msg without, "
        f"{_f(cases[1]['cpu_us_per_msg'])} with {clients} clients "
        f"({_f(cases[1]['cpu_diff_pct'], '+.1f')} %), {_f(cases[2]['cpu_us_per_msg'])} "
        f"restarted ({_f(cases[2]['cpu_diff_pct'], '+.1f')} %), goal {GOAL_PCT:g} %; lost "
        f"{base['lost']} / {cases[1]['lost']} / {cases[2]['lost']}; ui "
        f"{_f(served['ui_cpu_ms_per_s'])} ms CPU/s; status again {_f(again.get('max'), '.2f')} s "
        "after the restart"
    )
    return {
        "offered": rate,
        "seconds": seconds,
        "clients": clients,
        "goal_pct": GOAL_PCT,
        "cases": cases,
    }
