"""The report's facts from the log files: integrity, records in order, runs, the config.

Reading and verification are the log reader's own (mitigations/violationlog/reader.py,
and ``logs --verify``'s rotation links); nothing here re-implements the chain.
"""

from __future__ import annotations

import hashlib
import io
import statistics
from contextlib import redirect_stderr
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from mitigations.violationlog.reader import read_bytes, verify_bytes
from monitors.errors import UserError
from supervisor.tools.logs import load, verify_files
from supervisor.tools.why import is_start, mark_runs


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
    """Every file verified (with the links between rotated files) and read."""
    for p in paths:
        read_bytes(p)  # a missing or unreadable file: one UserError naming it
    out = io.StringIO()
    status = verify_files(paths, out)
    lines = out.getvalue().splitlines()
    first = None
    for p in paths:
        res = verify_bytes(p, read_bytes(p))
        if res.errors:
            first = res.errors[0]
            break
    if status and first is None:  # a gap across a rotation link
        first = next((s for s in lines if "warning" not in s and "chain intact" not in s), None)
    skipped = io.StringIO()
    with redirect_stderr(skipped):  # lines that are not records: shown in the page
        files = load(paths)  # oldest first by rotation links (as `logs` reads them)
    records = [r for f in files for r in f.records]  # in the order written
    if not records:
        raise UserError("not a violation log: no record in it", file=paths[0])
    mark_runs(records)
    _times(records)
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
    """The config named by the last ``start`` (or ``replay``) supervisor record."""
    for r in reversed(data.records):
        if is_start(r) and r.get("config"):
            return str(r["config"])
    return None


def file_sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def resolve_config(
    given: str | None, data: LogData, needed_for: str | None
) -> tuple[Path | None, str]:
    """The config to read the log with, and why there is none.

    ``--config``: it must be one the records were written with (its SHA-256 among
    their ``config_sha256``). Else the ``start`` record's path, if that file is still
    the same config. ``needed_for``: what cannot be done without one (an error)."""
    hashes = data.hashes
    if given is not None:
        p = Path(given)
        try:
            digest = file_sha256(p)
        except OSError as e:
            raise UserError(f"cannot read config: {e.strerror or e}", file=given) from e
        if hashes and digest not in hashes:
            raise UserError(
                f"SHA-256 {digest[:12]}... is not the config the log was written with "
                f"(config_sha256 {', '.join(sorted(h[:12] + '...' for h in hashes))})",
                file=given,
            )
        return p, ""
    named = config_path(data)
    why, where = "the log names no config file", data.paths[0]
    if named is not None:
        p = Path(named)
        where = named
        try:
            digest = file_sha256(p)
        except OSError as e:
            why = f"the config the log names cannot be read ({e.strerror or e})"
        else:
            if not hashes or digest in hashes:
                return p, ""
            why = "the config the log names has changed since (its SHA-256 differs)"
    if needed_for is not None:
        raise UserError(f"{needed_for} needs the config: {why}; give --config CONFIG", file=where)
    return None, f"{why} ({where})" if named else why


def median(values: list[float]) -> float:
    return statistics.median(values)
