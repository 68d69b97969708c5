"""``safety-supervisor reset``: the operator's reset, through the control socket.

Connects to the running daemon's control socket (:mod:`supervisor.daemon.control`;
``--socket``, else the installed service's ``/run/safety-supervisor/control.sock``,
else the path a ``run`` of this user in this ROS domain listens on).  The
kernel checks the socket file's permissions, the daemon the caller's
credentials, which it writes into the ``reset`` record.  The daemon resets
every requirement's monitor and lifts latched mitigations of requirements that
hold again; it refuses (and says which) for those still violated, and refuses
resets beyond its rate limit.  docs/reference/commands.md, ``reset``.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import grp
import json
import math
import os
import pwd
import socket
import stat
import time
from typing import Any

from monitors.errors import UserError
from monitors.untrusted import Untrusted, load_json, printable
from supervisor.names import client_control_socket

MAX_ANSWER = 65536
CONNECT_RETRY_S = 0.02
MAX_TIMEOUT_S = 86400.0  # a day: beyond it, a typo


def add_socket_options(r: argparse.ArgumentParser, timeout_s: float, wait_for: str) -> None:
    """``--socket`` and ``--timeout`` of the commands that ask the control socket."""
    r.add_argument(
        "--socket",
        metavar="PATH",
        help="the daemon's control socket (default: /run/safety-supervisor/control.sock "
        "if it exists, else the one `run` uses for this user and ROS_DOMAIN_ID)",
    )
    r.add_argument(
        "--timeout",
        type=seconds_arg,
        default=timeout_s,
        help=f"seconds to wait for {wait_for} (default {timeout_s:g})",
    )


def add_parser(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser(
        "reset", help="operator reset of the running supervisor (lifts latched mitigations)"
    )
    add_socket_options(r, 10.0, "the answer")
    r.add_argument(
        "--requirement",
        metavar="ID",
        default=None,
        help="reset this requirement only (default: every requirement)",
    )


def seconds_arg(text: str) -> float:
    """A ``--timeout``: a positive, finite number of seconds (argparse's usage error
    otherwise, never the socket module's ValueError)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of seconds: {text!r}") from None
    if not math.isfinite(value) or value <= 0 or value > MAX_TIMEOUT_S:
        raise argparse.ArgumentTypeError(
            f"must be more than 0 and at most {MAX_TIMEOUT_S:g} seconds, not {text!r}"
        )
    return value


def cmd_reset(args: argparse.Namespace) -> int:
    path = args.socket or client_control_socket()
    req: dict[str, Any] = {"command": "reset"}
    if args.requirement is not None:
        req["requirement"] = args.requirement
    answer = request(path, req, args.timeout)
    # The daemon's words, one line and safe for the terminal whoever answered.
    print(printable(answer["message"]), flush=True)
    return 0 if answer["ok"] else 1


class NoAnswer(UserError):
    """No supervisor answered: none listens, or it did not answer in time
    (``status`` exits 3 for it, as ``systemctl status`` does for a stopped unit)."""


def request(
    path: str,
    req: dict[str, Any],
    timeout: float,
    *,
    max_answer: int = MAX_ANSWER,
    max_depth: int = 4,
) -> dict[str, Any]:
    """One request, one answer; every failure is a UserError naming the socket
    (:class:`NoAnswer` when no supervisor answers)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(timeout)
        try:
            _connect(s, path, time.monotonic() + timeout)
        except (FileNotFoundError, ConnectionRefusedError):
            raise NoAnswer(
                "no supervisor is running here",
                file=path,
                hint="start it (systemctl start safety-supervisor), or pass the socket "
                "of a `run` with --socket",
            ) from None
        except PermissionError:
            who, hint = _who_may(path)
            raise UserError("permission denied: " + who, file=path, hint=hint) from None
        except OSError as e:
            if e.errno == errno.ENOTSOCK:
                raise UserError("not a control socket", file=path) from None
            raise UserError(f"cannot connect: {e.strerror or e}", file=path) from None
        try:
            s.sendall(json.dumps(req).encode() + b"\n")
            data = b""
            while b"\n" not in data and len(data) < max_answer:
                chunk = s.recv(MAX_ANSWER)
                if not chunk:
                    break
                data += chunk
        except TimeoutError:
            raise NoAnswer(f"no answer within {timeout:g} s", file=path) from None
        except OSError as e:
            raise UserError(f"connection failed: {e.strerror or e}", file=path) from None
    line, nl, _ = data.partition(b"\n")
    if not nl and len(data) >= max_answer:
        raise UserError(f"the answer is longer than {max_answer} bytes", file=path)
    if not line.strip():
        raise NoAnswer("the supervisor closed the connection without an answer", file=path)
    return _checked(line, path, max_answer, max_depth)


def _checked(line: bytes, path: str, max_answer: int, max_depth: int) -> dict[str, Any]:
    """The one schema check of an answer (docs/reference/ros-interfaces.md,
    "Control socket"): an object with ``ok`` (bool) and ``message`` (string),
    ``refused`` a string if present.  Whatever else comes back (a wrong
    program on the socket) is one UserError."""

    def wrong(why: str) -> UserError:
        return UserError(f"the answer is not understood: {why}", file=path)

    try:
        answer = load_json(line, max_bytes=max_answer, max_depth=max_depth)
    except Untrusted as e:
        raise wrong(str(e)) from None
    if not isinstance(answer, dict):
        raise wrong(f"a JSON {type(answer).__name__}, not an object")
    if not isinstance(answer.get("ok"), bool):
        raise wrong("'ok' is missing or not true/false")
    if not isinstance(answer.get("message"), str):
        raise wrong("'message' is missing or not a string")
    if not isinstance(answer.get("refused", ""), str):
        raise wrong("'refused' is not a string")
    return answer


def _connect(s: socket.socket, path: str, deadline: float) -> None:
    """Connect; a full listen queue (EAGAIN: a flood of other clients) is tried
    again until ``deadline``, the daemon accepts its queue within milliseconds."""
    while True:
        try:
            s.connect(path)
            return
        except BlockingIOError:
            if time.monotonic() + CONNECT_RETRY_S > deadline:
                raise
            time.sleep(CONNECT_RETRY_S)


def _who_may(path: str) -> tuple[str, str]:
    """Who the socket file lets in, in words (its owner, its group if it has the
    mode), and what to ask for."""
    try:
        st = os.stat(path)
    except OSError:
        return (
            "the socket's directory is closed to this user",
            "pass the socket of a supervisor you may reach with --socket",
        )
    owner = str(st.st_uid)
    with contextlib.suppress(KeyError):
        owner = pwd.getpwuid(st.st_uid).pw_name
    group = str(st.st_gid)
    with contextlib.suppress(KeyError):
        group = grp.getgrgid(st.st_gid).gr_name
    if st.st_mode & stat.S_IWGRP:
        return (
            f"only user {owner} and members of group {group} may reset",
            f"ask for membership of group {group} (usermod -aG {group} USER), log in again",
        )
    return (
        f"only user {owner} (and root) may reset; the socket has no operators group",
        "set control.group in the supervisor's config (the service's is safety-operators)",
    )
