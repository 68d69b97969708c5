"""The UI's HTTP server: the page, its Server-Sent Events and the reset endpoint.

The standard library's ThreadingHTTPServer: one page, one event stream per
browser and a rare POST need no framework (docs/reference/commands.md, ``ui``).

Safety of the one state-changing request (``POST /api/reset``), in this order:

1. the ``Host`` header must name this server (a DNS-rebinding page would send
   its own name), for every request;
2. ``Origin`` (when sent) must be this server's origin and ``Sec-Fetch-Site``
   (when sent) ``same-origin`` or ``none``: 403 otherwise, so no other site's
   page can make a browser reset;
3. ``Content-Type: application/json`` (415 otherwise): a form cannot send it
   without a CORS preflight, which this server never answers;
4. ``Authorization: Bearer <token>``, compared in constant time (401 otherwise).

Only then is the body read, whatever its framing (``Content-Length``, or
``Transfer-Encoding: chunked`` decoded within the same cap; both at once, another
coding, no body: refused), and checked: ``{}`` (all) or ``{"requirement": ID}``,
anything else 400, over ``MAX_BODY`` 413.  The reset is then forwarded to the control
socket the UI's own configuration names (never one a status document names: any
ROS node can publish one), naming the UI and the browser's address; the daemon's
answer is returned as is.  No exception of a handler reaches http.server's
traceback printing: one line on stderr and, where the answer has not begun, a 500.
"""

from __future__ import annotations

import hmac
import ipaddress
import json
import os
import queue
import re
import secrets
import socket
import stat
import sys
import threading
from collections.abc import Callable
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from monitors.errors import UserError
from monitors.untrusted import Untrusted, load_json, printable
from supervisor.tools.reset import request
from supervisor.tools.ui.fleet import Fleet, local_reset_availability
from supervisor.tools.ui.hub import Hub
from supervisor.tools.ui.page import FLEET_PAGE, PAGE

KEEPALIVE_S = 10.0  # an SSE comment this often: a closed browser is noticed, proxies keep it
MAX_BODY = 4096  # a reset's body is {"requirement": ID}: tens of bytes
MAX_REQUIREMENT = 200  # characters of an ID; the control socket's limit of its strings
MAX_CHUNK_LINES = 64  # chunk-size and trailer lines of one chunked body
IO_TIMEOUT_S = 30.0  # a client that stops sending midway is dropped, its thread freed
RESET_TIMEOUT_S = 5.0
VIOLATED_FOR_S = 60.0  # ui --violated-for's default (docs/reference/commands.md, ui)
# A robot's page in the fleet and its stream, state and reset (fleet names: fleet.NAME_RE)
ROBOT_PATH = re.compile(r"/robot/([A-Za-z0-9_.-]+)(/events|/api/state|/api/reset)?")


def reset_availability(socket_path: str | None, token: bytes | None) -> dict[str, Any]:
    """Whether a reset from the page can reach the daemon, and if not why.

    The socket is not connected to: a connection without a request counts as a
    refused call in the daemon's log.  Connecting needs write permission on the
    socket file, which the kernel checks exactly like this."""

    def no(why: str) -> dict[str, Any]:
        return {"available": False, "why": why, "socket": socket_path}

    if token is None:
        return no("no token configured (--token-file)")
    if not socket_path:
        return no("no control socket configured")
    try:
        st = os.stat(socket_path)
    except OSError:
        return no(f"{socket_path}: not on this machine")
    if not stat.S_ISSOCK(st.st_mode):
        return no(f"{socket_path}: not a socket")
    if not os.access(socket_path, os.W_OK):
        return no(f"{socket_path}: permission denied (the UI's user is not in its group)")
    return {"available": True, "why": "", "socket": socket_path}


class HttpError(Exception):
    """A request refused with ``code`` and a one-line ``message``."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message


def allowed_hosts(host: str, port: int) -> Callable[[str], bool]:
    """Which ``Host`` headers name this server: the bound address and localhost
    names for a loopback bind; also this machine's names and any IP address for
    a wildcard or other bind."""
    names = {f"localhost:{port}"}
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        ip = None
        names.add(f"{host}:{port}")
    if ip is not None:
        names.add(f"[{ip}]:{port}" if ip.version == 6 else f"{ip}:{port}")
    wide = ip is None or not ip.is_loopback
    if wide:
        names |= {f"{socket.gethostname()}:{port}", f"{socket.getfqdn()}:{port}"}

    def ok(value: str) -> bool:
        value = value.strip().lower()
        if value in names:
            return True
        if not (wide and ip is not None and ip.is_unspecified):
            return False
        h, _, p = value.rpartition(":")
        try:
            ipaddress.ip_address(h.strip("[]"))
        except ValueError:
            return False
        return p == str(port)

    return ok


def reset_body(data: bytes) -> str | None:
    """The requirement a reset's body names, None for all (``{}``); HttpError (400)
    for anything else, in one line."""
    try:
        body = load_json(data, max_bytes=MAX_BODY, max_depth=2)
    except Untrusted as e:
        raise HttpError(HTTPStatus.BAD_REQUEST, f"the body is {e}") from None
    if not isinstance(body, dict) or not set(body) <= {"requirement"}:
        raise HttpError(HTTPStatus.BAD_REQUEST, 'the body must be {} or {"requirement": "ID"}')
    requirement = body.get("requirement")
    if "requirement" in body and not (
        isinstance(requirement, str) and 0 < len(requirement) <= MAX_REQUIREMENT
    ):
        raise HttpError(
            HTTPStatus.BAD_REQUEST,
            f'"requirement" must be an ID of 1 to {MAX_REQUIREMENT} characters',
        )
    return requirement


class UiServer(ThreadingHTTPServer):
    daemon_threads = True  # an open event stream never holds up the exit
    # socketserver's default listen queue is 5: in a burst of connections the kernel
    # drops the rest and TCP retries them after 1 s, an operator's reset among them.
    request_queue_size = 128

    def __init__(
        self,
        address: tuple[str, int],
        hub: Hub | None,
        token: bytes | None,
        socket_path: Callable[[], str | None],
        fleet: Fleet | None = None,
        violated_for_s: float = VIOLATED_FOR_S,
    ) -> None:
        """``fleet``: the fleet view (then ``hub`` is unused: each robot has its own).
        ``violated_for_s``: how long the page shows a requirement violated after each
        violation (``ui --violated-for``)."""
        try:
            family = socket.AF_INET6 if ipaddress.ip_address(address[0]).version == 6 else None
        except ValueError:
            family = None
        if family is not None:
            self.address_family = family
        super().__init__(address, Handler)
        self.hub = hub
        self.fleet = fleet
        self.violated_for_s = float(violated_for_s)
        self.token = token
        self.socket_path = socket_path
        self.host_ok = allowed_hosts(address[0], self.server_address[1])
        self.stopping = threading.Event()

    def handle_error(self, request: Any, client_address: Any) -> None:
        """One line, never socketserver's traceback: a handler's failure is the UI's
        bug, not something a client may print at length on the operator's terminal."""
        e = sys.exc_info()[1]
        if isinstance(e, OSError):
            return  # the client went away
        print(f"safety-supervisor ui: WARNING: a request from {client_address[0]} failed: "
              f"{type(e).__name__}: {printable(str(e))[:200]}", file=sys.stderr, flush=True)  # fmt: skip

    def url(self) -> str:
        host, port = self.server_address[0], self.server_address[1]
        shown = f"[{host}]" if ":" in str(host) else str(host)
        return f"http://{shown}:{port}/"

    def stop(self) -> None:
        self.stopping.set()
        if self.hub is not None:
            self.hub.close()
        if self.fleet is not None:
            self.fleet.close()
        self.shutdown()
        self.server_close()


class Handler(BaseHTTPRequestHandler):
    server: UiServer
    server_version = "safety-supervisor-ui"
    sys_version = ""
    timeout = IO_TIMEOUT_S

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - the base's name
        pass  # requests are not logged; resets are, below

    # ------------------------------------------------------------ helpers

    def _send(
        self,
        code: int,
        body: bytes,
        ctype: str = "application/json",
        headers: dict[str, str] | None = None,
    ) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("Referrer-Policy", "no-referrer")
        for k, v in (headers or {}).items():
            self.send_header(k, v)
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, code: int, doc: dict[str, Any]) -> None:
        self._send(code, json.dumps(doc).encode())

    def _host_ok(self) -> bool:
        if self.server.host_ok(self.headers.get("Host", "")):
            return True
        self._json(HTTPStatus.MISDIRECTED_REQUEST, {"ok": False, "message": "unknown Host"})
        return False

    def _same_origin(self) -> bool:
        origin = self.headers.get("Origin")
        if origin is not None and origin != f"http://{self.headers.get('Host', '')}":
            return False
        site = self.headers.get("Sec-Fetch-Site")
        return site is None or site in ("same-origin", "none")

    def _authorised(self) -> bool:
        token = self.server.token
        scheme, _, given = self.headers.get("Authorization", "").partition(" ")
        if token is None or scheme.lower() != "bearer":
            return False
        return hmac.compare_digest(given.strip().encode(), token)

    def _guarded(self, handler: Callable[[], None]) -> None:
        """``handler``, with any failure one line on stderr and a 500 if the answer
        has not begun; the connection is then closed."""
        self._answered = False
        try:
            handler()
        except OSError:
            self.close_connection = True  # the client went away, or stopped sending
        except Exception as e:  # noqa: BLE001 - the last guard of a request
            self.close_connection = True
            self.server.handle_error(self.request, self.client_address)
            if not self._answered:
                try:
                    self._json(HTTPStatus.INTERNAL_SERVER_ERROR,
                               {"ok": False, "message": f"internal error ({type(e).__name__})"})  # fmt: skip
                except OSError:
                    pass

    def send_response(self, code: int, message: str | None = None) -> None:
        self._answered = True
        super().send_response(code, message)

    # ------------------------------------------------------------ GET

    def do_GET(self) -> None:  # noqa: N802 - http.server's name
        self._guarded(self._get)

    def _get(self) -> None:
        if not self._host_ok():
            return
        path = self.path.split("?", 1)[0]
        hub = self.server.hub
        if self.server.fleet is not None:
            self._fleet_get(self.server.fleet, path)
        elif hub is None:
            self._not_found()
        elif path == "/":
            self._page()
        elif path == "/events":
            self._events(hub.subscribe, hub.unsubscribe)
        elif path == "/api/state":
            self._json(HTTPStatus.OK, hub.snapshot())
        else:
            self._not_found()

    def _not_found(self) -> None:
        self._json(HTTPStatus.NOT_FOUND, {"ok": False, "message": "not found"})

    def _fleet_get(self, fleet: Fleet, path: str) -> None:
        """The fleet's paths (docs/reference/commands.md, ``ui``, "The fleet")."""
        if path == "/" and fleet.configured == 1:
            # one robot listed: its page is the UI's page, the fleet one click away
            self._send(HTTPStatus.SEE_OTHER, b"", "text/plain",
                       {"Location": f"/robot/{fleet.first().id}"})  # fmt: skip
        elif path in ("/", "/fleet"):
            self._page(FLEET_PAGE)
        elif path == "/fleet/events":
            self._events(fleet.subscribe, fleet.unsubscribe)
        elif path == "/api/fleet":
            self._json(HTTPStatus.OK, fleet.snapshot())
        elif (m := ROBOT_PATH.fullmatch(path)) and (robot := fleet.robot(m[1])) is not None:
            if m[2] is None:
                base = f"/robot/{robot.id}"
                self._page(PAGE.replace("__BASE__", base).replace("__FLEET__", "/fleet"))
            elif m[2] == "/events":
                self._events(robot.hub.subscribe, robot.hub.unsubscribe)
            elif m[2] == "/api/state":
                self._json(HTTPStatus.OK, robot.hub.snapshot())
            else:
                self._not_found()
        else:
            self._not_found()

    def _page(self, page: str = PAGE) -> None:
        nonce = secrets.token_urlsafe(16)
        # Nothing may load from elsewhere; the one inline script runs by its nonce.
        csp = (
            f"default-src 'none'; script-src 'nonce-{nonce}'; style-src 'unsafe-inline'; "
            "connect-src 'self'; img-src 'self' data:; base-uri 'none'; form-action 'none'; "
            "frame-ancestors 'none'"
        )
        # the single robot's page: its stream and reset at /, no fleet to go back to
        page = page.replace("__BASE__", "").replace("__FLEET__", "")
        page = page.replace("__HOLD_S__", repr(self.server.violated_for_s))
        body = page.replace("__NONCE__", nonce).encode()
        self._send(
            HTTPStatus.OK,
            body,
            "text/html; charset=utf-8",
            {"Content-Security-Policy": csp, "X-Frame-Options": "DENY"},
        )

    def _events(
        self,
        subscribe: Callable[[], queue.Queue[str | None]],
        unsubscribe: Callable[[queue.Queue[str | None]], None],
    ) -> None:
        q = subscribe()
        try:
            self.send_response(HTTPStatus.OK)
            self.send_header("Content-Type", "text/event-stream")
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            self.end_headers()
            self.wfile.write(b"retry: 1000\n\n")  # reconnect quickly after a UI restart
            self.wfile.flush()
            while not self.server.stopping.is_set():
                try:
                    line = q.get(timeout=KEEPALIVE_S)
                except queue.Empty:
                    self.wfile.write(b": keepalive\n\n")
                    self.wfile.flush()
                    continue
                if line is None:
                    break
                self.wfile.write(b"data: " + line.encode() + b"\n\n")
                self.wfile.flush()
        except OSError:
            pass  # the browser went away
        finally:
            unsubscribe(q)

    # ------------------------------------------------------------ POST

    def do_POST(self) -> None:  # noqa: N802 - http.server's name
        # a refused request's body is never read: the connection cannot be reused
        self.close_connection = True
        self._guarded(self._post)

    def _post(self) -> None:
        if not self._host_ok():
            return
        path = self.path.split("?", 1)[0]
        fleet = self.server.fleet
        # Where a reset goes: the UI's own configuration, never a status document
        # (docs/reference/ros-interfaces.md, "What the status topic can be trusted for").
        target: tuple[Hub, str | None, dict[str, Any]] | None = None
        if fleet is None and path == "/api/reset" and self.server.hub is not None:
            socket_path = self.server.socket_path()
            target = (
                self.server.hub,
                socket_path,
                reset_availability(socket_path, self.server.token),
            )
        elif fleet is not None and (m := ROBOT_PATH.fullmatch(path)) and m[2] == "/api/reset":
            robot = fleet.robot(m[1])
            if robot is not None:
                state = local_reset_availability(
                    robot.hub.status, robot.socket, self.server.token, reset_availability
                )
                target = (robot.hub, robot.socket, state)
        if target is None:
            self._not_found()
            return
        if not self._same_origin():
            self._json(HTTPStatus.FORBIDDEN, {"ok": False, "message": "cross-origin request"})
            return
        if self.headers.get_content_type() != "application/json":
            self._json(
                HTTPStatus.UNSUPPORTED_MEDIA_TYPE,
                {"ok": False, "message": "Content-Type must be application/json"},
            )
            return
        if not self._authorised():
            self._send(
                HTTPStatus.UNAUTHORIZED,
                json.dumps({"ok": False, "message": "a valid token is needed"}).encode(),
                headers={"WWW-Authenticate": 'Bearer realm="safety-supervisor"'},
            )
            return
        try:
            requirement = reset_body(self._body())
        except HttpError as e:
            self._json(e.code, {"ok": False, "message": e.message})
            return
        self._reset(requirement, *target)

    def _body(self) -> bytes:
        """The request's body, whatever its framing, at most ``MAX_BODY`` bytes."""
        codings = self.headers.get_all("Transfer-Encoding") or []
        lengths = self.headers.get_all("Content-Length") or []
        if codings:
            if lengths:
                # which one a proxy in front honoured is unknown (request smuggling)
                raise HttpError(HTTPStatus.BAD_REQUEST, "both Transfer-Encoding and Content-Length")
            names = [c.strip().lower() for h in codings for c in h.split(",") if c.strip()]
            if names != ["chunked"]:
                raise HttpError(HTTPStatus.NOT_IMPLEMENTED,
                                "only Transfer-Encoding: chunked is understood")  # fmt: skip
            return self._chunked()
        if not lengths:
            raise HttpError(HTTPStatus.BAD_REQUEST, "a reset needs a body ({} for all)")
        text = lengths[0].strip()
        if len(lengths) > 1 or not (text.isascii() and text.isdigit()):
            raise HttpError(HTTPStatus.BAD_REQUEST, "bad Content-Length")
        if int(text) > MAX_BODY:
            raise HttpError(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, f"a body over {MAX_BODY} bytes")
        data = self.rfile.read(int(text))
        if len(data) < int(text):
            raise HttpError(HTTPStatus.BAD_REQUEST, "the body is shorter than its Content-Length")
        return data

    def _chunked(self) -> bytes:
        """A chunked body decoded (RFC 9112, 7.1), within ``MAX_BODY`` bytes."""
        parts: list[bytes] = []
        total = 0
        for _ in range(MAX_CHUNK_LINES):
            line = self.rfile.readline(256)
            size_text = line.split(b";", 1)[0].strip()
            if (
                not line.endswith(b"\n")
                or not size_text
                or not all(c in b"0123456789abcdefABCDEF" for c in size_text)
            ):
                raise HttpError(HTTPStatus.BAD_REQUEST, "a chunk size that is not one")
            size = int(size_text, 16)
            if size == 0:
                break
            total += size
            if total > MAX_BODY:
                raise HttpError(
                    HTTPStatus.REQUEST_ENTITY_TOO_LARGE, f"a body over {MAX_BODY} bytes"
                )
            chunk = self.rfile.read(size + 2)
            if len(chunk) < size + 2 or chunk[size:] != b"\r\n":
                raise HttpError(HTTPStatus.BAD_REQUEST, "a chunk cut short")
            parts.append(chunk[:size])
        else:
            raise HttpError(HTTPStatus.BAD_REQUEST, f"more than {MAX_CHUNK_LINES} chunks")
        for _ in range(MAX_CHUNK_LINES):  # trailer fields, up to the empty line
            line = self.rfile.readline(256)
            if line in (b"\r\n", b"\n"):
                return b"".join(parts)
            if not line.endswith(b"\n"):
                break
        raise HttpError(HTTPStatus.BAD_REQUEST, "a chunked body without its end")

    def _reset(
        self,
        requirement: str | None,
        hub: Hub,
        path: str | None,
        state: dict[str, Any],
    ) -> None:
        client = self.client_address[0]
        if not state["available"] or path is None:
            self._json(HTTPStatus.SERVICE_UNAVAILABLE, {"ok": False, "message": state["why"]})
            return
        # The daemon's reset record names where the reset came from
        # (docs/reference/ros-interfaces.md, "Control socket").
        req: dict[str, Any] = {"command": "reset", "via": "ui", "client": client}
        if requirement is not None:
            req["requirement"] = requirement
        try:
            answer = request(path, req, RESET_TIMEOUT_S)
        except UserError as e:
            self._json(HTTPStatus.SERVICE_UNAVAILABLE, {"ok": False, "message": str(e)})
            return
        message = str(answer.get("message", ""))
        what = f"reset {requirement or 'all'} from {client}"
        # the requirement is the client's and the message the socket's: terminal-safe
        print(f"safety-supervisor ui: {printable(what)}: {printable(message)}", flush=True)
        hub.note(
            {"event": "ui", "requirement": requirement or "*", "what": what, "detail": message}
        )
        self._json(HTTPStatus.OK, {"ok": answer.get("ok") is True, "message": message})
