"""``safety-supervisor status``: the running daemon's state, as ``systemctl status``
shows a unit's, asked on the control socket (:mod:`supervisor.daemon.control`,
the read-only ``status`` request).

Alive, config and its hash, uptime, ticks, messages and losses, whether it
records, and each requirement's state and last violation; ``--json`` for
scripts.  Exit 0 when a supervisor answered, 3 when none answers (none runs, or
it did not answer in time), as ``systemctl status`` exits 3 for a unit that is not
active; 1 when the answer cannot be had or understood (docs/reference/commands.md,
``status``).
"""

from __future__ import annotations

import argparse
import json
from datetime import UTC, datetime
from typing import Any

from monitors.errors import UserError
from monitors.untrusted import printable
from supervisor.names import client_control_socket
from supervisor.tools.reset import NoAnswer, add_socket_options, request

EXIT_NOT_RUNNING = 3  # systemctl status's "program is not running" (LSB)
# A thousand requirements and inputs fit; anything larger is not our daemon's answer.
MAX_STATUS_ANSWER = 4 * 1024 * 1024
MAX_STATUS_DEPTH = 5  # answer, status, requirements, requirement, stale_inputs

# The fields shown, with their JSON types: the one check of what the socket said.
_TOP: dict[str, tuple[type, ...]] = {
    "supervisor": (str,),
    "component": (str,),
    "config": (str, type(None)),
    "config_sha256": (str, type(None)),
    "pid": (int,),
    "started": (str,),
    "uptime_s": (int, float),
    "policy": (str,),
    "ticks": (int,),
    "received": (int,),
    "lost": (int,),
    "violations": (int,),
    "reloads": (int,),
    "recording": (bool,),
    "requirements": (list,),
    "inputs": (list,),
}
_REQUIREMENT: dict[str, tuple[type, ...]] = {
    "id": (str,),
    "state": (str,),
    "violations": (int,),
    "last_violation": (str, type(None)),
    "last_tick": (int, type(None)),
}
_INPUT: dict[str, tuple[type, ...]] = {
    "name": (str,),
    "topic": (str, type(None)),
    "age_s": (int, float, type(None)),
    "stale": (bool,),
    "messages": (int,),
    "lost": (int,),
}


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "status",
        help="the running supervisor's state (alive, config, uptime, requirements); "
        "exit 3 when none answers",
        description="Asks the running supervisor on its control socket, as systemctl "
        "status asks systemd: alive, config and its SHA-256, uptime, ticks, messages "
        "received and lost, recording, and each requirement's state and last violation. "
        "Exit 0 when it answered, 3 when no supervisor answers, 1 when the answer "
        "cannot be read.",
    )
    add_socket_options(p, 5.0, "the answer")
    p.add_argument(
        "--json",
        action="store_true",
        help="the supervisor's answer as one JSON object (the fields of the human output)",
    )


def cmd_status(args: argparse.Namespace) -> int:
    path = args.socket or client_control_socket()
    try:
        answer = request(
            path,
            {"command": "status"},
            args.timeout,
            max_answer=MAX_STATUS_ANSWER,
            max_depth=MAX_STATUS_DEPTH,
        )
    except NoAnswer as e:
        print(printable(str(e)), flush=True)
        return EXIT_NOT_RUNNING
    if not answer["ok"]:  # refused: no permission, or an older daemon without status
        raise UserError(printable(answer["message"]), file=path)
    status = checked_status(answer.get("status"), path)
    if args.json:
        print(json.dumps(status, sort_keys=True), flush=True)
    else:
        print("\n".join(printable(line) for line in render(status, path)), flush=True)
    return 0


def checked_status(doc: Any, path: str) -> dict[str, Any]:
    """The answer's ``status`` with the fields shown and their types, or one
    UserError naming the socket (whoever answered there)."""

    def wrong(why: str) -> UserError:
        return UserError(f"the status answer is not understood: {why}", file=path)

    def fields(obj: Any, spec: dict[str, tuple[type, ...]], where: str) -> dict[str, Any]:
        if not isinstance(obj, dict):
            raise wrong(f"{where} is not an object")
        out = {}
        for key, types in spec.items():
            value = obj.get(key)
            # bool is an int to Python: a count must not be true/false.
            if not isinstance(value, types) or (isinstance(value, bool) and bool not in types):
                raise wrong(f"{where}'s {key!r} is missing or of the wrong type")
            out[key] = value
        return out

    status = fields(doc, _TOP, "status")
    status["requirements"] = [
        fields(r, _REQUIREMENT, f"requirement {i + 1}") for i, r in enumerate(doc["requirements"])
    ]
    status["inputs"] = [fields(x, _INPUT, f"input {i + 1}") for i, x in enumerate(doc["inputs"])]
    return status


def _span(seconds: float) -> str:
    """``2 h 5 min``, ``3 min 12 s``, ``4.2 s``: as systemctl says how long ago."""
    s = int(seconds)
    days, s = divmod(s, 86400)
    hours, s = divmod(s, 3600)
    minutes, s = divmod(s, 60)
    if days:
        return f"{days} d {hours} h"
    if hours:
        return f"{hours} h {minutes} min"
    if minutes:
        return f"{minutes} min {s} s"
    return f"{seconds:.1f} s"


def _ago(ts: str | None, now: datetime) -> str:
    if ts is None:
        return "-"
    try:
        then = datetime.fromisoformat(ts.replace("Z", "+00:00"))
    except ValueError:
        return ts
    return f"{ts} ({_span(max(0.0, (now - then).total_seconds()))} ago)"


def render(st: dict[str, Any], path: str, now: datetime | None = None) -> list[str]:
    """The human output: systemctl status's layout, then one row per requirement."""
    now = now or datetime.now(UTC)
    sha = st["config_sha256"] or "-"
    lines = [
        f"● safety-supervisor {st['supervisor']} ({st['component']})",
        f"     Active: active (running) since {st['started']}; {_span(st['uptime_s'])} ago",
        f"        PID: {st['pid']}",
        f"     Config: {st['config'] or '-'}",
        f"     SHA256: {sha}",
        f"    Control: {path}",
        f"       Step: {st['policy']}, {st['ticks']} ticks, {st['received']} messages "
        f"received, {st['lost']} lost",
        f" Violations: {st['violations']} (reloads: {st['reloads']})",
        f"  Recording: {'yes' if st['recording'] else 'no'}",
    ]
    reqs = st["requirements"]
    if reqs:
        width = max(len("REQUIREMENT"), *(len(r["id"]) for r in reqs))
        lines += [
            "",
            f"{'REQUIREMENT':<{width}}  {'STATE':<10}  {'VIOLATIONS':>10}  LAST VIOLATION",
        ]
        for r in reqs:
            last = _ago(r["last_violation"], now)
            if r["last_tick"] is not None and r["last_violation"] is not None:
                last += f", tick {r['last_tick']}"
            lines.append(f"{r['id']:<{width}}  {r['state']:<10}  {r['violations']:>10}  {last}")
    stale = [x["name"] for x in st["inputs"] if x["stale"]]
    lossy = [f"{x['name']} ({x['lost']})" for x in st["inputs"] if x["lost"]]
    if stale:
        lines.append(f"stale inputs: {', '.join(stale)}")
    if lossy:
        lines.append(f"inputs with lost messages: {', '.join(lossy)}")
    return lines
