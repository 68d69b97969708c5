"""The HTTP half of the control soak (:mod:`supervisor.tools.bench.control`): the real
``safety-supervisor ui`` against the soak's daemon, hostile HTTP clients, and the
operator's reset through the page's endpoint.

Every attack is one connection (or a burst of them) of a random kind: random bytes,
random methods, paths and headers, bodies with a wrong or missing Content-Length,
chunked framing valid and broken, huge bodies, deep JSON, slowloris headers and
bodies, bad or missing tokens, a foreign Origin or Host, Server-Sent Events
subscribers that stall, many connections at once.  No attack sends a request that
may reset (the right token, same-origin headers and a valid body together), so
every ``reset`` record whose ``via`` is ``ui`` in the daemon's log is an operator's
probe: an attack that got through shows as a record too many, and a reset answered
but lost as one too few.  docs/BENCHMARKS.md, "Control socket and UI soak".
"""

from __future__ import annotations

import http.client
import json
import random
import socket
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from supervisor.tools.bench.session import Session
from supervisor.tools.bench.ui import HOST, UiChild, free_port
from supervisor.tools.children import Child

HTTP_KINDS = (
    "bytes", "method", "headers", "length", "chunked", "chunked_bad", "huge", "deep",
    "slowloris", "token", "origin", "sse", "many", "pipeline",
)  # fmt: skip
# Bodies that are valid JSON objects but no reset (the schema refuses each)
BAD_BODIES = (b"null", b"[]", b'"x"', b"{", b'{"requirement": 5}', b'{"requirement": ""}',
              b'{"requirement": "x", "all": 1}', b'{"requirement": null}', b"\xff\xfe{}")  # fmt: skip
JUNK_HEADERS = ("X-A", "Cookie", "Range", "Expect", "Upgrade", "Connection", "Accept",
                "Transfer-Encoding", "Content-Length", "If-None-Match", "\x00", "A b")  # fmt: skip
JUNK_VALUES = ("", "\x1b[2J", "100-continue", "websocket", "keep-alive, Upgrade", "bytes=0-",
               "x" * 9000, "-1", "9" * 40, "chunked", "\u202e", "close")  # fmt: skip
ATTACK_TIMEOUT_S = 45.0  # above the UI's own 30 s I/O timeout: it drops first


class SoakUi(UiChild):
    """The ``ui`` under soak (:class:`UiChild` with ``--socket``: it resets through
    the soak's daemon), and the headers the page's ``fetch`` sends with a reset
    (docs/reference/commands.md, ``ui``)."""

    def __init__(self, s: Session, work: Path, control_socket: str) -> None:
        self.socket = control_socket
        super().__init__(s, work, free_port())
        self.host = f"{HOST}:{self.port}"
        self.secret = self.token.read_text().strip()

    def start(self) -> Child:
        self.started += 1
        argv = [sys.executable, "-m", "supervisor", "ui", "--bind", f"{HOST}:{self.port}"]
        argv += ["--token-file", str(self.token), "--socket", self.socket]
        self.child = Child("ui", argv, env=self.s.env, cwd=self.work, stderr=self.stderr_path())
        self.s.children.append(self.child)  # killed with the session whatever happens
        return self.child

    def stderr_path(self) -> Path:
        return self.work / f"ui-{self.started}.stderr"

    def page_headers(self) -> dict[str, str]:
        """What Chromium sends with the page's reset ``fetch``."""
        return {
            "Host": self.host,
            "Origin": f"http://{self.host}",
            "Sec-Fetch-Site": "same-origin",
            "Content-Type": "application/json",
            "Authorization": f"Bearer {self.secret}",
        }

    def reset(self, body: dict[str, Any], timeout: float) -> tuple[int, dict[str, Any]]:
        """The operator's reset through the page's endpoint: (HTTP status, answer)."""
        conn = http.client.HTTPConnection(HOST, self.port, timeout=timeout)
        try:
            conn.request("POST", "/api/reset", json.dumps(body).encode(), self.page_headers())
            answer = conn.getresponse()
            return answer.status, json.loads(answer.read())
        finally:
            conn.close()


def listen_overflows() -> int | None:
    """The kernel's count of connections dropped for a full accept queue, machine-wide
    (TcpExt ListenOverflows): an operator's connect then waits for its SYN's
    retransmission, 1 s later."""
    try:
        lines = Path("/proc/net/netstat").read_text().splitlines()
    except OSError:
        return None
    for names, values in zip(lines[::2], lines[1::2], strict=False):
        if names.startswith("TcpExt:"):
            row = dict(zip(names.split()[1:], values.split()[1:], strict=False))
            return int(row["ListenOverflows"]) if "ListenOverflows" in row else None
    return None


def _request(method: str, path: str, headers: list[tuple[str, str]], body: bytes = b"") -> bytes:
    head = f"{method} {path} HTTP/1.1\r\n" + "".join(f"{k}: {v}\r\n" for k, v in headers)
    return head.encode("utf-8", "surrogateescape") + b"\r\n" + body


def _chunked(body: bytes, rnd: random.Random) -> bytes:
    out, i = b"", 0
    while i < len(body):
        n = rnd.randint(1, max(1, len(body) - i))
        out += f"{n:x}\r\n".encode() + body[i : i + n] + b"\r\n"
        i += n
    return out + b"0\r\n\r\n"


def _status(sock: socket.socket) -> str:
    """The first answer's status code, or how the connection ended without one."""
    data = b""
    try:
        while b"\r\n" not in data and len(data) < 4096:
            part = sock.recv(4096)
            if not part:
                break
            data += part
    except TimeoutError:
        return "client_timeout"
    except OSError as e:
        return type(e).__name__
    parts = data.split(b" ", 2)
    if len(parts) > 1 and parts[0].startswith(b"HTTP/") and parts[1].isdigit():
        return parts[1].decode()
    return "closed" if not data else "no_status_line"


class Attacker:
    """One attacking thread's connections against the ``ui`` at ``side``."""

    def __init__(self, side: SoakUi, seed: int, stop: threading.Event) -> None:
        self.side = side
        self.rnd = random.Random(seed)
        self.stop = stop  # holding a connection ends early when the soak ends

    def _connect(self) -> socket.socket:
        s = socket.create_connection((HOST, self.side.port), timeout=ATTACK_TIMEOUT_S)
        s.settimeout(ATTACK_TIMEOUT_S)
        return s

    def _reset_headers(self, **over: str | None) -> list[tuple[str, str]]:
        """The page's reset headers with ``over`` replaced (None: left out)."""
        h = {**self.side.page_headers(), "Connection": "close", **over}
        return [(k, v) for k, v in h.items() if v is not None]

    def _bad_auth(self) -> dict[str, str | None]:
        t = self.side.secret
        return {"Authorization": self.rnd.choice([None, "", "Bearer", "Bearer ", f"Basic {t}",
                f"Bearer {t}x", f"Bearer {t[:-1]}", f"bearer{t}", "Bearer " + "a" * 64,
                f"Bearer {t}\x00", f"Bearer {t.upper()}"])}  # fmt: skip

    def attack(self, kind: str) -> tuple[str, bool]:
        """(outcome, whether a request that could have reset got a 200)."""
        conns: list[socket.socket] = []
        try:
            s = self._connect()
            conns.append(s)
            if kind == "sse":
                return self._sse(s), False
            # each sender: whether its request could have reset; any other kind: pipeline
            send = self._senders().get(kind, self._send_pipeline)
            could_reset = send(s, conns)
            outcome = _status(s)
            return outcome, could_reset and outcome == "200"
        except TimeoutError:
            return "client_timeout", False
        except OSError as e:
            return type(e).__name__, False
        finally:
            for c in conns:
                c.close()

    def _senders(self) -> dict[str, Callable[[socket.socket, list[socket.socket]], bool]]:
        """The kinds that send one request (or many) and read its status."""
        return {
            "bytes": self._send_bytes,
            "method": self._send_method,
            "headers": self._send_headers,
            "length": self._send_length,
            "chunked": self._send_chunked,
            "chunked_bad": self._send_chunked_bad,
            "huge": self._send_huge,
            "deep": self._send_deep,
            "slowloris": self._send_slowloris,
            "token": self._send_token,
            "origin": self._send_origin,
            "many": self._send_many,
        }

    def _send_bytes(self, s: socket.socket, conns: list[socket.socket]) -> bool:
        rnd = self.rnd
        s.sendall(rnd.randbytes(rnd.randint(1, 20000)))
        s.shutdown(socket.SHUT_WR)
        return False

    def _send_method(self, s: socket.socket, conns: list[socket.socket]) -> bool:
        rnd = self.rnd
        method = rnd.choice(["GET", "POST", "PUT", "HEAD", "DELETE", "OPTIONS", "BREW",
                             "CONNECT", "TRACE", "G\x00T", "PATCH"])  # fmt: skip
        path = rnd.choice(["/", "/api/reset", "/api/state", "/events", "/robot/a/api/reset",
                           "//api/reset", "/%00", "/" + "a" * 70000, "*", "/../etc/passwd",
                           "http://evil/api/reset", "/api/reset?x=1", "/\x1b[2J"])  # fmt: skip
        s.sendall(_request(method, path, [("Host", self.side.host), ("Connection", "close")]))
        return method == "POST" and "reset" in path  # no token: never a reset

    def _send_headers(self, s: socket.socket, conns: list[socket.socket]) -> bool:
        rnd = self.rnd
        headers = [("Host", self.side.host)]
        for _ in range(rnd.choice([1, 5, 20, 150])):
            headers.append((rnd.choice(JUNK_HEADERS), rnd.choice(JUNK_VALUES)))
        s.sendall(_request(rnd.choice(["GET", "POST"]), "/api/reset", headers))
        s.shutdown(socket.SHUT_WR)
        return True

    def _send_length(self, s: socket.socket, conns: list[socket.socket]) -> bool:
        rnd = self.rnd
        # the right token, a body that is no reset, framed wrongly
        body = rnd.choice(BAD_BODIES)
        length = rnd.choice([None, "", "-1", "1e3", "0x10", " 5", "5, 5",
                             str(len(body) + rnd.randint(1, 100)), str(len(body))])  # fmt: skip
        s.sendall(
            _request(
                "POST",
                "/api/reset",
                self._reset_headers(**{"Content-Length": length}),
                body,
            )
        )
        s.shutdown(socket.SHUT_WR)
        return True

    def _send_chunked(self, s: socket.socket, conns: list[socket.socket]) -> bool:
        rnd = self.rnd
        body = rnd.choice(BAD_BODIES)
        h = self._reset_headers(**{"Transfer-Encoding": "chunked"})
        s.sendall(_request("POST", "/api/reset", h, _chunked(body, rnd)))
        return True

    def _send_chunked_bad(self, s: socket.socket, conns: list[socket.socket]) -> bool:
        rnd = self.rnd
        body = rnd.choice([b"{}", b'{"requirement": "x"}'])
        te, cl = "chunked", None
        framing = rnd.choice(["size", "short", "noend", "many", "both", "gzip", "ext"])
        if framing == "size":
            data = b"zz\r\n" + body + b"\r\n0\r\n\r\n"
        elif framing == "short":
            data = b"40\r\n" + body
        elif framing == "noend":
            data = _chunked(body, rnd)[:-5]
        elif framing == "many":
            data = b"1\r\n \r\n" * 100 + b"0\r\n\r\n"
        elif framing == "both":
            data, cl = _chunked(body, rnd), "2"
        elif framing == "gzip":
            data, te = _chunked(body, rnd), "gzip, chunked"
        else:
            data = b"2;" + b"e" * 300 + b"\r\n{}\r\n0\r\n\r\n"
        h = self._reset_headers(**{"Transfer-Encoding": te, "Content-Length": cl})
        s.sendall(_request("POST", "/api/reset", h, data))
        s.shutdown(socket.SHUT_WR)
        return True

    def _send_huge(self, s: socket.socket, conns: list[socket.socket]) -> bool:
        rnd = self.rnd
        chunked = rnd.random() < 0.5
        h = self._reset_headers(
            **({"Transfer-Encoding": "chunked"} if chunked else {"Content-Length": str(10**9)})
        )
        s.sendall(_request("POST", "/api/reset", h))
        block = (b"1000\r\n" + b"x" * 4096 + b"\r\n") if chunked else b"x" * 65536
        try:
            for _ in range(rnd.randint(1, 200)):  # up to 13 MB, until refused
                s.sendall(block)
        except OSError:
            pass  # the UI answered 413 and closed: what it should do
        return True

    def _send_deep(self, s: socket.socket, conns: list[socket.socket]) -> bool:
        rnd = self.rnd
        n = rnd.randint(100, 2000)
        body = rnd.choice([b'{"requirement": ' + b"[" * n + b"]" * n + b"}", b"[" * 4000])
        h = self._reset_headers(**{"Content-Length": str(len(body))})
        s.sendall(_request("POST", "/api/reset", h, body))
        return True

    def _send_slowloris(self, s: socket.socket, conns: list[socket.socket]) -> bool:
        rnd = self.rnd
        # a request's head or body a byte at a time, or half a head then silence
        body = rnd.choice(BAD_BODIES)
        data = _request(
            "POST",
            "/api/reset",
            self._reset_headers(**{"Content-Length": str(len(body))}),
            body,
        )
        if rnd.random() < 0.5:
            for b in data[: rnd.randint(5, len(data))]:
                s.sendall(bytes([b]))
                self.stop.wait(rnd.uniform(0.05, 0.5))
        else:
            s.sendall(data[: rnd.randint(5, len(data) - 1)])
            self.stop.wait(rnd.uniform(1, 35))
        s.shutdown(socket.SHUT_WR)
        return True

    def _send_token(self, s: socket.socket, conns: list[socket.socket]) -> bool:
        rnd = self.rnd
        body = rnd.choice([b"{}", b'{"requirement": "state_req103"}'])
        h = self._reset_headers(**{"Content-Length": str(len(body))}, **self._bad_auth())
        s.sendall(_request("POST", "/api/reset", h, body))
        return True

    def _send_origin(self, s: socket.socket, conns: list[socket.socket]) -> bool:
        rnd = self.rnd
        # the right token and body, but another site's page, host or content type
        body = b"{}"
        over: dict[str, str | None] = {"Content-Length": "2"}
        over.update(rnd.choice([
            {"Origin": "http://evil.example"}, {"Origin": "null"},
            {"Origin": f"http://{self.side.host}.evil"}, {"Sec-Fetch-Site": "cross-site"},
            {"Sec-Fetch-Site": "same-site"}, {"Host": "evil.example"},
            {"Host": f"evil:{self.side.port}"}, {"Host": None},
            {"Content-Type": "text/plain"}, {"Content-Type": None},
            {"Content-Type": "application/x-www-form-urlencoded"},
        ]))  # fmt: skip
        s.sendall(_request("POST", "/api/reset", self._reset_headers(**over), body))
        return True

    def _send_many(self, s: socket.socket, conns: list[socket.socket]) -> bool:
        rnd = self.rnd
        for _ in range(rnd.randint(20, 120)):
            c = self._connect()
            conns.append(c)
            c.sendall(
                rnd.choice([b"", b"GET / HTTP/1.1\r\n", b"POST /api/reset HTTP/1.1\r\nHost: "])
            )
        self.stop.wait(rnd.uniform(0.1, 2))
        s.sendall(
            _request("GET", "/api/state", [("Host", self.side.host), ("Connection", "close")])
        )
        return False

    def _send_pipeline(self, s: socket.socket, conns: list[socket.socket]) -> bool:
        """Several requests on one keep-alive connection."""
        rnd = self.rnd
        reqs = b"".join(
            _request(
                rnd.choice(["GET", "HEAD"]),
                rnd.choice(["/", "/api/state", "/nope"]),
                [("Host", self.side.host)],
            )  # fmt: skip
            for _ in range(rnd.randint(2, 30))
        )
        s.sendall(reqs)
        s.shutdown(socket.SHUT_WR)
        return False

    def _sse(self, s: socket.socket) -> str:
        rnd = self.rnd
        # subscribe, read a little, then stop reading for a while
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        path = rnd.choice(["/events", "/events", "/robot/a/events"])
        s.sendall(
            _request("GET", path, [("Host", self.side.host), ("Accept", "text/event-stream")])
        )
        outcome = _status(s)
        self.stop.wait(rnd.uniform(0.5, 20))
        return f"{outcome}_stalled"
