"""``safety-supervisor ui``: parse the options, start the ROS node and the server, wait.

It never runs inside the daemon: a crash or a restart of the UI leaves monitoring
alone.  docs/reference/commands.md, ``ui``.
"""

from __future__ import annotations

import argparse
import ipaddress
import math
import re
import signal
import sys
import threading
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from supervisor.names import client_control_socket
from supervisor.tools.ui.token import TOKEN_FILE, read_token

PROG = "ui"
DEFAULT_BIND = "127.0.0.1:8321"


def bind_arg(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[::1]:PORT`` for IPv6) as argparse's type."""
    host, sep, port = text.rpartition(":")
    host = host.strip("[]")
    try:
        if not sep or not host:
            raise ValueError
        ipaddress.ip_address(host)
        number = int(port)
        if not 0 <= number <= 65535:
            raise ValueError
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not ADDRESS:PORT (e.g. 127.0.0.1:8321, [::1]:8321, 0.0.0.0:8321)"
        ) from None
    return host, number


def namespace_arg(text: str) -> str:
    """A ROS namespace as argparse's type (rclpy's own error spans several lines)."""
    if text != "/" and not re.fullmatch(
        r"/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*/?", text
    ):
        raise argparse.ArgumentTypeError(f"{text!r} is not a ROS namespace (e.g. /robot1)")
    return text


MAX_VIOLATED_FOR_S = 7 * 24 * 3600.0


def seconds_arg(text: str) -> float:
    """``--violated-for``: seconds, 0 (never held) to a week, as argparse's type."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0 <= value <= MAX_VIOLATED_FOR_S:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a number of seconds from 0 to {MAX_VIOLATED_FOR_S:.0f}"
        )
    return value


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "ui", help="the operator's web page: live state, events, resets (its own process)"
    )
    p.add_argument(
        "--bind",
        type=bind_arg,
        default=bind_arg(DEFAULT_BIND),
        metavar="ADDRESS:PORT",
        help=f"where to listen (default {DEFAULT_BIND}: this machine only)",
    )
    p.add_argument(
        "--token-file",
        default=None,
        metavar="PATH",
        help=f"the bearer token that resets need (default {TOKEN_FILE} if it exists; "
        "without a token the page is read-only)",
    )
    p.add_argument(
        "--namespace",
        type=namespace_arg,
        default="/",
        metavar="NS",
        help="the daemon's ros.namespace (default /): where its status and violations are",
    )
    p.add_argument(
        "--socket",
        default=None,
        metavar="PATH",
        help="the daemon's control socket, where resets go (default: where `reset` looks; "
        "never the path a status document names)",
    )
    p.add_argument(
        "--violated-for",
        type=seconds_arg,
        default=None,
        metavar="SECONDS",
        help="how long a requirement shows 'violated N s ago' after each violation, "
        "though its policy reset it (default 60)",
    )
    p.add_argument(
        "--fleet",
        default=None,
        metavar="FILE",
        help="several robots: a YAML list of {name, namespace, domain}; the page lists "
        "every supervisor on their domains, each linking to its own page",
    )


def _token(args: argparse.Namespace) -> bytes | None:
    if args.token_file:
        return read_token(Path(args.token_file))
    if TOKEN_FILE.exists():
        return read_token(TOKEN_FILE)
    return None


def _page_options(args: argparse.Namespace) -> dict[str, Any]:
    return {} if args.violated_for is None else {"violated_for_s": args.violated_for}


def cmd_ui(args: argparse.Namespace) -> int:
    from supervisor.tools.ui.hub import Hub
    from supervisor.tools.ui.server import UiServer, reset_availability

    token = _token(args)
    if args.fleet is not None:
        return _fleet(args, token)

    # Resets go where this command's configuration says, never where a status
    # document says: any node of the domain can publish one (docs/reference/
    # ros-interfaces.md, "What the status topic can be trusted for").
    def socket_path() -> str:
        return str(args.socket) if args.socket else client_control_socket()

    hub = Hub(lambda _doc: reset_availability(socket_path(), token))
    try:
        server = UiServer(args.bind, hub, token, socket_path, **_page_options(args))
    except OSError as e:
        host, port = args.bind
        raise UserError(f"cannot listen on {host}:{port}: {e.strerror or e}", file=PROG) from None

    from supervisor.tools.ui.node import UiNode

    node = UiNode(hub, args.namespace)
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    _serve(server, node, token, stop)
    return 0


def _serve(server: Any, node: Any, token: bytes | None, stop: threading.Event) -> None:
    """Serve until SIGTERM or Ctrl-C (``stop``), then stop the server and the node."""
    thread = threading.Thread(target=server.serve_forever, name="ui-http", daemon=True)
    thread.start()
    mode = "resets with the token" if token is not None else "read-only: no token"
    print(f"safety-supervisor ui: {server.url()} ({mode})", flush=True)
    try:
        while not stop.wait(0.5):
            pass
    finally:
        server.stop()
        node.close()
    print("safety-supervisor ui: stopped", file=sys.stderr, flush=True)


def _fleet(args: argparse.Namespace, token: bytes | None) -> int:
    """The fleet view (docs/reference/commands.md, ``ui``, "The fleet")."""
    from supervisor.tools.ui.fleet import Fleet, load_fleet, local_reset_availability
    from supervisor.tools.ui.server import UiServer, reset_availability

    for option, given in (("--namespace", args.namespace != "/"), ("--socket", args.socket)):
        if given:
            # each robot's namespace and socket are in the file
            raise UserError(f"{option} is for one robot, not with --fleet", file=PROG)
    robots = load_fleet(Path(args.fleet))
    fleet = Fleet(
        robots, lambda doc, sock: local_reset_availability(doc, sock, token, reset_availability)
    )
    try:
        server = UiServer(args.bind, None, token, lambda: None, fleet=fleet, **_page_options(args))
    except OSError as e:
        host, port = args.bind
        raise UserError(f"cannot listen on {host}:{port}: {e.strerror or e}", file=PROG) from None

    from supervisor.tools.ui.node import FleetNode

    node = FleetNode(fleet)
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    _serve(server, node, token, stop)
    return 0
