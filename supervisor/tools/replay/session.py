"""A replay run: the config compiled, its recordings opened, the outcome summarised."""

from __future__ import annotations

import hashlib
import shutil
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from monitors.backends.load import LoadedMonitor, load_monitor
from monitors.errors import UserError
from monitors.ir.formula import use_parser_cache
from monitors.ir.spec import MonitorSpec
from supervisor.cache import Cache
from supervisor.config import ConfigSource, load_config
from supervisor.daemon.session import Session, build_session
from supervisor.pipeline import build_project, monitor_library
from supervisor.tools.replay.engine import Outcome, replay
from supervisor.tools.replay.sources import NothingToJudge, Progress, open_recordings

if TYPE_CHECKING:
    from mitigations.violationlog.writer import ViolationLog


@dataclass(frozen=True)
class Prepared:
    """A config compiled for replay, its monitor not yet loaded: what ``loaded`` makes
    a session from.  A process that replays many bags with one config (``fleet
    replay``'s workers) keeps it: parsing and compiling the config took most of a
    small bag's replay (docs/BENCHMARKS.md, "Fleet")."""

    project: Any
    spec: MonitorSpec
    cache: Cache | None
    key: str | None
    # monitors of finished sessions, given back by ``loaded``: the next session resets
    # one (an O(1) C call) rather than loading a new copy of the library, a temporary
    # directory, a file copy and a dlopen per bag (docs/BENCHMARKS.md, "Fleet")
    spare: list[LoadedMonitor] = field(default_factory=list, compare=False)


def prepare(config: Path | ConfigSource) -> Prepared:
    """The config loaded and compiled, the monitor's cache key computed; from its
    bytes already read when given them (``ConfigSource``: fleet replay's worker keys
    its compiles by those bytes)."""
    cache = Cache.open_user()
    if cache is not None:
        # the requirement parsers' tables too: most of a cold parse (formula.py)
        use_parser_cache(cache.root)
    # dry_run: a replay's actions never run, their hosts' keys are not its business
    project = build_project(load_config(config), ros=False, dry_run=True)
    err = project.first_error()
    if err is not None:
        raise err
    spec = project.spec()
    return Prepared(project, spec, cache, monitor_key(spec) if cache is not None else None)


@contextmanager
def loaded(config: Path, prepared: Prepared | None = None) -> Iterator[Session]:
    """The config's session, its monitor from the start-up cache (``Cache.open_user``)
    or built in a temporary directory. Unlike ``run`` it skips the analyses: a
    replay judges a recording, not the config.  ``prepared``: the config already
    compiled (``prepare``); each session is new all the same."""
    p = prepared if prepared is not None else prepare(config)
    monitor = p.spare.pop() if p.spare else None
    build: Path | None = None
    try:
        if monitor is None:
            build = Path(tempfile.mkdtemp(prefix="safety-supervisor-replay-"))
            monitor = load_monitor(monitor_library(p.spec, build, p.cache, p.key), p.spec)
        else:
            monitor.reset()  # every requirement at tick 0, as freshly loaded
        session = build_session(p.project, monitor, lambda: None)
        try:
            yield session
        finally:
            assert session.cleanup is not None
            session.cleanup()  # the predictions' monitor, when there is one
            if prepared is not None and monitor.has_reset:
                p.spare.append(monitor)
    finally:
        if build is not None:
            shutil.rmtree(build, ignore_errors=True)


def monitor_key(spec: MonitorSpec) -> str:
    """The cache key of the monitor library alone: its C, the compiler, cffi and
    Python (build_identity) and this package's version. ``run``'s key covers the
    analyses too, which a replay does not make; the items are the same
    (pipeline.monitor_library)."""
    from importlib.metadata import version

    from monitors.backends.build import build_identity
    from monitors.backends.c99 import generate

    h = hashlib.sha256()
    for part in (
        "safety-supervisor replay monitor 1",
        version("safety-supervisor"),
        *generate(spec),
        build_identity(spec, reset=True, reset_each=True),
    ):
        h.update(part.encode() + b"\0")
    return h.hexdigest()


def expand(paths: list[Path]) -> list[Path]:
    """A recording directory of ``run --record`` (bag directories, one per rotation)
    stands for its bags, oldest first; anything else is itself."""
    out: list[Path] = []
    for p in paths:
        bags = (
            sorted(
                b for b in p.iterdir() if (b / "metadata.yaml").exists() or any(b.glob("*.mcap"))
            )
            if p.is_dir() and not _is_bag(p)
            else []
        )
        out.extend(bags or [p])
    return out


def _is_bag(p: Path) -> bool:
    return (p / "metadata.yaml").exists() or any(p.glob("*.mcap")) or any(p.glob("*.db3"))


@dataclass
class Run:
    """One config's replay: its outcome, the notes on what was read, and the config
    topics no recording has (topic -> warning line)."""

    outcome: Outcome
    notes: list[str]
    missing: dict[str, str] = field(default_factory=dict)


def run_one(
    config: Path,
    paths: list[Path],
    output: Path | None,
    progress: Progress | None,
    *,
    fast: bool = True,
    namespace: str | None = None,
    sink: Any = None,
    prepared: Prepared | None = None,
) -> Run:
    """Replay ``paths`` with ``config``, recorded names taken off ``namespace`` (the
    config's ``ros.namespace`` when None).  ``sink``, instead of ``output``: an object
    with the ViolationLog's record methods (``violation``, ``mitigation``, ``reset``,
    ``supervisor``) that takes the records in memory (``fleet replay``'s task);
    ``prepared``: the config compiled once for many bags (``prepare``)."""
    with loaded(config, prepared) as session:
        cfg = session.config
        recording = open_recordings(expand(paths), cfg, namespace)
        said_later = set(recording.missing.values())
        notes = [n for n in recording.summary().splitlines() if n not in said_later]
        out: ViolationLog | None = sink
        said: list[str] = []  # the output log's own reports
        if output is not None and sink is None:
            # structlog and the log writer only when records are written
            from mitigations.violationlog.writer import ViolationLog

            output.parent.mkdir(parents=True, exist_ok=True)
            out = ViolationLog(
                output,
                cfg.component,
                cfg.sha256,
                echo=False,
                fsync=False,
                durability=cfg.log_durability,
                say=said.append,  # judged at close: one line if records were lost
            )
            out.supervisor(
                "replay",
                config=str(config),
                recordings=[str(p) for p in paths],
                dry_run=True,
                **cfg.log_fields(),
            )
        warnings: list[str] = []
        try:
            outcome = replay(
                session, recording, out, progress=progress, fast=fast, warn=warnings.append
            )
            if out is not None and outcome.error is not None:
                out.supervisor("replay_damaged", detail=str(outcome.error))
        finally:
            if out is not None and out is not sink:
                out.close()
                _judge_output(out, said)
        if outcome.error is None and outcome.messages == 0 and recording.by_topic:
            outcome.error = NothingToJudge(
                "the recordings hold no message on the config's topics "
                f"({', '.join(recording.topics)}), so nothing was judged",
                file=", ".join(str(p) for p in paths),
                hint="replay a recording made while those topics were published, "
                "or name in the config the topics the recording has messages on",
            )
        return Run(outcome, notes + outcome.warnings + _counted(warnings), recording.missing)


def _judge_output(out: ViolationLog, said: list[str]) -> None:
    """Records that could not be written fail the replay, in one line: a replay's
    records are its result, and it has no journal to keep them."""
    if out.failed_writes:
        raise UserError(
            f"{out.failed_writes} records could not be written: {out.write_error}",
            file=str(out.path),
            hint="free space there, or give -o another place",
        )
    for text in said:
        print(text, file=sys.stderr)


def _counted(warnings: list[str]) -> list[str]:
    """The daemon's warnings of the replayed run, each text once with its count."""
    counts: dict[str, int] = {}
    for w in warnings:
        counts[w] = counts.get(w, 0) + 1
    return [f"warning: {w}" + (f" ({n} times)" if n > 1 else "") for w, n in counts.items()]


def replay_files(
    config: Path,
    paths: list[Path],
    output: Path | None,
    progress: Progress | None,
    *,
    fast: bool = True,
    namespace: str | None = None,
    require_all_topics: bool = False,
) -> dict[str, Any]:
    """One config's replay as the summary ``replay`` shows (and ``--json`` prints).
    With ``require_all_topics`` a config topic no recording has is the error."""
    run = run_one(config, paths, output, progress, fast=fast, namespace=namespace)
    outcome, notes = run.outcome, run.notes
    error = str(outcome.error) if outcome.error else None
    if error is None and require_all_topics and run.missing:
        error = (
            f"--require-all-topics: {len(run.missing)} config topic(s) in none of the "
            f"recordings: {', '.join(run.missing)}"
        )
    return {
        **_totals(outcome),
        "notes": notes,
        "requirements": [
            {
                "id": rid,
                "violations": len(v),
                "first_tick": v[0][0] if v else None,
                "first_s": _since(outcome, v[0][1]) if v else None,
                **(_predictions(outcome, rid) if outcome.predicting else {}),
            }
            for rid, v in _by_requirement(outcome).items()
        ],
        "predicting": outcome.predicting,
        "output": str(output) if output else None,
        "missing_topics": list(run.missing),
        "missing": list(run.missing.values()),
        "error": error,
    }


def compare(
    a: Path,
    b: Path,
    paths: list[Path],
    progress: Progress | None,
    *,
    fast: bool = True,
    namespace: str | None = None,
) -> dict[str, Any]:
    """Both configs over the same recordings: per requirement id, the violations only
    one reports (matched by the time of their tick) and the first detections."""
    run_a = run_one(a, paths, None, progress, fast=fast, namespace=namespace)
    run_b = run_one(b, paths, None, None, fast=fast, namespace=namespace)
    ra, notes_a, rb, notes_b = run_a.outcome, run_a.notes, run_b.outcome, run_b.notes
    missing = {**run_a.missing, **run_b.missing}
    va, vb = _by_requirement(ra), _by_requirement(rb)
    rows = []
    for rid in dict.fromkeys([*va, *vb]):
        xa, xb = va.get(rid), vb.get(rid)
        ta = {t for _, t in xa or []}
        tb = {t for _, t in xb or []}
        rows.append(
            {
                "id": rid,
                "a": None if xa is None else len(xa),
                "b": None if xb is None else len(xb),
                "only_a": [k for k, t in xa or [] if t not in tb],
                "only_b": [k for k, t in xb or [] if t not in ta],
                "first_a_s": _since(ra, xa[0][1]) if xa else None,
                "first_b_s": _since(rb, xb[0][1]) if xb else None,
                "first_a_tick": xa[0][0] if xa else None,
                "first_b_tick": xb[0][0] if xb else None,
                "first": _first(xa, xb),
                # two predictors on the same recordings (docs/reference/prediction.md)
                **(
                    {"predictions_a": _predictions(ra, rid), "predictions_b": _predictions(rb, rid)}
                    if ra.predicting or rb.predicting
                    else {}
                ),
            }
        )
    errors = [str(r.error) for r in (ra, rb) if r.error is not None]
    return {
        **_totals(ra),
        "configs": [str(a), str(b)],
        "notes": notes_a + [n for n in notes_b if n not in notes_a],
        "missing_topics": list(missing),
        "missing": list(missing.values()),
        "requirements": rows,
        "predicting": ra.predicting or rb.predicting,
        "error": errors[0] if errors else None,
    }


def _first(xa: list[tuple[int, int]] | None, xb: list[tuple[int, int]] | None) -> str:
    if xa is None or xb is None:
        return f"only in {'A' if xb is None else 'B'}'s config"
    if not xa and not xb:
        return "neither detects a violation"
    if not xa or not xb:
        return f"only {'B' if not xa else 'A'} detects a violation"
    (ka, ta), (kb, tb) = xa[0], xb[0]
    if ta == tb:
        return "same tick"
    who, dt, dk = ("B", ta - tb, ka - kb) if tb < ta else ("A", tb - ta, kb - ka)
    return f"{who} {dk} tick{'s' * (dk != 1)} ({dt / 1e9:.3f} s) earlier"


def _by_requirement(outcome: Outcome) -> dict[str, list[tuple[int, int]]]:
    """Every requirement of the config, in config order, with its violations."""
    return {rid: outcome.violations.get(rid, []) for rid in outcome.requirements}


def _predictions(outcome: Outcome, rid: str) -> dict[str, Any]:
    """A requirement's predictions (docs/reference/prediction.md): made, expired, the
    violations that followed one and their least lead time."""
    leads = outcome.leads.get(rid, [])
    return {
        "predictions": len(outcome.predictions.get(rid, [])),
        "expired": outcome.expired.get(rid, 0),
        "predicted": len(leads),
        "min_lead_ms": min(leads) if leads else None,
    }


def _since(outcome: Outcome, t: int) -> float:
    return (t - (outcome.start_ns or 0)) / 1e9


def _totals(outcome: Outcome) -> dict[str, Any]:
    span = (outcome.end_ns or 0) - (outcome.start_ns or 0)
    return {
        "messages": outcome.messages,
        "ticks": outcome.ticks,
        "seconds": round(outcome.seconds, 3),
        "seconds_recorded": span / 1e9,
        "rate": outcome.messages / outcome.seconds if outcome.seconds > 0 else 0.0,
        "markers": outcome.markers,
    }
