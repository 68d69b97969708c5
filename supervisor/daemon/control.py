"""The operator's control socket: authenticated, authorised, rate-limited resets.

A Unix stream socket (``$RUNTIME_DIRECTORY/control.sock`` under systemd, see
:mod:`supervisor.names`).  Who may connect is decided by the kernel from the
socket file's mode (0660 with ``control.group``, else 0600) and checked again
here on the caller's SO_PEERCRED, which also names the caller in the ``reset``
record.  The protocol is one JSON line each way (docs/reference/ros-interfaces.md,
"Control socket").

One small thread accepts connections, reads the request and hands it to the
receive loop (the ``wake`` callback triggers the loop's guard condition), the
way the ROS reset service's requests reach it: the loop is the only thread
that touches the policies.  :class:`ResetGate` and :class:`Refusals` are the
loop's rate limit and its once-per-interval report of refused calls.
"""

from __future__ import annotations

import contextlib
import errno
import grp
import json
import os
import pwd
import selectors
import socket
import stat
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from monitors.untrusted import Untrusted, load_json, printable
from supervisor.config.model import ControlConfig
from supervisor.names import OPERATORS_GROUP, daemon_control_socket

COMMANDS = ("reset", "reload", "status")  # status: read-only, ``safety-supervisor status``
FIELDS = ("command", "requirement", "via", "client")
MAX_FIELD = 200  # characters of requirement, via and client
MAX_REQUEST = 4096  # bytes of one request line
CLIENT_DEADLINE_S = 2.0  # from connect to the request line: a silent or slow client is dropped
ANSWER_TIMEOUT_S = 5.0  # the loop answers within one iteration; the watchdog covers a hang
# A reload is answered when the new config is in force or refused: validation
# (analyses within their time budget) and the compile take seconds, not minutes.
RELOAD_ANSWER_TIMEOUT_S = 300.0
LINGER_S = 1.0  # after the answer: discard what the client still sends, until its EOF
MAX_DISCARD = 1 << 20  # bytes discarded after a request line before the connection ends
MAX_CLIENTS = 256  # connections served at once; the oldest without a request makes room
EVICT_POLL = 32  # clients read (for a request already sent) before one is evicted
SELECT_S = 0.2  # how soon close() stops the thread; the thread's heartbeat
STALL_S = 5.0  # a thread that has not gone round its loop for this long is not serving
BACKLOG = socket.SOMAXCONN  # bursts of connects queue up instead of failing (EAGAIN)
_UCRED = struct.Struct("3i")  # struct ucred: pid, uid, gid


@dataclass(frozen=True)
class Caller:
    """The peer's credentials, from the kernel (SO_PEERCRED at connect time)."""

    pid: int
    uid: int
    gid: int

    def record(self) -> dict[str, Any]:
        out: dict[str, Any] = {"uid": self.uid, "gid": self.gid, "pid": self.pid}
        with contextlib.suppress(KeyError):
            out["user"] = pwd.getpwuid(self.uid).pw_name
        return out


@dataclass
class ControlRequest:
    """One request on its way from the socket thread to the loop and back."""

    command: str  # "reset", "reload" or "status"
    caller: Caller
    refused: str | None = None  # "permission" or "bad_request": the loop only reports it
    requirement: str | None = None  # reset one requirement; None: every one
    # Who asked, as a program that relays operators says it (the UI: "ui" and the
    # browser's address); recorded beside the socket peer's credentials.
    via: str | None = None
    client: str | None = None
    detail: str = ""
    reply: dict[str, Any] | None = None
    _done: threading.Event = field(default_factory=threading.Event)
    # Set by the server: the connection it came on, and how the answer gets back there.
    _client: Any = None
    _on_answer: Callable[[ControlRequest], None] | None = None

    def answer(self, reply: dict[str, Any]) -> None:
        if self._done.is_set():
            return  # answered once (e.g. by close() and by the loop)
        self.reply = reply
        self._done.set()
        if self._on_answer is not None:
            self._on_answer(self)

    def wait(self, timeout: float) -> bool:
        return self._done.wait(timeout)


class ResetGate:
    """At most ``max_resets`` accepted resets in any window of ``interval_ns``.

    The limits are passed on each call, so a reload's new ``control:`` applies
    at once.  Loop thread only."""

    def __init__(self) -> None:
        self._accepted: deque[int] = deque()

    def admit(self, now: int, max_resets: int, interval_ns: int) -> bool:
        while self._accepted and now - self._accepted[0] >= interval_ns:
            self._accepted.popleft()
        if len(self._accepted) >= max_resets:
            return False
        self._accepted.append(now)
        return True


class Refusals:
    """Refused operator calls, counted by reason and reported at most once per
    interval (a flood of calls must not become a flood of records).  Loop thread only."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}
        self.callers: set[str] = set()
        self._last_report: int | None = None

    def add(self, reason: str, caller: str) -> None:
        self.counts[reason] = self.counts.get(reason, 0) + 1
        self.callers.add(caller)

    def due(self, now: int, interval_ns: int) -> dict[str, Any] | None:
        """The summary to report now, if any (and start counting afresh)."""
        if not self.counts:
            return None
        if self._last_report is not None and now - self._last_report < interval_ns:
            return None
        out: dict[str, Any] = {
            "refused": dict(sorted(self.counts.items())),
            "callers": sorted(self.callers),
            "interval_ms": round(interval_ns / 1e6, 3),
        }
        self.counts, self.callers, self._last_report = {}, set(), now
        return out


class ControlServer:
    """The listening socket and its thread; :meth:`take` is the loop's side.

    The thread serves every client at once with a selector: a client has
    ``CLIENT_DEADLINE_S`` from its connect to send its line, a line is at most
    ``MAX_REQUEST`` bytes, and past ``MAX_CLIENTS`` connections one that was
    answered, else the oldest that has not sent its line, is closed (answered
    ``busy``), so idle or slow clients
    never keep an operator's reset waiting.  Whatever one client sends or does
    ends at most that client's connection (docs/reference/ros-interfaces.md,
    "Control socket").  :meth:`alive` and :meth:`health` tell the loop whether
    the thread still serves; :meth:`revive` starts it again."""

    def __init__(self, path: str, group: str | None, gid: int | None) -> None:
        self.path = path
        self.group = group
        self.gid = gid
        self._sock: socket.socket | None = None
        self._inode: tuple[int, int] | None = None
        self._queue: deque[ControlRequest] = deque()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._wake: Callable[[], None] = lambda: None
        # Answers given by the loop, for the socket thread to send (it owns the sockets).
        self._answered: deque[ControlRequest] = deque()
        self._selector: selectors.BaseSelector | None = None
        self._nudge_r: socket.socket | None = None
        self._nudge_w: socket.socket | None = None
        self._clients: dict[int, _Client] = {}  # by file descriptor
        self._beat = 0.0  # monotonic time of the thread's last round
        self.error: str | None = None  # why the thread ended, if it did
        self.restarts = 0
        self.served = 0  # answers sent
        self.evicted = 0  # connections closed to make room (MAX_CLIENTS, EMFILE)
        self.client_errors = 0  # connections ended by an error of their own

    # ------------------------------------------------------------ loop side

    def start(self, wake: Callable[[], None]) -> None:
        """Serve on a thread; ``wake()`` is called after each request is queued."""
        self._wake = wake
        self._launch()

    def take(self) -> list[ControlRequest]:
        if not self._queue:
            return []
        with self._lock:
            out = list(self._queue)
            self._queue.clear()
        return out

    def alive(self) -> bool:
        """The thread runs and went round its loop lately (it never blocks longer
        than ``SELECT_S``)."""
        t = self._thread
        return (
            t is not None
            and t.is_alive()
            and not self._stop.is_set()
            and time.monotonic() - self._beat < STALL_S
        )

    def running(self) -> bool:
        """The thread has not ended (it may be late: :meth:`alive`)."""
        return self._thread is not None and self._thread.is_alive()

    def health(self) -> dict[str, Any]:
        """For the status document: whether it serves, and its counts."""
        return {
            "alive": self.alive(),
            "clients": len(self._clients),
            "served": self.served,
            "evicted": self.evicted,
            "client_errors": self.client_errors,
            "restarts": self.restarts,
            "error": self.error,
        }

    def revive(self) -> bool:
        """Start the thread again after it ended (the listening socket stays);
        False when it still runs or the server is closed."""
        t = self._thread
        if self._stop.is_set() or self._sock is None or (t is not None and t.is_alive()):
            return False
        self.restarts += 1
        self._launch()
        return True

    def close(self) -> None:
        """Stop serving and remove the socket file; idempotent."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._nudge()
        if self._thread is not None:
            self._thread.join(timeout=2 * SELECT_S + 1.0)
        if self._sock is not None:
            self._sock.close()
        # Remove the file only if it is still ours (not a successor's socket).
        with contextlib.suppress(OSError):
            st = os.stat(self.path)
            if (st.st_dev, st.st_ino) == self._inode:
                os.unlink(self.path)
        for req in self.take():  # their clients were answered by the thread
            req.answer(STOPPING)

    # ------------------------------------------------------------ socket thread

    def _launch(self) -> None:
        assert self._sock is not None
        self._selector = selectors.DefaultSelector()
        self._nudge_r, self._nudge_w = socket.socketpair()
        for s in (self._nudge_r, self._nudge_w):
            s.setblocking(False)
        self._selector.register(self._sock, selectors.EVENT_READ, None)
        self._selector.register(self._nudge_r, selectors.EVENT_READ, None)
        self._beat = time.monotonic()
        self._thread = threading.Thread(target=self._serve, name="control", daemon=True)
        self._thread.start()

    def _nudge(self) -> None:
        """Wake the socket thread's select (from the loop, or close())."""
        w = self._nudge_w
        if w is not None:
            with contextlib.suppress(OSError):  # full: a wake-up is pending anyway
                w.send(b"\0")

    def _on_answer(self, req: ControlRequest) -> None:
        self._answered.append(req)
        self._nudge()

    def _serve(self) -> None:
        sel, nudge = self._selector, self._nudge_r
        assert sel is not None and nudge is not None
        try:
            while not self._stop.is_set():
                self._beat = now = time.monotonic()
                soonest = min((c.deadline for c in self._clients.values()), default=now + SELECT_S)
                for key, events in sel.select(max(0.0, min(SELECT_S, soonest - now))):
                    if key.fileobj is self._sock:
                        self._accept()
                    elif key.fileobj is nudge:
                        with contextlib.suppress(OSError):
                            nudge.recv(4096)
                    else:
                        self._guard(key.data, lambda c, ev=events: c.on_events(self, ev))
                while self._answered:
                    req = self._answered.popleft()
                    client = req._client
                    if isinstance(client, _Client) and self._clients.get(client.fd) is client:
                        self._guard(client, lambda c, r=req: c.on_answer(self, r))
                now = time.monotonic()
                for client in [c for c in self._clients.values() if now >= c.deadline]:
                    self._guard(client, lambda c: c.on_deadline(self))
        except BaseException as e:  # noqa: BLE001 - recorded; the loop sees alive() False
            self.error = f"{type(e).__name__}: {e}"[:300]
        finally:
            self._shutdown()

    def _guard(self, client: _Client, step: Callable[[_Client], None]) -> None:
        """One client's step; whatever it raises ends that client only."""
        try:
            step(client)
        except Exception:  # noqa: BLE001 - a peer's doing (EPIPE...) or a bug: one client
            self.client_errors += 1
            self._drop(client)

    def _accept(self) -> None:
        assert self._sock is not None
        for _ in range(64):  # a burst; the rest next round, so answers are not held up
            try:
                conn, _ = self._sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as e:
                if e.errno in (errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM):
                    if not self._evict():  # no waiting client to make room: next round
                        return
                    continue
                return  # ECONNABORTED and the like: that connection is gone
            try:
                self._admit(conn)
            except OSError:
                conn.close()

    def _admit(self, conn: socket.socket) -> None:
        conn.setblocking(False)
        pid, uid, gid = _UCRED.unpack(
            conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _UCRED.size)
        )
        if len(self._clients) >= MAX_CLIENTS:
            self._evict()
        client = _Client(conn, Caller(pid, uid, gid), time.monotonic() + CLIENT_DEADLINE_S)
        self._clients[client.fd] = client
        assert self._selector is not None
        self._selector.register(conn, selectors.EVENT_READ, client)

    def _evict(self) -> bool:
        """Make room for a new connection: close one that was answered already
        (lingering), else the oldest that has not sent a line, after reading
        what it has sent (a request already there is served, not evicted;
        nothing unread is left to turn the close into a connection reset)."""
        clients = list(self._clients.values())
        answered = [c for c in clients if c.state == "lingering"]
        if answered:
            self.evicted += 1
            self._drop(min(answered, key=lambda c: c.deadline))
            return True
        reading = sorted((c for c in clients if c.state == "reading"), key=lambda c: c.deadline)
        for c in reading[:EVICT_POLL]:
            self._guard(c, lambda c: c.poll(self))
            if self._clients.get(c.fd) is not c:
                return True  # it failed while read: closed, room made
            if c.state == "reading":
                self.evicted += 1
                c.reply(self, _busy(f"more than {MAX_CLIENTS} clients at once"))
                self._drop(c)
                return True
        return False

    def _submit(self, client: _Client, req: ControlRequest) -> None:
        """Hand a request to the loop; the answer comes back through _on_answer."""
        if req.refused is None and not self._authorised(req.caller):
            req.refused = "permission"
            req.detail = f"uid {req.caller.uid} may not control the supervisor: " + (
                f"not in group {self.group}" if self.group else "not its user or root"
            )
        elif req.refused is None and req.command == "reload" and not _itself(req.caller):
            # Operators reset; the config is the service's (systemctl reload runs
            # ExecReload as the unit's user), so only that user and root reload.
            req.refused = "permission"
            req.detail = (
                f"uid {req.caller.uid} may not reload the supervisor: only its user or root"
            )
        req._client = client
        req._on_answer = self._on_answer
        with self._lock:
            self._queue.append(req)
        try:
            self._wake()
        except Exception:  # noqa: BLE001 - the node is shutting down; close() answers
            pass

    def _drop(self, client: _Client) -> None:
        if self._clients.get(client.fd) is client:
            del self._clients[client.fd]
        if self._selector is not None and client.events:
            with contextlib.suppress(Exception):
                self._selector.unregister(client.sock)
        client.events = 0
        client.sock.close()

    def _shutdown(self) -> None:
        """The thread's end: every client still connected gets an answer."""
        answer = STOPPING if self._stop.is_set() else _busy("its control thread failed")
        for client in list(self._clients.values()):
            with contextlib.suppress(Exception):
                if client.state in ("reading", "waiting"):
                    client.reply(self, answer)
            self._drop(client)
        for s in (self._nudge_r, self._nudge_w, self._selector):
            if s is not None:
                with contextlib.suppress(Exception):
                    s.close()
        self._nudge_w = None

    @staticmethod
    def _parse(line: bytes | None, caller: Caller) -> ControlRequest:
        """The one schema check of a request line: a JSON object of at most
        ``MAX_REQUEST`` bytes with a known ``command`` and, optionally,
        ``requirement``, ``via`` and ``client`` as short printable strings."""

        def bad(why: str) -> ControlRequest:
            return ControlRequest("?", caller, refused="bad_request", detail=why)

        if line is None:
            return bad(f"no request line (at most {MAX_REQUEST} bytes, ending in a newline)")
        try:
            doc = load_json(line, max_bytes=MAX_REQUEST, max_depth=2)
        except Untrusted as e:
            return bad(f"the request is {e}" if str(e).startswith("not ") else f"request {e}")
        if not isinstance(doc, dict):
            return bad('the request must be an object, e.g. {"command": "reset"}')
        unknown = sorted(k for k in doc if k not in FIELDS)
        if unknown:
            return bad(f"unknown field {_shown(unknown[0])}; known: {', '.join(FIELDS)}")
        command = doc.get("command")
        if command not in COMMANDS:
            return bad(f"unknown command {_shown(command)}; known: {', '.join(COMMANDS)}")
        if command in ("reload", "status") and doc.get("requirement") is not None:
            return bad(f"'requirement' belongs to reset; {command} is about the whole supervisor")
        extra = {k: doc.get(k) for k in FIELDS if k != "command"}
        for key, value in extra.items():
            if value is not None and not (
                isinstance(value, str) and 0 < len(value) <= MAX_FIELD and value.isprintable()
            ):
                return bad(f"'{key}' must be a string of 1 to {MAX_FIELD} printable characters")
        return ControlRequest(str(command), caller, **extra)

    def _authorised(self, c: Caller) -> bool:
        """The same rule the socket file's mode expresses, checked on the peer's
        credentials: the kernel's check is on the file, this one on the caller."""
        if _itself(c):
            return True
        if self.gid is None:
            return False
        if c.gid == self.gid:
            return True
        try:
            return self.gid in os.getgrouplist(pwd.getpwuid(c.uid).pw_name, c.gid)
        except (KeyError, OSError):
            return False

    # ------------------------------------------------------------ opening

    def open(self, file: str, line: int | None) -> None:
        """Bind and listen; raises UserError (at the config's ``control:`` line)."""

        def fail(msg: str, hint: str | None = None) -> UserError:
            return UserError(msg, file=file, line=line, hint=hint)

        path = Path(self.path)
        try:
            if not path.parent.is_dir():
                # Traversable by the group's members only if there is a group.
                path.parent.mkdir(mode=0o711 if self.gid is not None else 0o700, parents=True)
            owner = os.stat(path.parent).st_uid
            if owner not in (0, os.geteuid()):  # e.g. a directory planted in /tmp
                raise fail(
                    f"control socket {self.path}: its directory belongs to uid {owner}, "
                    "not to this user",
                    hint="set control.socket to a directory of your own",
                )
            _clear_stale(self.path)
        except OSError as e:
            raise fail(f"control socket {self.path}: {e.strerror or e}") from None
        except _InUse as e:
            raise fail(
                f"control socket {self.path} is in use by another running supervisor",
                hint="stop it, or give this one its own control.socket",
            ) from e
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        call = "bind"
        try:
            sock.bind(self.path)
            st = os.stat(self.path)
            self._inode = (st.st_dev, st.st_ino)
            if self.gid is not None:
                call = "chown"
                os.chown(self.path, -1, self.gid)
            call = "chmod"
            os.chmod(self.path, 0o660 if self.gid is not None else 0o600)
            call = "listen"
            sock.listen(BACKLOG)
        except OSError as e:
            sock.close()
            raise fail(
                f"control socket {self.path}: {call}: {e.strerror or e}",
                self._hint(call, e.errno),
            ) from None
        sock.setblocking(False)
        self._sock = sock

    def _hint(self, call: str, err: int | None) -> str | None:
        """Why ``call`` was refused.  chown of one's own file to a group one is
        in needs no privilege, so EPERM then comes from a sandbox (a seccomp
        filter such as SystemCallFilter=~@privileged, which holds @chown), not
        from the group (docs/reference/ros-interfaces.md, systemd)."""
        if call != "chown" or self.gid is None or err not in (errno.EPERM, errno.EINVAL):
            return None
        if self.gid in os.getgroups() or self.gid == os.getegid():
            return (
                f"this process is in group {self.group}, so a sandbox refused chown: "
                "the unit's SystemCallFilter= must allow @chown"
            )
        return (
            f"the daemon's user must be a member of group {self.group} "
            f"(the unit's SupplementaryGroups={self.group})"
        )


class _InUse(Exception):
    pass


def _itself(c: Caller) -> bool:
    """The caller is root or the daemon's own user."""
    return c.uid in (0, os.geteuid())


def _clear_stale(path: str) -> None:
    """Remove a socket left by a supervisor that died; refuse a live one or a non-socket."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(st.st_mode):
        raise OSError(errno.EEXIST, "exists and is not a socket")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.settimeout(1.0)
        probe.connect(path)
    except (ConnectionRefusedError, FileNotFoundError):
        os.unlink(path)  # nobody listens: a leftover
        return
    except OSError:
        raise _InUse() from None  # e.g. a full backlog: someone is there
    finally:
        probe.close()
    raise _InUse()


STOPPING: dict[str, Any] = {
    "ok": False,
    "refused": "stopping",
    "message": "the supervisor is stopping",
}


def _busy(why: str) -> dict[str, Any]:
    return {"ok": False, "refused": "busy", "message": f"the supervisor is busy: {why}; try again"}


def _shown(value: Any) -> str:
    """A client's value inside an answer: short, one line, no control characters."""
    text = repr(value)
    return printable(text if len(text) <= 40 else text[:37] + "...")


class _Client:
    """One connection: reading its line, waiting for the loop's answer, writing
    it, then discarding what the client still sends until its EOF (closing with
    unread data would reset the connection instead of ending it)."""

    def __init__(self, sock: socket.socket, caller: Caller, deadline: float) -> None:
        self.sock = sock
        self.fd = sock.fileno()
        self.caller = caller
        self.deadline = deadline
        self.wait = ANSWER_TIMEOUT_S  # for the loop's answer, once the request is read
        self.state = "reading"  # -> waiting -> writing -> lingering
        self.events = selectors.EVENT_READ  # what the selector watches for it
        self.eof = False  # the client closed its side
        self.buf = bytearray()
        self.out = b""
        self.discarded = 0

    def watch(self, srv: ControlServer, events: int) -> None:
        """Watch for ``events`` (0: none, e.g. at EOF while the loop answers)."""
        sel = srv._selector
        if sel is None or events == self.events:
            return
        if self.events and events:
            sel.modify(self.sock, events, self)
        elif events:
            sel.register(self.sock, events, self)
        else:
            sel.unregister(self.sock)
        self.events = events

    def on_events(self, srv: ControlServer, events: int) -> None:
        if events & selectors.EVENT_READ:
            self._read(srv)
        if self.state == "writing" and events & selectors.EVENT_WRITE:
            self._write(srv)

    def poll(self, srv: ControlServer) -> None:
        """Read what the client has sent so far, if anything (for _evict)."""
        with contextlib.suppress(BlockingIOError):
            self._read(srv)

    def _read(self, srv: ControlServer) -> None:
        if self.state == "reading":
            chunk = self.sock.recv(MAX_REQUEST + 1 - len(self.buf))
            if not chunk:  # EOF before a newline: say so, the client may still read
                self.eof = True
                self.watch(srv, 0)
                got = len(self.buf)
                self._request(srv, None, f"the connection ended after {got} bytes, no newline")
                return
            self.buf += chunk
            end = self.buf.find(b"\n")
            if end >= 0:
                self._request(srv, bytes(self.buf[:end]), None)
            elif len(self.buf) > MAX_REQUEST:
                self._request(srv, None, f"a request line longer than {MAX_REQUEST} bytes")
            return
        chunk = self.sock.recv(65536)  # after the line: discarded
        if not chunk:
            self.eof = True
            if self.state == "lingering":
                srv._drop(self)
            else:
                self.watch(srv, self.events & ~selectors.EVENT_READ)
            return
        self.discarded += len(chunk)
        if self.discarded > MAX_DISCARD:
            srv._drop(self)

    def _request(self, srv: ControlServer, line: bytes | None, why: str | None) -> None:
        if why is None:
            req = ControlServer._parse(line, self.caller)
        else:
            req = ControlRequest("?", self.caller, refused="bad_request", detail=why)
        self.buf = bytearray()
        self.state = "waiting"
        self.wait = RELOAD_ANSWER_TIMEOUT_S if req.command == "reload" else ANSWER_TIMEOUT_S
        self.deadline = time.monotonic() + self.wait
        srv._submit(self, req)

    def on_answer(self, srv: ControlServer, req: ControlRequest) -> None:
        if self.state == "waiting":
            self.reply(srv, req.reply or _busy("no answer"))

    def on_deadline(self, srv: ControlServer) -> None:
        if self.state == "reading":
            got = f" ({len(self.buf)} bytes without a newline)" if self.buf else ""
            why = f"no complete request line within {CLIENT_DEADLINE_S:g} s{got}"
            self._request(srv, None, why)
        elif self.state == "waiting":
            self.reply(srv, _busy(f"no answer within {self.wait:g} s"))
        else:  # writing or lingering: the client does not read or does not close
            srv._drop(self)

    def reply(self, srv: ControlServer, answer: dict[str, Any]) -> None:
        self.out = json.dumps(answer).encode() + b"\n"
        self.state = "writing"
        self.deadline = time.monotonic() + LINGER_S
        self._write(srv)

    def _write(self, srv: ControlServer) -> None:
        try:
            n = self.sock.send(self.out)
        except BlockingIOError:
            n = 0
        self.out = self.out[n:]
        reading = 0 if self.eof else selectors.EVENT_READ
        if self.out:
            self.watch(srv, reading | selectors.EVENT_WRITE)
            return
        srv.served += 1
        if self.eof:
            srv._drop(self)
            return
        self.sock.shutdown(socket.SHUT_WR)  # the answer is complete: EOF for the client
        self.state = "lingering"
        self.watch(srv, reading)


def open_control(cfg: ControlConfig) -> ControlServer:
    """The control socket of ``cfg`` (``control:``), bound and listening."""
    path = cfg.socket or daemon_control_socket()
    group = cfg.group
    if group is None and os.environ.get("RUNTIME_DIRECTORY"):
        group = OPERATORS_GROUP  # the unit's SupplementaryGroups=
    gid = None
    if group is not None:
        try:
            gid = grp.getgrnam(group).gr_gid
        except KeyError:
            raise UserError(
                f"control.group '{group}' does not exist on this machine",
                file=cfg.file,
                line=cfg.group_line,
                hint="create it (install-service does: groupadd --system "
                f"{group}) or set control.group",
            ) from None
    server = ControlServer(path, group, gid)
    server.open(cfg.file, cfg.socket_line if cfg.socket else cfg.line)
    return server
