"""``safety-supervisor reload``: reload the running daemon's config and wait for it.

The unit's ``ExecReload``.  ``kill -HUP`` returns at once, so ``systemctl
reload`` would return before the new config is in force (systemd 252 has no
``Type=notify-reload``).  This command asks on the control socket
(:mod:`supervisor.daemon.control`, the same socket and lookup as ``reset``) and
returns when the daemon answers: exit 0 once the new config is in force, with
its SHA-256; exit 1 and one line when the daemon refused it (the config's
``FILE:LINE: ...``; the previous config stays in force) or did not answer.
The daemon validates the config as ``check`` does, so no separate ``check``
runs before it.  docs/reference/commands.md, ``reload``.
"""

from __future__ import annotations

import argparse
import sys

from monitors.untrusted import printable
from supervisor.names import client_control_socket
from supervisor.tools.reset import add_socket_options, request

# Below the unit's TimeoutStartSec= (60 s), which systemd also applies to
# ExecReload: the command, not systemd, says why a reload did not finish.
DEFAULT_TIMEOUT_S = 50.0


def add_parser(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser(
        "reload",
        help="reload the running supervisor's config; returns once it is in force or refused",
    )
    add_socket_options(r, DEFAULT_TIMEOUT_S, "the outcome")


def cmd_reload(args: argparse.Namespace) -> int:
    path = args.socket or client_control_socket()
    answer = request(path, {"command": "reload"}, args.timeout)
    # The daemon's words, one line and safe for the terminal whoever answered.
    text = printable(" ".join(answer["message"].splitlines()))
    if answer["ok"]:
        print(text, flush=True)
        return 0
    print(text, file=sys.stderr, flush=True)
    return 1
