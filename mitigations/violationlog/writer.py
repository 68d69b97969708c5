"""The violation log writer (docs/reference/log.md).

JSON lines rendered as a structlog processor chain would (:func:`_processors`;
the common case in one encoder call, ``_ENCODE``); the format, the hash chain
(``prev_sha256``, ``line_sha256``), ``seq``, its semantics across rotation and the
encoding of NaN/inf are documented in :mod:`mitigations.violationlog.format`; the reader
verifies them.

Writing: the file is opened ``O_WRONLY|O_APPEND|O_CREAT`` (mode 0640); each
line is rendered completely and written with one ``os.write`` under a lock,
so threads never interleave partial lines.  ``violation`` and ``mitigation``
records are fsynced; when is ``durability`` (``logging.durability``,
docs/reference/log.md): ``before_action`` fsyncs before returning, so a violation
is on disk before its mitigations run; ``after_publish`` (the default) returns
once the line is written (in the page cache: a crash of the daemon does not lose
it) when it is made on ``defer_thread`` (the daemon's loop), and :meth:`flush`,
which the loop calls after the turn's actions are out, fsyncs it.  Records made
on any other thread are fsynced before returning in either mode.  Only opening
the log raises (``UserError``).

A failure to write (a full disk) never raises and never waits: the record
gets its ``seq`` and its time as usual, is echoed to stderr (the journal) as
usual, and waits in a bounded in-memory queue (``retry_buffer`` records).  The
queue is written, in ``seq`` order and chained, at the next record and every
``retry_interval_s`` by a helper thread.  When the queue is full, further
records are dropped (the first records of an outage are the evidence of how
it began); once there is room again, a ``supervisor`` record
``what=records_lost`` is queued right where the dropped ones would have been,
naming their exact ``seq`` ranges and the write error (docs/reference/faults.md).

Every record is also echoed as one readable line on stderr (journald), e.g.
``VIOLATION state_req103 tick=42 classifier=1 distance_to_target=2``.  Under systemd
each record also goes to journald's native socket with structured fields
(:mod:`mitigations.violationlog.journal`); then stderr, being the journal too, no
longer echoes the records it took (docs/reference/log.md).
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import structlog
from structlog.typing import EventDict, WrappedLogger

from mitigations.violationlog.format import (
    DURABILITIES,
    DURABILITY,
    EMPTY_SHA256,
    HEADER,
    RETRY_BUFFER,
    ZERO_SHA256,
    Row,
    describe,
    encode_fragment,  # noqa: F401 - the writer's name for it too (its tests, its docs)
    json_safe,
    seal_line,
    sha256_hex,
)
from mitigations.violationlog.format import ENCODE as _ENCODE
from mitigations.violationlog.format import unencodable as _no
from mitigations.violationlog.journal import JournalSender, priority, record_fields, socket_path
from monitors.errors import UserError

_RESERVED = frozenset(HEADER) | {"line_sha256"}
_second: tuple[int, str] = (-1, "")  # the last second stamped, and its text


def _now() -> str:
    """The UTC time to the microsecond, ``2026-11-27T15:16:06.269955Z`` (always six
    digits): the second's text made once per second, the microseconds added, which
    takes a fifth of ``datetime.now(UTC).strftime`` on the halt's path."""
    global _second
    s, us = divmod(time.time_ns() // 1000, 1_000_000)
    last = _second  # one read: another thread may replace it meanwhile
    if last[0] != s:
        last = _second = (s, time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(s)))
    return f"{last[1]}.{us:06d}Z"


_PREV_KEY = b'"prev_sha256":"'
_SEAL_KEY = b',"line_sha256":"'
_SEAL_ZEROS = _SEAL_KEY + ZERO_SHA256.encode() + b'"}\n'  # what seal_line hashes at the end
RETRY_INTERVAL_S = 1.0


def _header_first(_logger: WrappedLogger, _name: str, event_dict: EventDict) -> EventDict:
    """Fixed key order (readers and ``line_sha256`` rely on it)."""
    out = {k: event_dict.pop(k) for k in HEADER if k in event_dict}
    out.update(event_dict)
    return out


def _json_safe(_logger: WrappedLogger, _name: str, event_dict: EventDict) -> EventDict:
    """NaN and infinities as strings, other containers as JSON's (format.json_safe)."""
    return {k: json_safe(v) for k, v in event_dict.items()}


def _processors(*, safe: bool) -> list[Any]:
    # A local chain rather than structlog.configure(): the daemon may configure
    # structlog for its own diagnostics, and must not change this file's format.
    # safe=False is what _ENCODE does in one call (the reference its test compares).
    # ``ts`` is set by the writer: a record written late keeps the time it was made.
    if safe:
        render = structlog.processors.JSONRenderer(separators=(",", ":"), allow_nan=False)
        return [_header_first, _json_safe, render]
    # anything JSON has no form for raises here, and the record goes the safe way
    return [
        _header_first,
        structlog.processors.JSONRenderer(separators=(",", ":"), allow_nan=False, default=_no),
    ]


# The fields a violation record has before ``recent``, in the writer's order.
_BEFORE_RECENT = ("requirement", "text", "formula", "tick", "inputs")


def _fragments(recent: Sequence[Mapping[str, Any]]) -> list[str] | None:
    """Each row's pre-encoded JSON, or None if any row has none."""
    out = []
    for r in recent:
        text = getattr(r, "json", None) if type(r) is Row else None
        if text is None:
            return None
        out.append(text)
    return out


# A violation record's own fields, in the writer's order (violation()); extra
# fields named like these or the header are renamed, as _emit renames them.
_VIOLATION_KEYS = (*_BEFORE_RECENT, "recent", "stale", "policy_state")


@dataclass(frozen=True)
class ViolationTemplate:
    """One requirement's violation record with its fixed fields encoded once
    (:meth:`ViolationLog.violation_template`, when a config's session is built):
    on the halt's path only the tick, the values, ``recent``, ``stale``, the policy
    state and the header's time, ``seq`` and chain are filled in
    (docs/reference/log.md#durability).  ``head`` is the JSON of ``requirement``,
    ``text`` and ``formula``, ``tail`` that of the extra fields (renamed as
    :meth:`ViolationLog.violation` renames them), each without braces."""

    requirement: str
    text: str
    formula: str
    extra: Mapping[str, Any]
    head: str
    tail: str


def _stderr_is_journal() -> bool:
    """journald reads ``<N>`` level prefixes; a terminal should not see them."""
    try:
        st = os.fstat(2)
    except OSError:
        return False
    return os.environ.get("JOURNAL_STREAM", "") == f"{st.st_dev}:{st.st_ino}"


def seq_ranges(ranges: Sequence[Sequence[int]]) -> str:
    """``[[3, 5], [9, 9]]`` -> ``3-5,9``."""
    return ",".join(f"{a}" if a == b else f"{a}-{b}" for a, b in ranges)


@dataclass
class _Entry:
    """A rendered record waiting to be written: its body has ``prev_sha256`` as
    zeros at ``prev_at``, filled in when it is written (it chains to whatever
    line precedes it then)."""

    seq: int
    event: str
    ts: str
    body: bytes
    prev_at: int
    durable: bool
    counted: bool = True  # counts against retry_buffer (records_lost records do not)
    state: str = "queued"  # queued | written | dropped
    written: bytes | None = None  # the line as written, chain hashes filled in (journal)

    def line(self, prev: str) -> bytes:
        """The body with ``prev`` filled in and sealed, as ``seal_line`` seals it,
        hashed piece by piece instead of copied whole twice first (the halt's path)."""
        body, at = self.body, self.prev_at
        if not body.endswith(b"}"):  # seal_line's own check, and its message
            return seal_line(body[:at] + prev.encode() + body[at + 64 :])
        head, filled, rest = body[:at], prev.encode(), memoryview(body)[at + 64 : -1]
        digest = hashlib.sha256(head)
        digest.update(filled)
        digest.update(rest)
        digest.update(_SEAL_ZEROS)
        return b"".join((head, filled, rest, _SEAL_KEY, digest.hexdigest().encode(), b'"}\n'))


class ViolationLog:
    """Append-only, hash-chained violation log.  Thread-safe."""

    def __init__(
        self,
        path: str | os.PathLike[str],
        component: str,
        config_sha256: str,
        *,
        echo: TextIO | bool = True,
        retry_buffer: int = RETRY_BUFFER,
        retry_interval_s: float = RETRY_INTERVAL_S,
        fsync: bool = True,
        durability: str = DURABILITY,
        say: Callable[[str], None] | None = None,
    ) -> None:
        """``echo``: True for stderr (looked up at write time), a stream, or False.
        ``say``: where the log's own reports go (a failed write, a loss); default stderr.
        ``retry_buffer``: records kept in memory while the file cannot be written (>= 1).
        ``fsync``: False for a log written from a recording (``replay``): nothing is at
        stake while it is written, so it is synced once, at close.
        ``durability``: one of ``DURABILITIES`` (see the module's docstring)."""
        self._path = Path(path)
        self._config_sha256 = config_sha256
        self._component = component
        self._head = _header_json(component, config_sha256)
        self._echo = echo
        self._lock = threading.RLock()  # reopen() queues its link record while holding it
        # Rendered as they are (_ENCODE); a record JSON cannot hold as it is (a NaN,
        # a set) again through json_safe: the walk costs most of a record's rendering.
        self._log_safe = structlog.BoundLogger(
            structlog.ReturnLogger(), _processors(safe=True), {"component": component}
        )
        self._failed = 0
        self._journal = _stderr_is_journal()
        # Only the daemon's stderr echo has a journal twin: a log written to a
        # stream or silently (replay, tests) is not sent there.
        where = socket_path(self._journal) if echo is True else None
        self._journald = JournalSender(where) if where else None
        self._journald_reported = False
        self._fd: int | None = None
        self._prev_hex: str | None = EMPTY_SHA256
        self._prev_line = b""  # hashed into _prev when the next record needs it
        self._size = 0
        self._needs_newline = False
        self._resync = False
        self._seq = 0
        self._queue: deque[_Entry] = deque()
        self._queued = 0  # records in the queue, records_lost records not counted
        self._cap = max(1, int(retry_buffer))
        self._retry_s = retry_interval_s
        self._retrier: threading.Thread | None = None
        self._closed = threading.Event()
        self._error = ""  # the last write error: the reason of a loss
        self._say = say
        self._outage = False
        self._lost: list[list[int]] = []  # dropped seq ranges not yet recorded
        self._lost_events: dict[str, int] = {}
        self._lost_ts: list[str] = []  # first and last dropped record's time
        self._late = 0  # records written late in the current outage
        self._messages: list[str] = []  # reports gathered under the lock, printed after
        self._unsynced = False  # the last drain wrote durable records but fsync failed
        self._echoes: list[_Entry] = []  # records made under the lock, echoed after
        self._tail = b""
        self._sync_each = fsync
        self._durability = _checked_durability(durability)
        self._sync_due = False  # durable records written on defer_thread, not fsynced yet
        # Each record as rendered (its chain hash not yet filled in), for a copy
        # elsewhere: the daemon's recording (docs/reference/log.md).
        self.tee: Callable[[str], None] | None = None
        # Records emitted on this thread are teed and echoed only at flush(), and under
        # after_publish fsynced there: the daemon's loop sets it, so that a violation's
        # halt follows its write without waiting for the disk, the journal and the
        # copies (docs/reference/log.md).
        self.defer_thread: int | None = None
        self._deferred: list[tuple[str, _Entry | None, str, dict[str, Any]]] = []
        self._fd = self._open()
        self._load_tail()

    # ---------------------------------------------------------------- properties

    @property
    def path(self) -> Path:
        return self._path

    @property
    def failed_writes(self) -> int:
        """Records that could not be written when they were made (queued or lost)."""
        return self._failed

    @property
    def write_error(self) -> str:
        """The last write's error ("" when none failed)."""
        return self._error

    @property
    def pending(self) -> int:
        """Records waiting in memory to be written."""
        return len(self._queue)

    @property
    def seq(self) -> int:
        """The ``seq`` of the last record made (0 before the first)."""
        return self._seq

    @property
    def retry_buffer(self) -> int:
        return self._cap

    @retry_buffer.setter
    def retry_buffer(self, value: int) -> None:
        with self._lock:  # a reload may change it; records already queued stay
            self._cap = max(1, int(value))

    @property
    def durability(self) -> str:
        return self._durability

    @durability.setter
    def durability(self, value: str) -> None:
        checked = _checked_durability(value)
        with self._lock:  # a reload may change it: nothing written stays unsynced
            if self._sync_due:
                self._fsync()
            self._durability = checked

    @property
    def config_sha256(self) -> str:
        return self._config_sha256

    @config_sha256.setter
    def config_sha256(self, value: str) -> None:
        with self._lock:  # records after a reload carry the new hash, none half-way
            self._config_sha256 = value
            self._head = _header_json(self._component, value)

    @property
    def _prev(self) -> str:
        """The chain's hash of the file's last line (the next record's prev_sha256)."""
        if self._prev_hex is None:
            self._prev_hex = sha256_hex(self._prev_line)
        return self._prev_hex

    @_prev.setter
    def _prev(self, value: str) -> None:
        self._prev_hex = value

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
        """Write and fsync (``durability`` says when); True when the record is
        written, and fsynced unless that is deferred to :meth:`flush`."""
        fields = dict(
            requirement=requirement,
            text=text,
            formula=formula,
            tick=tick,
            inputs=dict(inputs),
            # a Row is not changed once made (no copy needed); other rows are copied
            recent=[r if type(r) is Row else dict(r) for r in recent],
            stale=list(stale),
            policy_state=dict(policy_state or {}),
        )
        return self._emit("violation", fields, extra, durable=True)

    @staticmethod
    def violation_template(
        requirement: str, *, text: str, formula: str, **extra: Any
    ) -> ViolationTemplate | None:
        """The fixed part of ``requirement``'s violation records, for
        :meth:`violation_from`; None when it has no plain JSON form (its records
        then take :meth:`violation`)."""
        fields: dict[str, Any] = dict.fromkeys(_VIOLATION_KEYS)
        for k, v in extra.items():  # as _emit renames them
            fields[k + "_" if k in _RESERVED or k in fields else k] = v
        renamed = {k: v for k, v in fields.items() if k not in _VIOLATION_KEYS}
        try:
            head = _ENCODE({"requirement": requirement, "text": text, "formula": formula})
            tail = _ENCODE(renamed)
        except (ValueError, TypeError, RecursionError):
            return None
        return ViolationTemplate(
            requirement, text, formula, dict(extra), head[1:-1], f",{tail[1:-1]}" if renamed else ""
        )

    def violation_from(
        self,
        template: ViolationTemplate,
        *,
        tick: int,
        inputs: Mapping[str, Any],
        recent: Sequence[Mapping[str, Any]] = (),
        stale: Iterable[str] = (),
        policy_state: Mapping[str, Any] | None = None,
    ) -> bool:
        """:meth:`violation` with ``template``'s fields, the same bytes: only the
        dynamic fields are encoded here.  A value without a plain JSON form (NaN,
        a set, another mapping), a row of ``recent`` that is not a :class:`Row` or
        a tick that is not an int take :meth:`violation`'s way."""
        stale = list(stale)
        parts = _fragments(recent) if type(tick) is int else None
        dynamic = None
        if parts is not None:
            try:
                dynamic = (
                    f'"tick":{tick},"inputs":{_ENCODE(inputs)},"recent":[{",".join(parts)}],'
                    f'"stale":{_ENCODE(stale)},"policy_state":{_ENCODE(policy_state or {})}'
                )
            except (ValueError, TypeError, RecursionError):
                dynamic = None
        if dynamic is None:
            return self.violation(
                template.requirement,
                text=template.text,
                formula=template.formula,
                tick=tick,
                inputs=inputs,
                recent=recent,
                stale=stale,
                policy_state=policy_state,
                **template.extra,
            )
        return self._emit("violation", {}, {}, durable=True, body=(template, dynamic))

    def violation_row(
        self,
        template: ViolationTemplate,
        *,
        row: Row,
        recent: Sequence[Row],
        stale: Sequence[str],
        policy_state: str,
    ) -> bool | None:
        """:meth:`violation_from` on the halt's path (docs/reference/log.md#the-halt-path),
        the same bytes: the tick and the values are those of ``row``, the step's own
        row of ``recent``, whose JSON is made at its step; ``policy_state`` is
        already encoded (:func:`encode_fragment`).  None when a row has no plain
        JSON form: nothing is written, the caller takes :meth:`violation_from`."""
        text = getattr(row, "json", None)
        try:
            parts = ",".join([r.json for r in recent])  # type: ignore[misc]
        except (AttributeError, TypeError):  # a plain dict, or a row without JSON
            return None
        cut = -1 if text is None else text.find(",")  # a row is {"tick": ..., **inputs}
        if cut < 0:
            return None
        assert text is not None
        state = _ENCODE(stale) if stale else "[]"
        dynamic = (
            f'{text[1:cut]},"inputs":{{{text[cut + 1 :]},"recent":[{parts}],'
            f'"stale":{state},"policy_state":{policy_state}'
        )
        return self._emit("violation", {}, {}, durable=True, body=(template, dynamic))

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

    def prediction(self, requirement: str, **fields: Any) -> bool:
        """A violation expected within the horizon (docs/reference/prediction.md):
        durable as a violation is, since its early actions follow it."""
        return self._emit("prediction", {"requirement": requirement}, fields, durable=True)

    def prediction_expired(self, requirement: str, **fields: Any) -> bool:
        """The horizon of a prediction passed without the violation."""
        return self._emit("prediction_expired", {"requirement": requirement}, fields)

    def supervisor(self, what: str, **fields: Any) -> bool:
        """start, ready, reload (ok=..., why=...), stop, input_stale, input_recovered,
        watchdog, ...; any extra fields."""
        return self._emit("supervisor", {"what": what}, fields)

    # ---------------------------------------------------------------- file handling

    def reopen(self, *, only_if_moved: bool = False) -> bool:
        """After logrotate (create mode): open the path anew and continue the chain
        of whatever file is there now (a new empty file starts from the empty hash).
        The first record made after it links back: ``supervisor what=log_reopened
        previous_last_sha256=<old file's last line>`` (records still queued from an
        outage are written before it, in ``seq`` order).  ``only_if_moved``: do
        nothing while the path still names the open file.  Never raises; False when
        the path could not be opened (old file kept) or the link record is not on disk."""
        with self._lock:
            if self._fd is None:
                return False
            if only_if_moved and not self._moved():
                return True
            old_fd = self._fd
            try:
                new_fd = self._open()
            except UserError as e:
                self._messages.append(
                    f"violation log: reopen failed, still writing the old file: {e}"
                )
                self._flush_messages()
                return False
            if self._sync_due:  # the old file's last records, before leaving it
                self._fsync()
            self._terminate_old(old_fd)
            old_prev, rotated = self._prev, True
            try:
                a, b = os.fstat(old_fd), os.fstat(new_fd)
                rotated = (a.st_dev, a.st_ino) != (b.st_dev, b.st_ino)
                os.close(old_fd)
            except OSError:
                pass
            self._fd = new_fd
            self._load_tail()
            link: dict[str, Any] = {"rotated": rotated}
            if rotated:
                link["previous_last_sha256"] = old_prev
            return self._emit("supervisor", {"what": "log_reopened"}, link, durable=True)

    def retry(self) -> int:
        """Write what is queued now; the number of records still waiting."""
        with self._lock:
            if self._fd is not None:
                self._drain()
            left = len(self._queue)
        self._flush_messages()
        return left

    def close(self) -> None:
        self.flush()
        with self._lock:
            if self._fd is None:
                return
            self._drain()
            unwritten = [e.seq for e in self._queue if e.state == "queued"]
            lost = [r[:] for r in self._lost]
            for s in unwritten:
                _add_seq(lost, s)
            if lost:
                self._messages.append(
                    f"violation log: {self._path}: closing with "
                    f"{sum(b - a + 1 for a, b in lost)} records never written "
                    f"(seq {seq_ranges(lost)}: {self._error}); they are only in the journal"
                )
            fd, self._fd = self._fd, None
            self._closed.set()
            if self._journald is not None:
                self._journald.close()
            try:
                os.fsync(fd)
            except OSError:
                pass  # e.g. a character device; every durable record was fsynced already
            os.close(fd)
        self._flush_messages()

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

    def _moved(self) -> bool:
        assert self._fd is not None
        try:
            a, b = os.fstat(self._fd), os.stat(self._path)
        except OSError:
            return True
        return (a.st_dev, a.st_ino) != (b.st_dev, b.st_ino)

    def _terminate_old(self, fd: int) -> None:
        """Before leaving a file: end a line a failed write left unterminated, so the
        old file does not end in a torn line (best effort: its disk may be full)."""
        try:
            if self._resync or os.fstat(fd).st_size != self._size:
                self._load_tail()
            if self._needs_newline and os.write(fd, b"\n") == 1:
                self._prev = sha256_hex(self._tail + b"\n")
                self._needs_newline = False
        except OSError:
            pass

    def _load_tail(self) -> None:
        """Chain state from the file's last line (restart, rotation, a failed write
        or another writer): its hash, and whether it lacks its newline."""
        assert self._fd is not None
        self._resync = False
        self._prev, self._needs_newline, self._tail = EMPTY_SHA256, False, b""
        try:
            self._size = os.fstat(self._fd).st_size
            if self._size == 0:
                return
            # Our fd is write-only; /proc/self/fd opens the same inode for reading,
            # whatever has been renamed in the meantime.
            rfd = os.open(f"/proc/self/fd/{self._fd}", os.O_RDONLY | os.O_CLOEXEC)
        except OSError as e:
            self._messages.append(
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
            self._needs_newline, self._tail = not ends_nl, tail
        except OSError as e:
            self._messages.append(
                f"violation log: cannot read {self._path} ({e.strerror}); "
                "the hash chain restarts here"
            )
        finally:
            os.close(rfd)

    def _render(self, event: str, ts: str, fields: dict[str, Any], durable: bool) -> _Entry:
        """Render with the next ``seq`` (taken only when rendering succeeds)."""
        seq = self._seq + 1
        # The header first, then the fields (none is named like the header: _emit
        # renames those), as _header_first orders them.
        record = {"ts": ts, "event": event, "component": self._component}
        record |= {"config_sha256": self._config_sha256, "prev_sha256": ZERO_SHA256}
        record["seq"] = seq
        parts = _fragments(fields["recent"]) if event == "violation" else None
        try:
            if parts is None:
                text = _ENCODE(record | fields)
            else:
                # The same bytes as the whole record's encoding, with each tick of
                # ``recent`` joined from its Row instead of encoded here.
                tail = dict(fields)
                for k in _BEFORE_RECENT:
                    record[k] = tail.pop(k)
                del tail["recent"]
                text = f'{_ENCODE(record)[:-1]},"recent":[{",".join(parts)}],{_ENCODE(tail)[1:]}'
        except (ValueError, TypeError):  # NaN, infinities, sets, other mappings
            header = {"ts": ts, "config_sha256": self._config_sha256}
            header |= {"prev_sha256": ZERO_SHA256, "seq": seq}
            text = self._log_safe.msg(event, **header, **fields)
        rendered = text.encode("ascii")
        # The header precedes every event field, and inside a JSON string a quote
        # is escaped, so the first match is the header's own prev_sha256.
        at = rendered.index(_PREV_KEY) + len(_PREV_KEY)
        self._seq = seq
        return _Entry(seq, event, ts, rendered, at, durable)

    def _render_template(self, ts: str, template: ViolationTemplate, dynamic: str) -> _Entry:
        """A violation from its template (:meth:`violation_from`), with the next ``seq``:
        the header's fields in _render's order, then the template's and the dynamic ones."""
        seq = self._seq + 1
        start = f'{{"ts":"{ts}","event":"violation",{self._head},"prev_sha256":"'
        text = f'{start}{ZERO_SHA256}","seq":{seq},{template.head},{dynamic}{template.tail}}}'
        self._seq = seq
        return _Entry(seq, "violation", ts, text.encode("ascii"), len(start), True)

    def _emit(
        self,
        event: str,
        fields: dict[str, Any],
        extra: Mapping[str, Any],
        durable: bool = False,
        body: tuple[ViolationTemplate, str] | None = None,
    ) -> bool:
        """``body``: a violation's template and its dynamic fields' JSON
        (:meth:`violation_from`), rendered instead of ``fields``."""
        for k, v in extra.items():
            fields[k + "_" if k in _RESERVED or k in fields else k] = v
        ts = _now()
        entry: _Entry | None = None
        error: str | None = None
        with self._lock:
            if self._fd is None:
                error = "the log is closed"
            else:
                self._drain()
                room = self._queued < self._cap
                if room and self._lost:
                    self._queue_lost()
                try:
                    if body is None:
                        entry = self._render(event, ts, fields, durable)
                    else:
                        entry = self._render_template(ts, *body)
                except Exception as e:  # noqa: BLE001 - a bad value must not stop monitoring
                    error = f"cannot render the record: {type(e).__name__}: {e}"
                else:
                    if room:
                        self._queue.append(entry)
                        self._queued += 1
                    else:
                        self._drop(entry)
                    self._drain()
            ok = entry is not None and entry.state == "written"
            if not ok:
                self._failed += 1
                self._not_written(event, entry, error)
            ok = ok and not (durable and self._unsynced)
        if self.defer_thread is not None and threading.get_ident() == self.defer_thread:
            self._deferred.append((event, entry, ts, fields))
        else:
            self._after_write(event, entry, ts, fields)
        return ok

    def flush(self) -> None:
        """Fsync what ``after_publish`` left unsynced, then tee and echo the records
        held back on ``defer_thread`` (call it there, after the turn's actions)."""
        if self._sync_due:
            with self._lock:
                if self._sync_due and self._fd is not None:
                    self._fsync()
            if self._messages:
                self._flush_messages()
        if self._prev_hex is None:
            # The chain's hash of the last line, made now, after the turn's halts, so
            # that the next violation does not make it before its own halt.
            with self._lock:
                self._prev  # noqa: B018 - the property makes and keeps it
        if not self._deferred:
            return
        deferred, self._deferred = self._deferred, []
        for item in deferred:
            self._after_write(*item)

    def _after_write(
        self, event: str, entry: _Entry | None, ts: str, fields: dict[str, Any]
    ) -> None:
        if self.tee is not None and entry is not None:
            self.tee(entry.body.decode("ascii"))
        if self._echo is not False:
            line = entry.written or entry.body if entry is not None else None
            record = json.loads(line) if line is not None else None
            self._echo_line(record or {"event": event, "ts": ts, **json_safe(fields)}, line)
        self._flush_messages()

    def _not_written(self, event: str, entry: _Entry | None, error: str | None) -> None:
        n = self._failed
        if n > 10 and n % 1000:  # a full disk must not flood the journal
            return
        if entry is None:
            what = f"{event} record NOT written: {error}"
        elif entry.state == "dropped":
            what = (
                f"{event} record seq={entry.seq} NOT written: {self._error}; dropped, "
                f"{self._cap} records already wait (logging.retry_buffer); it is "
                "in the journal and a records_lost record will name it"
            )
        else:
            what = (
                f"{event} record seq={entry.seq} NOT written: {self._error}; kept in "
                f"memory and retried ({len(self._queue)} waiting)"
            )
        self._messages.append(f"violation log: {self._path}: {what} ({n} failed writes)")

    def _drop(self, entry: _Entry) -> None:
        entry.state = "dropped"
        if not self._lost:  # once per gap, whatever the rate limit of the lines above
            self._messages.append(
                f"violation log: {self._path}: {self._cap} records wait to be written "
                f"(logging.retry_buffer); from seq {entry.seq} on records are dropped "
                "(they are in the journal) until there is room, and a records_lost "
                "record will name them"
            )
        _add_seq(self._lost, entry.seq)
        self._lost_events[entry.event] = self._lost_events.get(entry.event, 0) + 1
        self._lost_ts = [self._lost_ts[0] if self._lost_ts else entry.ts, entry.ts]

    def _queue_lost(self) -> None:
        """The records_lost record, queued right after the gap it explains."""
        lost, self._lost = self._lost, []
        events, self._lost_events = self._lost_events, {}
        first_last, self._lost_ts = self._lost_ts, []
        fields: dict[str, Any] = {
            "what": "records_lost",
            "lost": lost,
            "count": sum(b - a + 1 for a, b in lost),
            "reason": self._error or "unknown",
            "events": events,
        }
        if first_last:
            fields["first_ts"], fields["last_ts"] = first_last
        ts = _now()
        entry = self._render("supervisor", ts, fields, durable=True)
        entry.counted = False  # one per gap, so the queue stays bounded
        self._queue.append(entry)
        self._echoes.append(entry)
        self._messages.append(
            f"violation log: {self._path}: {fields['count']} records were lost "
            f"(seq {seq_ranges(lost)}: {fields['reason']}); a records_lost record says so"
        )

    def _drain(self) -> None:
        """Write the queue in order until it is empty or a write fails; then, if
        records were dropped, queue and write the records_lost record."""
        synced = True
        self._unsynced = False
        wrote_durable = False
        while True:
            while self._queue:
                head = self._queue[0]
                error = self._write(head)
                if error is not None:
                    self._error = error
                    if not self._outage:
                        self._outage = True
                        self._messages.append(
                            f"violation log: {self._path}: cannot write: {error}; records "
                            f"are kept in memory (up to {self._cap}) and retried"
                        )
                    self._start_retrier()
                    break
                self._queue.popleft()
                self._queued -= head.counted
                head.state = "written"
                wrote_durable = wrote_durable or head.durable
                if self._outage:
                    self._late += 1
            if self._queue or not self._lost:
                break
            self._queue_lost()
        if wrote_durable and self._sync_each:
            if (
                self._durability == "after_publish"
                and self.defer_thread is not None
                and threading.get_ident() == self.defer_thread
            ):
                self._sync_due = True  # flush() fsyncs it, after the actions are out
            else:
                synced = self._fsync()
        self._unsynced = not synced
        if self._outage and not self._queue and not self._lost:
            self._outage = False
            self._messages.append(
                f"violation log: {self._path}: writing again; {self._late} records "
                "were written late"
            )
            self._late = 0

    def _fsync(self) -> bool:
        """Fsync the file (under the lock); False, and a report, when it fails."""
        self._sync_due = False
        try:
            os.fsync(self._fd)  # type: ignore[arg-type]
        except OSError as e:
            self._messages.append(
                f"violation log: {self._path}: written but not fsynced: {e.strerror}"
            )
            return False
        return True

    def _start_retrier(self) -> None:
        if self._retrier is not None or self._closed.is_set():
            return
        self._retrier = threading.Thread(
            target=self._retry_loop, name="violation-log-retry", daemon=True
        )
        self._retrier.start()

    def _retry_loop(self) -> None:
        while not self._closed.wait(self._retry_s):  # returns at once when closed
            with self._lock:
                if self._fd is None:
                    self._retrier = None
                    return
                self._drain()
                done = not self._queue and not self._lost
                if done:
                    self._retrier = None  # the next failure starts a new one
            self._flush_messages()
            if done:
                return

    def _write(self, entry: _Entry) -> str | None:
        """Write one queued record, chained to the file's last line; the error text or None."""
        assert self._fd is not None
        written = 0
        try:
            if self._resync or os.fstat(self._fd).st_size != self._size:
                self._load_tail()  # copytruncate, another writer, a failed write
            line = entry.line(self._prev)
            data = b"\n" + line if self._needs_newline else line
            # One write per line; the loop only continues a short write (disk
            # nearly full), still under the lock, so nothing interleaves.
            while written < len(data):
                n = os.write(self._fd, data[written:])
                if n == 0:
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                written += n
        except OSError as e:
            # Part of the line may be in the file: re-read the tail before the next
            # write, which ends that fragment and chains over it.
            self._resync = True
            return e.strerror or str(e)
        self._size += written
        # The line's hash is made when the next record needs it: a violation's is
        # then made after its halt is out, not before (docs/reference/log.md#durability).
        self._prev_hex, self._prev_line = None, line
        self._needs_newline = False
        self._tail = entry.written = line[:-1]
        return None

    def _echo_line(self, record: dict[str, Any], line: bytes | None = None) -> None:
        """``line``: the record as written (or as rendered, when not written yet)."""
        if self._echo is False:
            return
        if self._journald is not None and self._to_journal(record, line) and self._journal:
            return  # stderr is the journal, which has the record with its fields already
        stream = sys.stderr if self._echo is True else self._echo
        level = priority(record)
        try:
            prefix = f"<{level}>" if self._journal and stream is sys.stderr else ""
            stream.write(prefix + describe(record) + "\n")
            stream.flush()
        except (OSError, ValueError):
            pass  # a closed stderr must not stop monitoring

    def _to_journal(self, record: dict[str, Any], line: bytes | None) -> bool:
        assert self._journald is not None
        text = line.decode("ascii") if line is not None else json.dumps(record)
        if self._journald.send(record_fields(record, text)):
            return True
        if not self._journald_reported:  # once: a missing journal must not flood stderr
            self._journald_reported = True
            self._print(
                f"violation log: cannot send records to the journal socket "
                f"{self._journald.path}: {self._journald.error}; records are echoed on "
                "stderr instead (reported once)"
            )
        return False

    def _flush_messages(self) -> None:
        """Print the reports gathered under the lock (never print while holding it)."""
        with self._lock:
            messages, self._messages = self._messages, []
            echoes, self._echoes = self._echoes, []
        for entry in echoes:
            if self._echo is not False:
                line = entry.written or entry.body
                self._echo_line(json.loads(line), line)
        for text in messages:
            self._print(text)

    def _print(self, text: str) -> None:
        if self._say is not None:
            self._say(text)
            return
        try:
            sys.stderr.write(("<3>" if self._journal else "") + text + "\n")
            sys.stderr.flush()
        except (OSError, ValueError):
            pass


def _header_json(component: str, config_sha256: str) -> str:
    """The header's ``component`` and ``config_sha256`` as _render encodes them."""
    return _ENCODE({"component": component, "config_sha256": config_sha256})[1:-1]


def _checked_durability(value: str) -> str:
    # The config loader validates logging.durability with its line; this guards
    # the other callers (tools, tests).
    if value not in DURABILITIES:
        raise ValueError(f"durability must be one of {', '.join(DURABILITIES)}, not {value!r}")
    return value


def _add_seq(ranges: list[list[int]], seq: int) -> None:
    if ranges and ranges[-1][1] == seq - 1:
        ranges[-1][1] = seq
    else:
        ranges.append([seq, seq])
