"""A replay run: the config compiled, its recordings opened, the outcome summarised."""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from mitigations.violationlog.writer import ViolationLog
from monitors.backends.load import compile_spec
from supervisor.config import load_config
from supervisor.daemon.session import Session, build_session
from supervisor.pipeline import build_project
from supervisor.tools.replay.engine import Outcome, replay
from supervisor.tools.replay.sources import Progress, open_recordings


@contextmanager
def loaded(config: Path) -> Iterator[Session]:
    """The config's session, its monitor built in a temporary directory. Unlike
    ``run`` it skips the analyses: a replay judges a recording, not the config."""
    project = build_project(load_config(config), ros=False)
    err = project.first_error()
    if err is not None:
        raise err
    build = Path(tempfile.mkdtemp(prefix="safety-supervisor-replay-"))
    try:
        yield build_session(project, compile_spec(project.spec(), build))
    finally:
        shutil.rmtree(build, ignore_errors=True)


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


def run_one(
    config: Path,
    paths: list[Path],
    output: Path | None,
    progress: Progress | None,
    *,
    fast: bool = True,
) -> tuple[Outcome, list[str]]:
    """Replay ``paths`` with ``config``; the outcome and the notes on what was read."""
    with loaded(config) as session:
        cfg = session.config
        recording = open_recordings(expand(paths), cfg)
        notes = recording.summary().splitlines()
        out = None
        if output is not None:
            output.parent.mkdir(parents=True, exist_ok=True)
            out = ViolationLog(
                output,
                cfg.component,
                cfg.sha256,
                echo=False,
                fsync=False,
                durability=cfg.log_durability,
            )
            out.supervisor(
                "replay", config=str(config), recordings=[str(p) for p in paths], dry_run=True
            )
        warnings: list[str] = []
        try:
            outcome = replay(
                session, recording, out, progress=progress, fast=fast, warn=warnings.append
            )
            if out is not None and outcome.error is not None:
                out.supervisor("replay_damaged", detail=str(outcome.error))
        finally:
            if out is not None:
                out.close()
        return outcome, notes + outcome.warnings + _counted(warnings)


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
) -> dict[str, Any]:
    outcome, notes = run_one(config, paths, output, progress, fast=fast)
    return {
        **_totals(outcome),
        "notes": notes,
        "requirements": [
            {
                "id": rid,
                "violations": len(v),
                "first_tick": v[0][0] if v else None,
                "first_s": _since(outcome, v[0][1]) if v else None,
            }
            for rid, v in _by_requirement(outcome).items()
        ],
        "output": str(output) if output else None,
        "error": str(outcome.error) if outcome.error else None,
    }


def compare(
    a: Path, b: Path, paths: list[Path], progress: Progress | None, *, fast: bool = True
) -> dict[str, Any]:
    """Both configs over the same recordings: per requirement id, the violations only
    one reports (matched by the time of their tick) and the first detections."""
    ra, notes_a = run_one(a, paths, None, progress, fast=fast)
    rb, notes_b = run_one(b, paths, None, None, fast=fast)
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
            }
        )
    errors = [str(r.error) for r in (ra, rb) if r.error is not None]
    return {
        **_totals(ra),
        "configs": [str(a), str(b)],
        "notes": notes_a + [n for n in notes_b if n not in notes_a],
        "requirements": rows,
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
