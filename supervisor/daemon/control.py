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
from supervisor.config.model import ControlConfig
from supervisor.names import OPERATORS_GROUP, daemon_control_socket

COMMANDS = ("reset",)
MAX_FIELD = 200  # characters of requirement, via and client
MAX_REQUEST = 4096  # bytes of one request line
READ_TIMEOUT_S = 2.0  # a client that connects and says nothing is dropped
ANSWER_TIMEOUT_S = 5.0  # the loop answers within one iteration; the watchdog covers a hang
ACCEPT_POLL_S = 0.2  # how soon close() stops the thread
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

    command: str
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

    def answer(self, reply: dict[str, Any]) -> None:
        self.reply = reply
        self._done.set()

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
    """The listening socket and its thread; :meth:`take` is the loop's side."""

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

    # ------------------------------------------------------------ loop side

    def start(self, wake: Callable[[], None]) -> None:
        """Serve on a thread; ``wake()`` is called after each request is queued."""
        self._wake = wake
        self._thread = threading.Thread(target=self._serve, name="control", daemon=True)
        self._thread.start()

    def take(self) -> list[ControlRequest]:
        if not self._queue:
            return []
        with self._lock:
            out = list(self._queue)
            self._queue.clear()
        return out

    def close(self) -> None:
        """Stop serving and remove the socket file; idempotent."""
        if self._stop.is_set():
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2 * ACCEPT_POLL_S + READ_TIMEOUT_S + ANSWER_TIMEOUT_S)
        if self._sock is not None:
            self._sock.close()
        # Remove the file only if it is still ours (not a successor's socket).
        with contextlib.suppress(OSError):
            st = os.stat(self.path)
            if (st.st_dev, st.st_ino) == self._inode:
                os.unlink(self.path)
        for req in self.take():  # never leave a caller waiting on a closed daemon
            req.answer(
                {"ok": False, "refused": "stopping", "message": "the supervisor is stopping"}
            )

    # ------------------------------------------------------------ socket thread

    def _serve(self) -> None:
        assert self._sock is not None
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                if self._stop.is_set():
                    return
                time.sleep(ACCEPT_POLL_S)  # e.g. EMFILE: let descriptors free up
                continue
            with conn:
                with contextlib.suppress(OSError):  # the caller went away: nothing to answer
                    self._handle(conn)

    def _handle(self, conn: socket.socket) -> None:
        conn.settimeout(READ_TIMEOUT_S)
        pid, uid, gid = _UCRED.unpack(
            conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _UCRED.size)
        )
        caller = Caller(pid, uid, gid)
        req = self._parse(_read_line(conn), caller)
        if req.refused is None and not self._authorised(caller):
            req.refused = "permission"
            req.detail = f"uid {uid} may not control the supervisor: " + (
                f"not in group {self.group}" if self.group else "not its user or root"
            )
        with self._lock:
            self._queue.append(req)
        try:
            self._wake()
        except Exception:  # noqa: BLE001 - the node is shutting down; close() answers
            return
        if not req.wait(ANSWER_TIMEOUT_S) or req.reply is None:
            reply: dict[str, Any] = {
                "ok": False,
                "refused": "busy",
                "message": f"the supervisor did not answer within {ANSWER_TIMEOUT_S:g} s",
            }
        else:
            reply = req.reply
        conn.sendall(json.dumps(reply).encode() + b"\n")

    @staticmethod
    def _parse(line: bytes | None, caller: Caller) -> ControlRequest:
        def bad(why: str) -> ControlRequest:
            return ControlRequest("?", caller, refused="bad_request", detail=why)

        if line is None:
            return bad(f"no request line (at most {MAX_REQUEST} bytes, ending in a newline)")
        try:
            doc = json.loads(line)
        except (ValueError, UnicodeDecodeError):
            return bad("the request is not JSON")
        command = doc.get("command") if isinstance(doc, dict) else None
        if command not in COMMANDS:
            return bad(f"unknown command {command!r}; known: {', '.join(COMMANDS)}")
        extra = {k: doc.get(k) for k in ("requirement", "via", "client")}
        for key, value in extra.items():
            if value is not None and (not isinstance(value, str) or len(value) > MAX_FIELD):
                return bad(f"'{key}' must be a string of at most {MAX_FIELD} characters")
        return ControlRequest(str(command), caller, **extra)

    def _authorised(self, c: Caller) -> bool:
        """The same rule the socket file's mode expresses, checked on the peer's
        credentials: the kernel's check is on the file, this one on the caller."""
        if c.uid in (0, os.geteuid()):
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
        try:
            sock.bind(self.path)
            st = os.stat(self.path)
            self._inode = (st.st_dev, st.st_ino)
            if self.gid is not None:
                os.chown(self.path, -1, self.gid)
            os.chmod(self.path, 0o660 if self.gid is not None else 0o600)
            sock.listen(16)
        except OSError as e:
            sock.close()
            hint = None
            if self.gid is not None and e.errno in (errno.EPERM, errno.EINVAL):
                hint = (
                    f"the daemon's user must be a member of group {self.group} "
                    f"(the unit's SupplementaryGroups={self.group})"
                )
            raise fail(f"control socket {self.path}: {e.strerror or e}", hint) from None
        sock.settimeout(ACCEPT_POLL_S)
        self._sock = sock


class _InUse(Exception):
    pass


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


def _read_line(conn: socket.socket) -> bytes | None:
    data = b""
    deadline = time.monotonic() + READ_TIMEOUT_S
    while b"\n" not in data and len(data) <= MAX_REQUEST and time.monotonic() < deadline:
        chunk = conn.recv(MAX_REQUEST + 1 - len(data))
        if not chunk:
            break
        data += chunk
    head, nl, _ = data.partition(b"\n")
    if not nl or len(head) > MAX_REQUEST:
        return None
    return head


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
