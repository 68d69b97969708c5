"""The report's facts from the log files: integrity, records in order, runs, the config.

Reading and verification are the log reader's own (mitigations/violationlog/reader.py,
and ``logs --verify``'s rotation links); nothing here re-implements the chain.
"""

from __future__ import annotations

import hashlib
import io
import os
import stat
import statistics
import sys
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from monitors.untrusted import Untrusted, printable, read_regular
from supervisor.tools.logs import load, verify_paths
from supervisor.tools.why import is_start, mark_runs

MAX_CONFIG = 4 * 1024 * 1024  # bytes of a config file looked at (ours are < 100 kB)
MAX_CANDIDATES = 200  # files beside a log or in a recording hashed to find the config


@dataclass
class Integrity:
    ok: bool
    first_problem: str | None  # the first error line of the verification, if any
    lines: list[str]  # what ``logs --verify`` prints
    skipped: list[str] = field(default_factory=list)  # lines that are not records


@dataclass
class LogData:
    paths: list[str]
    integrity: Integrity
    # In time order; each with "_t" (ns since the epoch: recorded_ts for a replay's
    # records, else ts) and "_run" (a new run starts with the daemon or a replay).
    records: list[dict[str, Any]]

    @property
    def hashes(self) -> set[str]:
        return {str(r["config_sha256"]) for r in self.records if r.get("config_sha256")}

    @property
    def dry_run(self) -> bool:
        return any(r.get("dry_run") for r in self.records if r.get("event") == "mitigation")


def to_ns(text: str) -> int:
    """ISO 8601 UTC with up to nanoseconds (``recorded_ts`` has nine digits, more
    than datetime keeps) to integer nanoseconds since the epoch."""
    base, _, frac = text.rstrip("Z").partition(".")
    zone = ""
    for sign in ("+", "-"):
        if sign in frac:
            frac, _, rest = frac.partition(sign)
            zone = sign + rest
    dt = datetime.fromisoformat(base + (zone or "+00:00"))
    digits = "".join(c for c in frac if c.isdigit())[:9].ljust(9, "0")
    return int(dt.timestamp()) * 1_000_000_000 + int(digits)


def load_logs(paths: list[str]) -> LogData:
    """Every file verified (with the links between rotated files) and read; the lines
    that are not records (and damage) are printed on stderr and kept for the page."""
    status, lines, results = verify_paths(paths)
    lines = [printable(s) for s in lines]
    first = next((r.errors[0] for r in results if r.errors), None)
    if status and first is None:  # a gap across a rotation link
        first = next((s for s in lines if "warning" not in s and "chain intact" not in s), None)
    skipped = io.StringIO()
    files = load(paths, skipped)  # oldest first by rotation links (as `logs` reads them)
    records = [r for f in files for r in f.records]  # in the order written
    if not records:
        raise UserError("not a violation log: no record in it", file=paths[0])
    sys.stderr.write(skipped.getvalue())
    mark_runs(records)
    _times(records)
    first = printable(first) if first is not None else None
    integrity = Integrity(status == 0, first, lines, skipped.getvalue().splitlines())
    return LogData(paths, integrity, records)


def _times(records: list[dict[str, Any]]) -> None:
    """``_t``: when a record happened. A replay's records carry ``recorded_ts`` (their
    ``ts`` is when replay wrote them); its own records without one (``replay`` at the
    start, ``replay_damaged`` at the end) take the recorded time next to them."""
    replayed = {r["_run"] for r in records if r.get("recorded_ts")}
    for r in records:
        try:
            r["_t"] = to_ns(str(r.get("recorded_ts") or r["ts"]))
        except ValueError:
            r["_t"] = int(r["_ts"].timestamp() * 1e9)
    for order in (list(reversed(records)), records):  # the record after, else before
        near: dict[int, int] = {}
        for r in order:
            if r["_run"] not in replayed:
                continue
            if r.get("recorded_ts") or r.get("_placed"):
                near[r["_run"]] = r["_t"]
            elif r["_run"] in near:
                r["_t"], r["_placed"] = near[r["_run"]], True
    for r in records:
        r.pop("_placed", None)


def config_path(data: LogData) -> str | None:
    """The config named by the last ``start`` (or ``replay``) supervisor record: only
    ever shown (escaped), never opened (docs/reference/faults.md, "Trust")."""
    for r in reversed(data.records):
        if is_start(r) and r.get("config"):
            return str(r["config"])
    return None


def config_hash(data: LogData) -> str | None:
    """The config_sha256 of the last start (or replay), else of the last record."""
    for r in reversed(data.records):
        if is_start(r) and r.get("config_sha256"):
            return str(r["config_sha256"])
    return next(
        (str(r["config_sha256"]) for r in reversed(data.records) if r.get("config_sha256")), None
    )


def changed_imports(data: LogData, sha256: str, digests: dict[str, str]) -> str | None:
    """How the imports of a config whose file is the log's (``sha256``) differ from
    those its start, reload or replay records name, if they do: an edited FRET export
    under an unchanged config judges with other requirements.  Files that any of
    them names are the log's, as a config file among the records' hashes is: an
    import edited and reloaded (or replayed again) between runs leaves records of
    both versions.  A log that names no imports (an older writer's) is not checked."""
    named = [
        r["imports"]
        for r in data.records
        if r.get("event") == "supervisor"
        and r.get("config_sha256") == sha256
        and isinstance(r.get("imports"), dict)
    ]
    if not named or digests in named:
        return None
    logged = named[-1]  # the differences from the latest
    name = next(n for n in sorted(set(logged) | set(digests)) if logged.get(n) != digests.get(n))
    was, now = logged.get(name), digests.get(name)
    return (
        f"its import {printable(name)} is not the one the log was written with "
        f"(SHA-256 {printable(str(was or 'none')[:12])}... then, "
        f"{(now or 'none')[:12]}... now)"
    )


def _candidates(data: LogData, bags: list[str]) -> list[Path]:
    """Regular files (not links) named ``*.yaml``/``*.yml`` beside the logs and in
    the recordings, as an incident's files are kept together."""
    dirs: list[Path] = []
    for name in [*data.paths, *bags]:
        p = Path(name)
        for d in (p, p.parent) if p.is_dir() else (p.parent,):
            if d not in dirs:
                dirs.append(d)
    out: list[Path] = []
    for d in dirs:
        try:
            names = sorted(os.listdir(d or "."))
        except OSError:
            continue
        for n in names:
            f = d / n
            try:
                regular = stat.S_ISREG(os.lstat(f).st_mode)
            except OSError:
                continue
            if regular and f.suffix in (".yaml", ".yml") and f not in out:
                out.append(f)
    return out[:MAX_CANDIDATES]


def _sha256(path: Path) -> str | None:
    """The file's SHA-256, if it is a regular file of at most MAX_CONFIG bytes."""
    try:
        return hashlib.sha256(read_regular(path, max_bytes=MAX_CONFIG)).hexdigest()
    except Untrusted:
        return None


def resolve_config(
    given: str | None, data: LogData, needed_for: str | None, bags: list[str] | None = None
) -> tuple[Path | None, str]:
    """The config to read the log with, and why there is none.

    ``--config``: it must be one the records were written with (its SHA-256 among
    their ``config_sha256``).  Else a file beside the logs or in the recordings whose
    SHA-256 is the log's.  The path a ``start`` record names is never opened: the log
    is anybody's to write (docs/reference/faults.md, "Trust"), and a file whose hash
    does not match is never parsed, so none of its lines is ever shown.
    ``needed_for``: what cannot be done without one (an error)."""
    hashes = data.hashes
    if given is not None:
        p = Path(given)
        try:
            digest = hashlib.sha256(read_regular(p, max_bytes=MAX_CONFIG)).hexdigest()
        except Untrusted as e:
            raise UserError(f"cannot read config: {e}", file=given) from None
        if hashes and digest not in hashes:
            shown = ", ".join(sorted(printable(h[:12]) + "..." for h in hashes))
            raise UserError(
                f"SHA-256 {digest[:12]}... is not the config the log was written with "
                f"(config_sha256 {shown})",
                file=given,
            )
        return p, ""
    want = config_hash(data)
    found = None
    if hashes:
        by_hash: dict[str, Path] = {}
        for f in _candidates(data, bags or []):
            digest = _sha256(f)
            if digest in hashes:
                by_hash.setdefault(digest, f)
        found = by_hash.get(want or "") or next(iter(by_hash.values()), None)
    if found is not None:
        return found, ""
    named = config_path(data)
    where = ", ".join(sorted({str(Path(p).parent) for p in data.paths}))
    why = (
        f"no *.yaml beside the log ({where}) or in the recording has its config_sha256"
        if hashes
        else "the log has no config_sha256"
    )
    if named is not None:
        why += f" (it was written with {printable(named)})"
    if needed_for is not None:
        raise UserError(
            f"{needed_for} needs the config: {why}; give --config CONFIG", file=data.paths[0]
        )
    return None, why


def median(values: list[float]) -> float:
    return statistics.median(values)
