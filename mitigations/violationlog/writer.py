"""The violation log writer (docs/reference/log.md).

JSON lines rendered by a structlog processor chain; the format, the hash chain
(``prev_sha256``, ``line_sha256``), its semantics across rotation and the
encoding of NaN/inf are documented in :mod:`mitigations.violationlog.format`; the reader
verifies them.

Writing: the file is opened ``O_WRONLY|O_APPEND|O_CREAT`` (mode 0640); each
line is rendered completely and written with one ``os.write`` under a lock,
so threads never interleave partial lines.  ``violation`` and ``mitigation``
return only after ``os.fsync``: the contract requires a violation to be on
disk before its mitigations run.  A failure to write is reported on stderr
and counted (``failed_writes``) but never raised: the daemon must keep
monitoring with a full disk.  Only opening the log raises (``UserError``).

Every record is also echoed as one readable line on stderr (journald), e.g.
``VIOLATION state_req103 tick=42 classifier=1 distance_to_target=2``.
"""

from __future__ import annotations

import errno
import json
import os
import sys
import threading
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, TextIO

import structlog
from structlog.typing import EventDict, WrappedLogger

from mitigations.violationlog.format import (
    EMPTY_SHA256,
    HEADER,
    describe,
    json_safe,
    seal_line,
    sha256_hex,
)
from monitors.errors import UserError

_RESERVED = frozenset(HEADER) | {"line_sha256"}
_ISO_UTC_US = "%Y-%m-%dT%H:%M:%S.%fZ"  # strftime keeps .000000; isoformat() would drop it


def _header_first(_logger: WrappedLogger, _name: str, event_dict: EventDict) -> EventDict:
    """Fixed key order (readers and ``line_sha256`` rely on it) and JSON-safe values."""
    out = {k: event_dict.pop(k) for k in HEADER if k in event_dict}
    out.update((k, json_safe(v)) for k, v in event_dict.items())
    return out


def _processors() -> list[Any]:
    # A local chain rather than structlog.configure(): the daemon may configure
    # structlog for its own diagnostics, and must not change this file's format.
    return [
        structlog.processors.TimeStamper(fmt=_ISO_UTC_US, utc=True, key="ts"),
        _header_first,
        structlog.processors.JSONRenderer(separators=(",", ":"), allow_nan=False),
    ]


def _stderr_is_journal() -> bool:
    """journald reads ``<N>`` level prefixes; a terminal should not see them."""
    try:
        st = os.fstat(2)
    except OSError:
        return False
    return os.environ.get("JOURNAL_STREAM", "") == f"{st.st_dev}:{st.st_ino}"


class ViolationLog:
    """Append-only, hash-chained violation log.  Thread-safe."""

    def __init__(
        self,
        path: str | os.PathLike[str],
        component: str,
        config_sha256: str,
        *,
        echo: TextIO | bool = True,
    ) -> None:
        """``echo``: True for stderr (looked up at write time), a stream, or False."""
        self._path = Path(path)
        self._config_sha256 = config_sha256
        self._echo = echo
        self._lock = threading.RLock()  # reopen() writes its link record while holding it
        self._log = structlog.BoundLogger(
            structlog.ReturnLogger(), _processors(), {"component": component}
        )
        self._failed = 0
        self._failing = False
        self._journal = _stderr_is_journal()
        self._fd: int | None = None
        self._prev = EMPTY_SHA256
        self._size = 0
        self._needs_newline = False
        self._resync = False
        self._fd = self._open()
        self._load_tail()

    # ---------------------------------------------------------------- properties

    @property
    def path(self) -> Path:
        return self._path

    @property
    def failed_writes(self) -> int:
        return self._failed

    @property
    def config_sha256(self) -> str:
        return self._config_sha256

    @config_sha256.setter
    def config_sha256(self, value: str) -> None:
        with self._lock:  # records after a reload carry the new hash, none half-way
            self._config_sha256 = value

    # ---------------------------------------------------------------- records

    def violation(
        self,
        requirement: str,
        *,
        text: str,
        formula: str,
        tick: int,
        inputs: Mapping[str, Any],
        recent: Sequence[Mapping[str, Any]] = (),
        stale: Iterable[str] = (),
        policy_state: Mapping[str, Any] | None = None,
        **extra: Any,
    ) -> bool:
        """Write and fsync; returns True when the record is on disk."""
        fields = dict(
            requirement=requirement,
            text=text,
            formula=formula,
            tick=tick,
            inputs=dict(inputs),
            recent=[dict(r) for r in recent],
            stale=list(stale),
            policy_state=dict(policy_state or {}),
        )
        return self._emit("violation", fields, extra, durable=True)

    def mitigation(
        self,
        requirement: str,
        *,
        action: str,
        kind: str,
        ok: bool,
        latency_ms: float,
        error: str | None = None,
        attempt: int = 1,
        **extra: Any,
    ) -> bool:
        fields = dict(
            requirement=requirement,
            action=action,
            kind=kind,
            ok=ok,
            error=error,
            latency_ms=latency_ms,
            attempt=attempt,
        )
        return self._emit("mitigation", fields, extra, durable=True)

    def reset(self, requirement: str, *, reason: str, **extra: Any) -> bool:
        return self._emit("reset", {"requirement": requirement, "reason": reason}, extra)

    def supervisor(self, what: str, **fields: Any) -> bool:
        """start, ready, reload (ok=..., why=...), stop, input_stale, input_recovered,
        watchdog, ...; any extra fields."""
        return self._emit("supervisor", {"what": what}, fields)

    # ---------------------------------------------------------------- file handling

    def reopen(self) -> bool:
        """SIGHUP after logrotate (create mode): open the path anew and continue the
        chain of whatever file is there now (a new empty file starts from the empty
        hash).  When the file changed, the first record written to it links back:
        ``supervisor what=log_reopened previous_last_sha256=<old file's last line>``.
        Never raises; False when the path could not be opened (old file kept)."""
        with self._lock:
            old_fd, old_prev = self._fd, self._prev
            try:
                new_fd = self._open()
            except UserError as e:
                self._report(f"violation log: reopen failed, still writing the old file: {e}")
                return False
            rotated = True
            if old_fd is not None:
                try:
                    a, b = os.fstat(old_fd), os.fstat(new_fd)
                    rotated = (a.st_dev, a.st_ino) != (b.st_dev, b.st_ino)
                    os.close(old_fd)
                except OSError:
                    pass
            self._fd = new_fd
            self._load_tail()
            link = {"rotated": rotated}
            if rotated:
                link["previous_last_sha256"] = old_prev
            return self._emit("supervisor", {"what": "log_reopened"}, link, durable=True)

    def close(self) -> None:
        with self._lock:
            if self._fd is None:
                return
            fd, self._fd = self._fd, None
            try:
                os.fsync(fd)
            except OSError:
                pass  # e.g. a character device; every durable record was fsynced already
            os.close(fd)

    def __enter__(self) -> ViolationLog:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # ---------------------------------------------------------------- internals

    def _open(self) -> int:
        flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_CLOEXEC
        try:
            return os.open(self._path, flags, 0o640)
        except OSError as e:
            hint = {
                errno.ENOENT: "its directory does not exist (systemd: LogsDirectory=)",
                errno.EACCES: "the supervisor's user may not write there",
                errno.EISDIR: "give a file name, not a directory",
                errno.EROFS: "the file system is read-only",
            }.get(e.errno or 0)
            raise UserError(
                f"cannot open the violation log for appending: {e.strerror}",
                file=str(self._path),
                hint=hint,
            ) from e

    def _load_tail(self) -> None:
        """Chain state from the file's last line (restart, rotation, a failed write
        or another writer): its hash, and whether it lacks its newline."""
        assert self._fd is not None
        self._resync = False
        self._prev, self._needs_newline = EMPTY_SHA256, False
        try:
            self._size = os.fstat(self._fd).st_size
            if self._size == 0:
                return
            # Our fd is write-only; /proc/self/fd opens the same inode for reading,
            # whatever has been renamed in the meantime.
            rfd = os.open(f"/proc/self/fd/{self._fd}", os.O_RDONLY | os.O_CLOEXEC)
        except OSError as e:
            self._report(
                f"violation log: cannot read {self._path} to continue its hash "
                f"chain ({e.strerror}); the chain restarts here"
            )
            return
        try:
            ends_nl = os.pread(rfd, 1, self._size - 1) == b"\n"
            pos = self._size - 1 if ends_nl else self._size
            tail = b""
            while pos > 0:
                start = max(0, pos - 65536)
                tail = os.pread(rfd, pos - start, start) + tail
                pos = start
                cut = tail.rfind(b"\n")
                if cut >= 0:
                    tail = tail[cut + 1 :]
                    break
            # An unterminated tail is a line cut short by a crash or a full disk: the
            # next write terminates it, and the chain covers it with that newline.
            self._prev = sha256_hex(tail + b"\n")
            self._needs_newline = not ends_nl
        except OSError as e:
            self._report(
                f"violation log: cannot read {self._path} ({e.strerror}); "
                "the hash chain restarts here"
            )
        finally:
            os.close(rfd)

    def _emit(
        self, event: str, fields: dict[str, Any], extra: Mapping[str, Any], durable: bool = False
    ) -> bool:
        for k, v in extra.items():
            fields[k + "_" if k in _RESERVED or k in fields else k] = v
        record: dict[str, Any] | None = None
        error: str | None = None
        with self._lock:
            if self._fd is None:
                error = "the log is closed"
            else:
                try:
                    if self._resync or os.fstat(self._fd).st_size != self._size:
                        self._load_tail()  # copytruncate, another writer, a failed write
                    rendered = self._log.msg(
                        event, config_sha256=self._config_sha256, prev_sha256=self._prev, **fields
                    )
                    line = seal_line(rendered.encode("ascii"))
                    record = json.loads(line)
                except Exception as e:  # noqa: BLE001 - a bad value must not stop monitoring
                    error = f"cannot render the record: {type(e).__name__}: {e}"
                else:
                    error = self._write(line, durable)
            failed, recovered = self._failed + (error is not None), self._failing and not error
            self._failed, self._failing = failed, error is not None
        if record is None:
            record = {"event": event, **json_safe(fields)}
        self._echo_line(record)
        if recovered:
            self._report(f"violation log: {self._path}: writing again ({failed} failed writes)")
        if error is not None:
            if failed <= 10 or failed % 1000 == 0:  # a full disk must not flood the journal
                self._report(
                    f"violation log: {self._path}: {event} record NOT written: {error} "
                    f"({failed} failed writes)"
                )
            return False
        return True

    def _write(self, line: bytes, durable: bool) -> str | None:
        assert self._fd is not None
        data = b"\n" + line if self._needs_newline else line
        written = 0
        try:
            # One write per line; the loop only continues a short write (disk
            # nearly full), still under the lock, so nothing interleaves.
            while written < len(data):
                n = os.write(self._fd, data[written:])
                if n == 0:
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                written += n
            if durable:
                os.fsync(self._fd)
        except OSError as e:
            self._resync = True  # re-read the tail: part of the line may be in the file
            return e.strerror or str(e)
        self._size += written
        self._prev, self._needs_newline = sha256_hex(line), False
        return None

    def _echo_line(self, record: dict[str, Any]) -> None:
        if self._echo is False:
            return
        stream = sys.stderr if self._echo is True else self._echo
        level = 4 if record.get("event") == "violation" else 6
        try:
            prefix = f"<{level}>" if self._journal and stream is sys.stderr else ""
            stream.write(prefix + describe(record) + "\n")
            stream.flush()
        except (OSError, ValueError):
            pass  # a closed stderr must not stop monitoring

    def _report(self, text: str) -> None:
        try:
            sys.stderr.write(("<3>" if self._journal else "") + text + "\n")
            sys.stderr.flush()
        except (OSError, ValueError):
            pass
