"""Recordings read back as a time-ordered stream of the config's input values.

Inputs (any mix, merged by receive time):

- a rosbag2 bag directory (``metadata.yaml``, versions 1 to 9, and ``.db3`` or
  ``.mcap`` files, zstd-compressed per file or per message; or the files alone, in
  rosbag2's order, without ``metadata.yaml``), or one of its storage files given
  directly, also an MCAP file whose recorder was killed before writing its summary;
- a JSON-lines trace (``.jsonl``/``.json``), one object per line::

      {"t_ns": 1500000000, "name": "speed", "value": 0.25}
      {"t_ns": 1600000000, "record": {"event": "marker", "what": "start"}}

  ``t_ns`` is a whole number of nanoseconds, not decreasing from line to line;
  ``name`` is a topic variable of the config and ``value`` a JSON value of its type
  (``true``/``false``, an integer, a number); ``record`` passes a log record through.
  Any other shape is an error naming the line.

Two ways to read (the replay engine picks): ``Recording.events()`` yields one event
per message, ``Recording.batches()`` the same data as columns of up to ``chunk``
messages. Events are ``(t_ns, topic, [(variable, value), ...])`` with every config
variable read from that topic, and ``(t_ns, "record", dict)`` for the daemon's own
JSON records recorded on ``RECORD_TOPICS`` (markers, resets, violations). Times are
the bag's receive (log) time in nanoseconds.

Damage (a truncated or corrupt file, a message that does not decode) ends the stream:
everything readable before it is yielded first, then a ``UserError`` names the file and
the position (message number, byte offset or line, last timestamp).

Speed: the bag readers here read the storage directly: sqlite3 in timestamp order
through apsw (rosbags' own SQLite binding, a fifth faster than the sqlite3 module at
fetching rows), the MCAP records with struct and numpy, since rosbags' MCAP reader
reaches about 0.5 M messages/s and refuses a file without its summary. rosbags
supplies the types: the bag's own message definitions, its CDR deserialiser for
variable-size messages, and its ROS 2 Jazzy types for bags without definitions. A primitive field (``cdr.py``: at a fixed CDR offset, or after strings and
primitive sequences whose lengths each message gives) is decoded for a whole batch with
numpy; any other field is deserialised message by message.
"""

from __future__ import annotations

import re
import struct
import weakref
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from rosbags.interfaces import Nodetype
from rosbags.typesys.store import Typestore

from mitigations.rosmsg import COMPATIBLE, package_hint
from monitors.errors import UserError
from monitors.untrusted import Untrusted, load_json, printable, read_regular
from supervisor.config.model import Config, Variable
from supervisor.daemon.cdr import PRIMITIVES, FieldPlan, field_plan
from supervisor.inputs.paths import ReadError
from supervisor.inputs.readers import SKIP, arrival_only, make_reader, plain_field
from supervisor.names import VIOLATIONS_TOPIC
from supervisor.tools.replay.mcap import Mcap
from supervisor.tools.replay.sqlite import Sqlite
from supervisor.tools.replay.storage import (
    CHUNK,
    DEFAULT_BOUNDS,
    DTYPES,
    METADATA_BYTES,
    RECORD_BYTES,
    RECORD_TOPICS,
    RECORDS_TOPIC,
    STRING,
    Bounds,
    Damage,
    Event,
    Progress,
    Raw,
    Source,
    field_value,
    inflate_file,
    normalise_type,
    open_regular,
    refuse_serialization,
)
from supervisor.tools.replay.trace import Trace


@dataclass(frozen=True)
class Unread:
    """A message that has no value for a variable (an element past the end)."""

    why: str


@dataclass
class Batch:
    """Up to ``chunk`` messages in receive order, as columns.

    Row i is a message on ``topics[topic[i]]`` received at ``t_ns[i]``. ``values[v]``
    holds variable v's value on the rows of v's topic (other rows are 0); ``records``
    are the rows of ``RECORD_TOPICS`` with their parsed record; ``given`` (JSON-lines
    traces only) marks the rows of v's topic that set v."""

    t_ns: np.ndarray  # int64
    topic: np.ndarray  # int32, index into topics
    topics: list[str]
    values: dict[str, np.ndarray]
    records: dict[int, dict[str, Any]] = field(default_factory=dict)
    # A JSON-lines line sets one variable of its topic: given[v] marks the rows that
    # set v. A variable not in given has a value on every row of its topic.
    given: dict[str, np.ndarray] = field(default_factory=dict)
    # Rows whose value for a variable no column holds: the raw value (the runtime
    # rejects it, as it does online) or Unread (the field was not in the message).
    odd: dict[int, list[tuple[str, Any]]] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t_ns)

    def rows(self, topic: str) -> np.ndarray:
        """The row mask of one topic."""
        return self.topic == self.topics.index(topic)


@dataclass
class _TopicReader:
    """How one topic's payloads become values."""

    topic: str
    msgtype: str
    variables: list[Variable]
    plans: list[FieldPlan | None]  # None: deserialise each message
    record: bool = False
    # Per variable, the column's numpy dtype: the field's own type, so that a value
    # the variable's type cannot hold (a uint64 above 2^63-1) reaches the runtime as
    # it is and is rejected there, as the daemon rejects it.
    dtypes: list[Any] = field(default_factory=list)
    # Per variable, how a deserialised message is read (supervisor/inputs/readers.py).
    readers: list[Callable[[Any], Any]] = field(default_factory=list)


# --- rosbag2 directories --------------------------------------------------------------


def _load_metadata(meta: Path) -> Any:
    """The parsed metadata.yaml, at most METADATA_BYTES of a regular file."""
    try:
        text = read_regular(meta, max_bytes=METADATA_BYTES)
    except Untrusted as e:
        raise UserError(f"not a readable rosbag2 metadata file ({e})", file=str(meta)) from None
    try:
        return yaml.load(text, Loader=_YamlLoader)  # noqa: S506 - a safe loader
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise UserError(
            f"not a readable rosbag2 metadata file ({printable(str(problem))})",
            file=str(meta),
            line=line,
        ) from None


def bag_info(meta: Path) -> tuple[dict[str, str], dict[str, int], list[str]]:
    """The topics (name -> type), message counts and storage file names of a bag's
    metadata.yaml: one check of its shape, each fault one line naming the key."""

    def bad(where: str, what: str) -> UserError:
        return UserError(f"{where}: {what}", file=str(meta))

    doc = _load_metadata(meta)
    info = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
    if not isinstance(info, dict):
        raise bad("rosbag2_bagfile_information", "missing, or not a mapping")
    # zstd per file (the files end in .zstd) or per message (each payload says so by
    # zstd's magic): both are read as they are, supervisor/tools/replay/storage.py
    mode, fmt = info.get("compression_mode") or "", info.get("compression_format") or ""
    if str(mode).upper() not in ("", "NONE", "FILE", "MESSAGE"):
        raise bad("compression_mode", f"'{printable(str(mode)[:40])}' is not FILE, MESSAGE or NONE")
    if mode and str(mode).upper() != "NONE" and fmt != "zstd":
        raise bad("compression_format", f"'{printable(str(fmt)[:40])}' is not zstd")
    entries = info.get("topics_with_message_count") or []
    if not isinstance(entries, list):
        raise bad("topics_with_message_count", "not a list")
    topics: dict[str, str] = {}
    counts: dict[str, int] = {}
    for k, t in enumerate(entries):
        tm = t.get("topic_metadata") if isinstance(t, dict) else None
        name = tm.get("name") if isinstance(tm, dict) else None
        typ = tm.get("type") if isinstance(tm, dict) else None
        if not isinstance(name, str) or not isinstance(typ, str):
            raise bad(f"topics_with_message_count[{k}]", "no topic_metadata with a name and a type")
        n = t.get("message_count") or 0
        if not isinstance(n, int) or isinstance(n, bool) or n < 0:
            raise bad(f"topics_with_message_count[{k}].message_count", "not a whole number >= 0")
        fmt = tm.get("serialization_format") or ""
        if not isinstance(fmt, str):
            raise bad(f"topics_with_message_count[{k}].serialization_format", "not a string")
        refuse_serialization(name, fmt, str(meta.parent))
        topics[name] = normalise_type(typ)
        counts[name] = n
    files = info.get("relative_file_paths") or []
    if not isinstance(files, list):
        raise bad("relative_file_paths", "not a list")
    for k, f in enumerate(files):
        # a bag names its own files: never a path elsewhere, a device or a FIFO
        if not (isinstance(f, str) and _FILE_NAME.fullmatch(f)):
            shown = printable(repr(f)[:80])
            raise bad(
                f"relative_file_paths[{k}]",
                f"{shown} is not a file name in the bag directory ending in .mcap or .db3"
                " (or either with .zstd)",
            )
    return topics, counts, files


_FILE_NAME = re.compile(r"[^/\\\x00]+\.(mcap|db3)(\.zstd)?")
_STORAGE = (".mcap", ".db3", ".mcap.zstd", ".db3.zstd")


def _storage_files(path: Path) -> list[Path]:
    """A bag directory's storage files in rosbag2's order, ``x_2`` before ``x_10``."""

    def key(f: Path) -> list[Any]:
        return [(0, int(p), "") if p.isdigit() else (1, 0, p) for p in re.split(r"(\d+)", f.name)]

    return sorted((f for f in path.iterdir() if f.name.endswith(_STORAGE)), key=key)


_YamlLoader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml: 10x faster


def bag_dir(path: Path, bounds: Bounds = DEFAULT_BOUNDS) -> list[Source]:
    topics, counts, names = bag_info(path / "metadata.yaml")
    files = [path / p for p in names] or _storage_files(path)
    sources: list[Source] = []
    for k, f in enumerate(files):
        if not f.exists():
            raise UserError(f"the bag's file {f.name} is missing", file=str(path))
        # the bag's counts are per topic over all its files: give them to the first
        part = counts if k == 0 else {}
        sources.append(_storage(f, bounds, part, topics))
    return sources


def _storage(
    f: Path,
    bounds: Bounds,
    counts: dict[str, int] | None = None,
    topics: dict[str, str] | None = None,
) -> Source:
    """One storage file, if it is a regular file (a FIFO would be waited on)."""
    try:
        open_regular(f).close()
    except Damage as e:
        raise UserError(str(e), file=str(f)) from None
    if f.suffix != ".zstd":
        if f.suffix == ".mcap":
            return Mcap(f, counts, topics, bounds)
        return Sqlite(f, counts, bounds, topics=topics)
    # zstd per file: read a decompressed copy, deleted with the source
    try:
        plain = inflate_file(f, bounds)
    except Damage as e:
        raise UserError(str(e), file=str(f)) from None
    try:
        src: Source
        if plain.suffix == ".mcap":
            src = Mcap(plain, counts, topics, bounds, label=str(f))
        else:
            src = Sqlite(plain, counts, bounds, label=str(f), topics=topics)
    except BaseException:
        plain.unlink(missing_ok=True)
        raise
    weakref.finalize(src, plain.unlink, missing_ok=True)
    return src


# --- the recording --------------------------------------------------------------------


def _column_dtype(leaf: str, vtype: str) -> Any:
    """A column for a field of ROS type ``leaf``: its own numpy type (bool for a bool)."""
    if leaf == "bool":
        return np.bool_
    prim = PRIMITIVES.get(leaf)
    return np.dtype(prim[1].lstrip("<")) if prim is not None else DTYPES[vtype]


def _leaf_type(store: Typestore, msgtype: str, path: str) -> str:
    """The primitive type at a dotted path of msgtype, from the recording's types."""
    typ = msgtype
    parts = path.split(".")
    for i, part in enumerate(parts):
        fields = dict(store.fielddefs[typ][1])
        if part not in fields:
            raise UserError(f"{typ} has no field '{part}' (fields: {', '.join(fields) or 'none'})")
        kind, detail = fields[part]
        last = i == len(parts) - 1
        if kind == Nodetype.BASE and last:
            return "boolean" if detail[0] == "bool" else detail[0]
        if kind == Nodetype.NAME and not last:
            typ = detail
            continue
        raise UserError(f"field '{'.'.join(parts[: i + 1])}' of {msgtype} is not a number or bool")
    raise AssertionError("unreachable")


@dataclass
class _Columns:
    """What ``Recording._decode`` builds from one raw chunk, and the first message
    that did not decode (``bad``, its row; ``error``, the located line)."""

    raw: Raw
    first: int  # messages read before this chunk
    values: dict[str, np.ndarray] = field(default_factory=dict)
    records: dict[int, dict[str, Any]] = field(default_factory=dict)
    given: dict[str, np.ndarray] = field(default_factory=dict)
    odd: dict[int, list[tuple[str, Any]]] = field(default_factory=dict)
    bad: int = -1
    error: str | None = None

    def __post_init__(self) -> None:
        self.bad = self.n

    @property
    def n(self) -> int:
        return len(self.raw)

    def fail(self, i: int, topic: str, what: str) -> None:
        """Row ``i`` did not decode: the batch ends before the earliest such row."""
        if i < self.bad:
            t = int(self.raw.t_ns[i])
            self.bad = i
            self.error = f"message {self.first + i + 1} read (topic {topic}, t_ns {t}) {what}"

    def trace_values(self, rd: _TopicReader, rows: np.ndarray) -> None:
        """A JSON-lines trace's rows of one topic: each line sets one variable."""
        items, n = self.raw.items, self.n
        assert items is not None
        for i in rows.tolist():
            if rd.record:
                self.records[i] = items[i]
        for v in rd.variables:
            col = np.zeros(n, dtype=DTYPES[v.type])
            mask = np.zeros(n, dtype=np.bool_)
            for i in rows.tolist():
                name, value = items[i]
                if name == v.name:
                    col[i], mask[i] = value, True
            self.values[v.name], self.given[v.name] = col, mask

    def batch(self, topics: list[str]) -> Batch:
        """The rows before the first that did not decode."""
        bad, raw = self.bad, self.raw
        return Batch(
            raw.t_ns[:bad],
            raw.topic[:bad],
            topics,
            {k: c[:bad] for k, c in self.values.items()},
            {i: r for i, r in self.records.items() if i < bad},
            {k: m[:bad] for k, m in self.given.items()},
            {i: x for i, x in self.odd.items() if i < bad},
        )


class NothingToJudge(UserError):
    """The recordings hold nothing the config reads: no topic of it, or no message on
    them (``fleet replay`` counts such a bag as skipped, not failed)."""


class Recording:
    """Recordings opened for a config; see the module docstring."""

    def __init__(self, sources: list[Source], cfg: Config, namespace: str = "/") -> None:
        self.sources = sources
        self.cfg = cfg
        self.warnings: list[str] = [w for s in sources for w in s.warnings]
        by_topic: dict[str, list[Variable]] = {}
        for v in cfg.inputs:
            if v.topic:
                by_topic.setdefault(v.topic, []).append(v)
        # per source, each recorded name -> the config's name for it (resolve())
        self.names: list[dict[str, str]] = []
        recorded: dict[str, str] = {}
        self.ignored: dict[str, set[str]] = {}
        for src in sources:
            names = self._resolved(src, by_topic, namespace)
            self.names.append(names)
            resolved = set(names.values())
            for topic, typ in src.topics.items():
                name = names[topic]
                if name in by_topic:
                    want = normalise_type(by_topic[name][0].msg or "")
                    if typ != want:
                        v = by_topic[name][0]
                        raise UserError(
                            f"topic {topic} is recorded as {typ}, but the config reads it as {want}",
                            file=src.label,
                            hint=f"variable '{v.name}' at {cfg.path}:{v.line}",
                        )
                    recorded[name] = typ
                elif name == VIOLATIONS_TOPIC and RECORDS_TOPIC in resolved:
                    # the same violations are on the records topic beside it
                    self.ignored.setdefault(src.label, set()).add(topic)
                elif name in RECORD_TOPICS:
                    if typ != STRING:
                        raise UserError(
                            f"topic {topic} is recorded as {typ}, not {STRING}", file=src.label
                        )
                    recorded[name] = typ
                else:
                    self.ignored.setdefault(src.label, set()).add(topic)
        if by_topic and not recorded:  # the daemon's own records alone are read
            bag = sorted({t for s in sources for t in s.topics})
            raise NothingToJudge(
                "no topic of the config is in the recordings, so nothing would be judged: "
                f"recorded: {', '.join(bag) or 'none'}; the config reads: {', '.join(sorted(by_topic))}",
                file=", ".join(s.label for s in sources) or "replay",
                hint="a robot's bag recorded in a namespace maps onto the config with "
                "--namespace (or ros.namespace)",
            )
        # config topics no recording has: also apart, for replay to say them at its end
        # and in --json (docs/reference/commands.md, replay)
        self.missing: dict[str, str] = {}
        for t in (t for t in by_topic if t not in recorded):
            names_ = [v.name for v in by_topic[t]]
            # an event is false until its message comes (docs/reference/config.md), so
            # only a value without 'initial:' keeps the monitor from stepping
            no_initial = [v.name for v in by_topic[t] if v.initial is None and not v.event]
            text = f"warning: topic {t} ({', '.join(names_)}) is in none of the recordings"
            if no_initial:
                verb = "gets" if len(no_initial) == 1 else "get"
                text += (
                    f"; without 'initial:', {', '.join(no_initial)} never {verb} a value, "
                    "so the monitor never steps"
                )
            self.missing[t] = printable(text)
            self.warnings.append(text)
        self.topics = sorted(recorded)
        self.ids = {t: i for i, t in enumerate(self.topics)}
        self.by_topic = by_topic
        # the messages to read, if every source's metadata counts them
        self.total: int | None = None
        if all(s.counts is not None for s in sources):
            self.total = sum(
                n
                for s, names in zip(sources, self.names, strict=True)
                for t, n in (s.counts or {}).items()
                if names.get(t, t) in recorded and t not in self.ignored.get(s.label, ())
            )
        # Fields are checked against the recorded types now, before anything is read.
        self._topic_readers = [self._readers(s) for s in sources]

    @staticmethod
    def _resolved(
        src: Source, by_topic: dict[str, list[Variable]], namespace: str
    ) -> dict[str, str]:
        """Each recorded name as the config names it: a relative name (rosbag2 records
        ``topic1``) is resolved in the root namespace as rclpy does, ``/topic1``; a name
        under ``namespace`` (a robot's, like ``/robot1``) that the config does not name
        as it is loses that prefix, so ``/robot1/scan`` is the config's ``/scan``.
        Two recorded names for one config topic in one file are an error."""
        out: dict[str, str] = {}
        for topic in src.topics:
            name = topic if topic.startswith("/") else f"/{topic}"
            if namespace != "/" and name not in by_topic and name.startswith(namespace + "/"):
                name = name[len(namespace) :]
            out[topic] = name
        seen: dict[str, str] = {}
        for topic, name in out.items():
            if name in seen and (name in by_topic or name in RECORD_TOPICS):
                raise UserError(
                    f"topics {seen[name]} and {topic} are both the config's {name}",
                    file=src.label,
                    hint="replay one of them, or give the namespace that tells them apart",
                )
            seen[name] = topic
        return out

    def summary(self) -> str:
        """What is read and what is not, a line each."""
        lines = [f"reading {len(self.topics)} topic(s): {', '.join(self.topics) or 'none'}"]
        for label, topics in self.ignored.items():
            lines.append(f"{label}: ignored (not in the config): {', '.join(sorted(topics))}")
        # topic names come from the recording: never control sequences on a terminal
        return "\n".join(printable(line) for line in [*lines, *self.warnings])

    def _readers(self, src: Source) -> dict[int, _TopicReader]:
        out: dict[int, _TopicReader] = {}
        recorded_as = {n: t for t, n in self.names[self.sources.index(src)].items()}
        for topic, tid in self.ids.items():
            if topic not in recorded_as:
                continue
            if topic in RECORD_TOPICS:
                out[tid] = _TopicReader(topic, STRING, [], [], record=True)
                continue
            variables = self.by_topic[topic]
            msgtype = src.topics[recorded_as[topic]]
            plans: list[FieldPlan | None] = []
            dtypes: list[Any] = []
            for v in variables:
                if isinstance(src, Trace) or plain_field(v) is None:
                    # an event reads no field; a reduction, an element, a stamp or
                    # a service call's field reads each message whole
                    plans.append(None)
                    dtypes.append(np.int64 if v.age_of else DTYPES[v.type])
                    continue
                try:
                    leaf = _leaf_type(src.store, msgtype, v.field)
                except UserError as e:
                    raise UserError(f"topic {topic}: {e.message}", file=src.label) from None
                except KeyError as e:
                    raise UserError(
                        f"topic {topic}: type {e.args[0]} is defined neither in the recording "
                        f"nor by an installed package: {package_hint(str(e.args[0]))}",
                        file=src.label,
                    ) from None
                if leaf not in COMPATIBLE[v.type]:
                    raise UserError(
                        f"topic {topic}: field '{v.field}' of {msgtype} is {leaf}, which cannot feed the {v.type} variable '{v.name}'",
                        file=src.label,
                    )
                plans.append(field_plan(src.store, msgtype, v.field))
                dtypes.append(_column_dtype(leaf, v.type))
            readers = [] if isinstance(src, Trace) else [make_reader(v) for v in variables]
            out[tid] = _TopicReader(
                topic, msgtype, variables, plans, dtypes=dtypes, readers=readers
            )
        return out

    def _decode(
        self, src: Source, readers: dict[int, _TopicReader], raw: Raw, first: int
    ) -> tuple[Batch, str | None]:
        """Columns of one raw chunk; on a message that does not decode, the columns
        of the messages before it and the located error."""
        out = _Columns(raw, first)
        arr = np.frombuffer(raw.buf, np.uint8)
        for tid, rd in readers.items():
            rows = np.flatnonzero(raw.topic == tid)
            if not len(rows):
                continue
            if raw.items is not None:  # a JSON-lines trace: values already checked
                out.trace_values(rd, rows)
            elif rd.record:
                self._decode_records(src, rd, rows, out)
            else:
                slow = self._gather(src, rd, arr, rows, out)
                if slow:
                    self._deserialize(src, rd, rows, slow, out)
        return out.batch(self.topics), out.error

    def _decode_records(
        self, src: Source, rd: _TopicReader, rows: np.ndarray, out: _Columns
    ) -> None:
        """The parsed record of each row of a record topic, up to the first that fails."""
        for i in rows.tolist():
            try:
                out.records[i] = self._record(src, out.raw.payload(i))
            except ValueError as e:
                out.fail(i, rd.topic, str(e))
                break

    def _gather(
        self, src: Source, rd: _TopicReader, arr: np.ndarray, rows: np.ndarray, out: _Columns
    ) -> list[tuple[Variable, Callable[[Any], Any]]]:
        """The columns read in bulk from the payloads at their planned offsets; returns
        the variables (with their readers) that need each message deserialised."""
        raw, n = out.raw, out.n
        slow: list[tuple[Variable, Callable[[Any], Any]]] = []
        for j, (v, plan) in enumerate(zip(rd.variables, rd.plans, strict=True)):
            if arrival_only(v):
                # true on every message of its topic: its arrival is the value
                col = np.zeros(n, dtype=np.bool_)
                col[rows] = True
                out.values[v.name] = col
                continue
            got = plan.gather(arr, raw.start[rows], raw.end[rows]) if plan else None
            if got is not None and not plan.fixed and not self._agrees(src, rd, v, raw, rows, got):  # type: ignore[union-attr]
                rd.plans[j] = None  # the layout guess is wrong for this data
                got = None
            if got is None:
                slow.append((v, rd.readers[j]))
                continue
            col = np.zeros(n, dtype=rd.dtypes[j])
            col[rows] = got != 0 if col.dtype == np.bool_ else got
            out.values[v.name] = col
        return slow

    @staticmethod
    def _deserialize(
        src: Source,
        rd: _TopicReader,
        rows: np.ndarray,
        slow: list[tuple[Variable, Callable[[Any], Any]]],
        out: _Columns,
    ) -> None:
        """One deserialisation per message for all of the topic's ``slow`` fields."""
        n = out.n
        dtype_of = dict(zip((v.name for v in rd.variables), rd.dtypes, strict=True))
        cols = {v.name: np.zeros(n, dtype=dtype_of[v.name]) for v, _ in slow}
        # A message may carry no value for a variable (a service event of the
        # other direction, an element past the end): not given on its row.
        has = {v.name: np.ones(n, dtype=np.bool_) for v, _ in slow}
        for i in rows.tolist():
            if i >= out.bad:
                break
            try:
                msg = src.store.deserialize_cdr(out.raw.payload(i), rd.msgtype)
            except Exception as e:  # noqa: BLE001 - any failure here is the data's
                out.fail(i, rd.topic, f"does not decode as {rd.msgtype} ({e})")
                break
            for v, read in slow:
                try:
                    x = read(msg)
                except (ReadError, AttributeError, TypeError, ValueError) as e:
                    x = Unread(str(e))
                if x is SKIP:
                    has[v.name][i] = False
                    continue
                if not isinstance(x, Unread):
                    try:
                        cols[v.name][i] = x
                        continue
                    except (OverflowError, ValueError, TypeError):
                        pass  # -inf for an int64: the runtime rejects it
                has[v.name][i] = False
                out.odd.setdefault(i, []).append((v.name, x))
        out.values.update(cols)
        out.given.update({k: m for k, m in has.items() if not m[rows].all()})

    @staticmethod
    def _agrees(
        src: Source, rd: _TopicReader, v: Variable, raw: Raw, rows: np.ndarray, got: np.ndarray
    ) -> bool:
        """A bulk read past strings and sequences, checked against rosbags'
        deserialiser on a few messages (first, middle, last)."""
        for k in {0, len(rows) // 2, len(rows) - 1}:
            try:
                want = field_value(
                    src.store.deserialize_cdr(raw.payload(int(rows[k])), rd.msgtype), v.field
                )
            except Exception:  # noqa: BLE001 - the per-message path will locate it
                return False
            if want != got[k] and not (want != want and got[k] != got[k]):  # NaN == NaN here
                return False
        return True

    @staticmethod
    def _record(src: Source, payload: bytes) -> dict[str, Any]:
        try:
            text = src.store.deserialize_cdr(payload, STRING).data  # type: ignore[attr-defined]
        except Exception as e:  # noqa: BLE001
            raise ValueError(f"does not decode as {STRING}: {e}") from None
        try:
            rec = load_json(text, max_bytes=RECORD_BYTES)
        except Untrusted as e:
            raise ValueError(f"not a JSON record ({e})") from None
        if not isinstance(rec, dict):
            raise ValueError("not a JSON object")
        return rec

    def _source_batches(self, src: Source, chunk: int) -> Iterator[Batch | UserError]:
        """One source's batches; damage ends them with the located error."""
        readers = self._topic_readers[self.sources.index(src)]
        names = self.names[self.sources.index(src)]
        ids = {
            t: self.ids[n]
            for t, n in names.items()
            if n in self.ids and t not in self.ignored.get(src.label, ())
        }
        first = 0
        last = -1
        try:
            for whole in src.chunks(ids, chunk):
                neg = np.flatnonzero(whole.t_ns < 0)  # a reader's int64 wrapped round
                cut = int(neg[0]) if len(neg) else len(whole)
                for i in range(0, cut, chunk):
                    raw = whole.part(i, min(i + chunk, cut))
                    batch, error = self._decode(src, readers, raw, first)
                    first += len(raw)
                    if len(batch):
                        if int(batch.t_ns[0]) < last:
                            self._warn_order(src, last)
                        last = int(batch.t_ns[-1])
                        yield batch
                    if error:
                        yield _printable(UserError(error, file=src.label))
                        return
                if cut < len(whole):
                    raise Damage(
                        f"damaged: message {first + 1} read has a receive time past 2^63-1 ns"
                    )
        except Damage as e:
            yield _printable(UserError(str(e), file=src.label))
        except UserError as e:
            yield _printable(e)
        except (struct.error, ValueError, OverflowError, IndexError, UnicodeDecodeError) as e:
            # a fault of the recording no check above names: damage all the same,
            # never a traceback (docs/reference/faults.md, "Trust")
            text = f"damaged: {type(e).__name__}: {e}; {first} messages read"
            yield _printable(UserError(text, file=src.label))

    def _warn_order(self, src: Source, t: int) -> None:
        text = (
            f"warning: {src.label}: messages before t_ns {t} come after it in the file; "
            "they are replayed in file order"
        )
        if text.split(" before ")[0] not in "\n".join(self.warnings):
            self.warnings.append(text)

    def batches(self, chunk: int = CHUNK, progress: Progress | None = None) -> Iterator[Batch]:
        """Columns of up to ``chunk`` messages in receive order across all sources;
        raises the located UserError after the last readable batch.

        A damaged source ends the stream at its last readable message: the other
        sources' later messages are not yielded, so what is replayed is a gapless
        prefix of the recording."""
        gens = [self._source_batches(s, chunk) for s in self.sources]
        bufs: list[Batch | None] = [None] * len(gens)
        last = [-1] * len(gens)
        live = set(range(len(gens)))
        error: UserError | None = None
        stop_at: int | None = None
        done = 0
        while True:
            for k in sorted(live):
                if bufs[k] is not None:
                    continue
                item = next(gens[k], None)
                if isinstance(item, UserError):
                    live.discard(k)
                    if stop_at is None or last[k] < stop_at:
                        stop_at, error = last[k], item
                elif item is None:
                    live.discard(k)
                else:
                    bufs[k], last[k] = item, int(item.t_ns[-1])
            have = [k for k, b in enumerate(bufs) if b is not None]
            if not have:
                break
            # Rows up to the earliest last time of the sources still reading are final:
            # none of them can deliver an earlier message any more.
            bound = min((last[k] for k in live), default=None)
            if stop_at is not None:
                bound = stop_at if bound is None else min(bound, stop_at)
            parts = []
            for k in have:
                b = bufs[k]
                assert b is not None
                cut = len(b) if bound is None else int(np.searchsorted(b.t_ns, bound, side="right"))
                parts.append(_slice(b, 0, cut))
                bufs[k] = _slice(b, cut, len(b)) if cut < len(b) else None
            out = _merge(parts)
            if out is not None:
                done += len(out)
                yield out
                if progress:
                    progress(done, self.total)
            if stop_at is not None and bound == stop_at:
                break
        if error is not None:
            raise error

    def events(self, chunk: int = CHUNK, progress: Progress | None = None) -> Iterator[Event]:
        """One event per message in receive order: ``(t_ns, topic, [(var, value)])``
        or ``(t_ns, "record", dict)``; raises the located UserError after the last
        readable event."""
        names = {
            self.ids[t]: [v.name for v in vs] for t, vs in self.by_topic.items() if t in self.ids
        }
        for batch in self.batches(chunk, progress):
            ts = batch.t_ns.tolist()
            tops = batch.topic.tolist()
            cols = {k: c.tolist() for k, c in batch.values.items()}
            given = {k: m.tolist() for k, m in batch.given.items()}
            records = batch.records
            for i, (t, tid) in enumerate(zip(ts, tops, strict=True)):
                if i in records:
                    yield (t, "record", records[i])
                    continue
                if given:
                    vals = [(n, cols[n][i]) for n in names[tid] if n in cols]
                    vals = [(n, x) for n, x in vals if n not in given or given[n][i]]
                else:
                    vals = [(n, cols[n][i]) for n in names[tid]]
                # a raw value no column holds goes on for the runtime to reject
                vals += [(n, x) for n, x in batch.odd.get(i, ()) if not isinstance(x, Unread)]
                yield (t, self.topics[tid], vals)


def _slice(b: Batch, i: int, j: int) -> Batch:
    return Batch(
        b.t_ns[i:j],
        b.topic[i:j],
        b.topics,
        {k: c[i:j] for k, c in b.values.items()},
        {r - i: rec for r, rec in b.records.items() if i <= r < j},
        {k: m[i:j] for k, m in b.given.items()},
        {r - i: x for r, x in b.odd.items() if i <= r < j},
    )


def _merge(parts: list[Batch]) -> Batch | None:
    """Parts into one batch in receive order (stable: a source's own order is kept)."""
    parts = [p for p in parts if len(p)]
    if len(parts) <= 1:
        return parts[0] if parts else None
    topics = parts[0].topics
    t = np.concatenate([p.t_ns for p in parts])
    top = np.concatenate([p.topic for p in parts])
    names = {k: p.values[k].dtype for p in parts for k in p.values}
    values = {
        k: np.concatenate([p.values.get(k, np.zeros(len(p), dtype=dt)) for p in parts])
        for k, dt in names.items()
    }
    given = {
        k: np.concatenate([p.given.get(k, np.ones(len(p), dtype=np.bool_)) for p in parts])
        for k in {k for p in parts for k in p.given}
    }
    records: dict[int, dict[str, Any]] = {}
    odd: dict[int, list[tuple[str, Any]]] = {}
    base = 0
    for p in parts:
        records.update({base + r: rec for r, rec in p.records.items()})
        odd.update({base + r: x for r, x in p.odd.items()})
        base += len(p)
    order = np.argsort(t, kind="stable")
    inverse = np.empty_like(order)
    inverse[order] = np.arange(len(order))
    return Batch(
        t[order],
        top[order],
        topics,
        {k: c[order] for k, c in values.items()},
        {int(inverse[r]): rec for r, rec in records.items()},
        {k: m[order] for k, m in given.items()},
        {int(inverse[r]): x for r, x in odd.items()},
    )


def _open_one(path: Path, cfg: Config) -> list[Source]:
    if not path.exists():
        raise UserError("no such file or directory", file=str(path))
    bounds = Bounds(cfg.limits.replay_chunk_bytes, cfg.limits.replay_ratio)
    if path.is_dir():
        if (path / "metadata.yaml").exists():
            return bag_dir(path, bounds)
        files = _storage_files(path)
        if not files:
            raise UserError(
                "not a rosbag2 bag: no metadata.yaml, .mcap or .db3 file (or .zstd of one)",
                file=str(path),
            )
        # a bag directory whose recorder died before writing metadata.yaml
        return [_storage(f, bounds) for f in files]
    if path.name.endswith(_STORAGE):
        return [_storage(path, bounds)]
    if path.suffix in (".jsonl", ".json", ".ndjson"):
        return [Trace(path, cfg)]
    raise UserError(
        f"unknown recording format '{path.suffix}'",
        file=str(path),
        hint="give a rosbag2 bag directory, a .mcap or .db3 file (or .zstd of one), or a .jsonl trace",
    )


def open_recordings(paths: list[Path], cfg: Config, namespace: str | None = None) -> Recording:
    """Open bags, storage files and traces for cfg's topic variables, their names
    resolved with ``namespace`` (``Recording._resolved``; None: the config's
    ``ros.namespace``, as ``replay --namespace`` defaults); type mismatches and a
    recording with none of the config's topics are errors here, before anything is
    read (``Recording.missing`` lists the config topics no recording has)."""
    try:
        sources = [s for p in paths for s in _open_one(Path(p), cfg)]
        return Recording(sources, cfg, cfg.ros.namespace if namespace is None else namespace)
    except UserError as e:
        raise _printable(e) from None


def _printable(e: UserError) -> UserError:
    """The error with whatever a recording put in it (topic names, types, text)
    made safe for a terminal."""
    e.message = printable(e.message)
    e.args = (e.message,)
    return e


__all__ = [
    "RECORD_TOPICS",
    "RECORDS_TOPIC",
    "Batch",
    "Event",
    "NothingToJudge",
    "Recording",
    "open_recordings",
]
