"""Records to journald with structured fields, over its native protocol.

docs/reference/log.md ("In the systemd journal") lists the fields, the priority of
each record and the setting.  The protocol is systemd's "Native Journal Protocol":
one datagram per entry on ``/run/systemd/journal/socket``, each field ``NAME=value\\n``,
or ``NAME\\n`` + the value's length (64-bit little-endian) + value + ``\\n`` when the
value holds a newline.  An entry too large for one datagram is written to a sealed
memfd whose descriptor is sent instead (SCM_RIGHTS), as libsystemd does.

Hand-written rather than a library: systemd-python needs a build against
libsystemd, cysystemd is a compiled extension too, and both send to libsystemd's
fixed socket path, which tests and containers need to point elsewhere
(``SAFETY_SUPERVISOR_JOURNAL_SOCKET``).  Standard library only, like the reader.
"""

from __future__ import annotations

import errno
import fcntl
import os
import socket
import struct
import threading
from collections.abc import Iterable, Mapping
from typing import Any

from mitigations.violationlog.format import describe

SOCKET_ENV = "SAFETY_SUPERVISOR_JOURNAL_SOCKET"
DEFAULT_SOCKET = "/run/systemd/journal/socket"
IDENTIFIER = "safety-supervisor"

# syslog priorities (journalctl -p): what the operator should look at first.
ERR, WARNING, INFO = 3, 4, 6
_SUPERVISOR_WARNINGS = frozenset(
    {
        "check_warning",
        "input_stale",
        "input_problem",
        "input_publisher_gone",
        "input_rejected",
        "input_nan",
        "input_no_publisher",
        "analysis_skipped",
        "reset_refused",
        "control_unchanged",
    }
)
_SUPERVISOR_ERRORS = frozenset({"internal_error", "records_lost", "control_failed"})


def priority(rec: Mapping[str, Any]) -> int:
    """A record's syslog priority (the mapping is in docs/reference/log.md)."""
    event = rec.get("event")
    if event == "violation":
        return WARNING
    if event == "mitigation":
        # ok false: a failed attempt, or a confirmation whose effect was not seen
        return INFO if rec.get("ok") is True else ERR
    if event == "supervisor":
        what = rec.get("what")
        if what in _SUPERVISOR_ERRORS or rec.get("ok") is False:  # reload ok=false
            return ERR
        if what in _SUPERVISOR_WARNINGS:
            return WARNING
    return INFO


def record_fields(rec: Mapping[str, Any], line: str) -> list[tuple[str, str]]:
    """The journal fields of a record; ``line`` is its JSON line without ``\\n``."""
    fields = [
        ("MESSAGE", describe(dict(rec))),
        ("PRIORITY", str(priority(rec))),
        ("SYSLOG_IDENTIFIER", IDENTIFIER),
        ("EVENT", str(rec.get("event", ""))),
    ]
    if rec.get("requirement") is not None:
        fields.append(("REQUIREMENT", str(rec["requirement"])))
    if rec.get("event") == "supervisor" and rec.get("what") is not None:
        fields.append(("WHAT", str(rec["what"])))
    for name, key in (
        ("SEQ", "seq"),
        ("COMPONENT", "component"),
        ("CONFIG_SHA256", "config_sha256"),
    ):
        if rec.get(key) is not None:
            fields.append((name, str(rec[key])))
    fields.append(("SAFETY_SUPERVISOR_RECORD", line))
    return fields


def encode(fields: Iterable[tuple[str, str | bytes]]) -> bytes:
    """One journal entry in the native protocol."""
    out = bytearray()
    for name, value in fields:
        data = value.encode("utf-8", "replace") if isinstance(value, str) else value
        key = name.encode("ascii")
        if b"\n" in data:
            out += key + b"\n" + struct.pack("<Q", len(data)) + data + b"\n"
        else:
            out += key + b"=" + data + b"\n"
    return bytes(out)


def socket_path(stderr_is_journal: bool) -> str | None:
    """Where to send, or None: the environment variable when set (empty or ``off``:
    never), else the system's socket when stderr is the journal (started by systemd)."""
    configured = os.environ.get(SOCKET_ENV)
    if configured is not None:
        return None if configured.strip() in ("", "off") else configured
    return DEFAULT_SOCKET if stderr_is_journal else None


class JournalSender:
    """Sends entries to one socket path; never raises and never blocks."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.sent = 0
        self.failed = 0
        self.error = ""  # the last failure, for the one report on stderr
        self._lock = threading.Lock()
        self._sock: socket.socket | None = None

    def send(self, fields: Iterable[tuple[str, str | bytes]]) -> bool:
        """True when journald has the entry."""
        data = encode(fields)
        with self._lock:
            try:
                if self._sock is None:
                    # Non-blocking: a congested journald must not delay monitoring;
                    # the entry then goes to stderr and is counted as failed.
                    self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
                    self._sock.setblocking(False)
                try:
                    self._sock.sendto(data, self.path)
                except OSError as e:
                    if e.errno not in (errno.EMSGSIZE, errno.ENOBUFS):
                        raise
                    self._send_memfd(data)
            except OSError as e:
                self.failed += 1
                self.error = e.strerror or str(e)
                return False
            self.sent += 1
            return True

    def _send_memfd(self, data: bytes) -> None:
        """Larger than a datagram: journald reads the entry from a sealed memfd."""
        assert self._sock is not None
        fd = os.memfd_create("journal-entry", os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view) :]
            seals = fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW | fcntl.F_SEAL_WRITE | fcntl.F_SEAL_SEAL
            fcntl.fcntl(fd, fcntl.F_ADD_SEALS, seals)
            # sendmsg, not socket.send_fds: that one drops its address argument (3.11)
            rights = [(socket.SOL_SOCKET, socket.SCM_RIGHTS, struct.pack("i", fd))]
            self._sock.sendmsg([b""], rights, 0, self.path)
        finally:
            os.close(fd)

    def close(self) -> None:
        with self._lock:
            if self._sock is not None:
                self._sock.close()
                self._sock = None
