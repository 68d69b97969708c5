"""One ``inject`` run: every trace computed before anything is sent, then one
injection (REQ) published, or (``--all``) every requirement injected in turn
into a running supervisor and what its violation log says compared with what
was expected: a self-test of a deployed system."""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from supervisor.pipeline import Project, project_for
from supervisor.tools.inject.errors import InjectError, Unviolable
from supervisor.tools.inject.injection import Injection
from supervisor.tools.inject.node import RosOut, request_reset
from supervisor.tools.inject.plan import Planner
from supervisor.tools.inject.player import Player, Timing
from supervisor.tools.inject.report import columns, describe, trace_table
from supervisor.tools.inject.target import WARMUP
from supervisor.tools.inject.verdict import log_size, logged, verdict, violations_since

EXIT_OK, EXIT_FAIL = 0, 1

STOPPED = (
    "note: publishing stopped: unless the robot publishes again, the supervisor reports "
    "its inputs stale (and runs on_stale) after stale_after_ms"
)


def _out(line: str = "") -> None:
    print(line, flush=True)


def _load(path: str) -> Project:
    project = project_for(path)
    err = project.first_error()
    if err is not None:
        raise err
    return project


def run_inject(args: argparse.Namespace) -> int:
    """``inject`` once its arguments are checked: compute every trace first, then
    publish one (REQ) or each in turn against the log (--all)."""
    project = _load(args.config)
    cfg = project.config
    planner = Planner(project)
    if args.all:
        ids = _all_order(cfg, planner)
    else:
        cfg.requirement(args.requirement)  # unknown id: one line with the list
        ids = [args.requirement]
    t = time.perf_counter()
    plans: list[Injection] = []  # all computed before anything is sent
    skipped: dict[str, str] = {}
    for rid in ids:
        try:
            plans.append(planner.plan(rid))
        except Unviolable as e:
            if not args.all:
                raise
            skipped[rid] = str(e)
    solve_s = time.perf_counter() - t
    names = planner.inputs
    if args.dry_run:
        for inj in plans:
            for line in describe(inj, planner) + trace_table(inj, names):
                _out(line)
            for n in inj.notes:
                _out(f"note: {n}")
            _out()
        for line in _skipped(cfg, planner, plans, skipped) if args.all else []:
            _out(line)
        _out(f"dry run: nothing published ({len(plans)} trace(s) computed in {solve_s:.2f} s)")
        return EXIT_OK
    if not plans:
        raise InjectError("nothing to inject: " + "; ".join(_skipped(cfg, planner, [], skipped)))
    log = None
    if args.all or args.log:  # REQ with --log: check the log for that one injection too
        if not (args.log or cfg.log_path):
            raise InjectError("--all needs the supervisor's log: give --log FILE")
        log = Path(args.log or cfg.log_path)
        if not log.exists():
            raise InjectError(f"{log}: no such violation log (is it the running supervisor's?)")
    timing = Timing(args.gap_ms / 1000, args.tick_ms / 1000, args.hold_s)
    out = RosOut(cfg, planner.topics)
    try:
        out.wait_for_supervisor(args.wait_s)
        player = Player(out, planner, timing)
        if log is None:
            inj = plans[0]
            ms = player.play(inj, WARMUP)
            player.hold(inj.trace[0], timing.hold_s)
            for line in describe(inj, planner) + trace_table(inj, names, ms):
                _out(line)
            for n in inj.notes:
                _out(f"note: {n}")
            _out(
                f"published: tick 0 x{WARMUP} at 10 Hz (warm-up), ticks 1..{inj.k - 1}, then "
                f"tick 0 for {timing.hold_s:g} s (nominal)"
            )
            _out(STOPPED)
            return EXIT_OK
        return _run_all(plans, skipped, player, log, cfg, planner, timing)
    finally:
        out.close()


def _all_order(cfg: Any, planner: Planner) -> list[str]:
    """Guarantees whose monitor is reset after the violation first, then those that
    stay violated, then assumptions: a requirement left violated is reported once
    and never again, so it cannot disturb the later injections' expectations."""
    entries = [e for e in cfg.requirements if e.id in planner.reqs]

    def rank(e: Any) -> int:
        sticky = e.policy_config.reset == "never" or e.policy_config.latch
        return 2 if e.assumption else (1 if sticky else 0)

    return [e.id for e in sorted(entries, key=rank)]


def _skipped(
    cfg: Any, planner: Planner, plans: Iterable[Injection], why: dict[str, str]
) -> list[str]:
    """A line per requirement ``--all`` did not inject, with the reason."""
    done = {p.req for p in plans}
    out = []
    for e in cfg.requirements:
        if e.id in done:
            continue
        reason = why.get(e.id) or (
            f"{e.id}: z3 cannot encode it ({planner.unsupported[e.id]})"
            if e.id in planner.unsupported
            else f"{e.id} did not formalize (see check)"
        )
        out.append(f"skipped {reason}")
    return out


def _run_all(
    plans: list[Injection],
    skipped: dict[str, str],
    player: Player,
    log: Path,
    cfg: Any,
    planner: Planner,
    timing: Timing,
) -> int:
    """Inject each plan in turn and compare the log with its expectation; one line
    per requirement at the end, exit 1 on any mismatch."""
    names = planner.inputs
    rows: list[tuple[str, str, str, str]] = []
    failures = 0
    sticky = []
    t_all = time.monotonic()
    for i, inj in enumerate(plans):
        entry = cfg.requirement(inj.req)
        if entry.policy_config.reset == "never" or entry.policy_config.latch:
            sticky.append(inj.req)
        offset = log_size(log)
        # later injections start from the nominal state the previous one held
        ms = player.play(inj, WARMUP if i == 0 else 2)
        expected = set(inj.expected)
        # the nominal state: reset policies re-arm; stop early once the log has it all
        wait = max(timing.hold_s, _reset_wait(entry))
        player.hold(inj.trace[0], wait)
        player.hold(
            inj.trace[0], 2.0, lambda e=expected, o=offset: e <= set(violations_since(log, o))
        )
        got = violations_since(log, offset)
        once = planner.schedule.policy in ("on_trigger", "synchronized")
        result = verdict(got, expected, once)
        failures += result != "ok"
        for line in describe(inj, planner) + trace_table(inj, names, ms):
            _out(line)
        for n in inj.notes:
            _out(f"note: {n}")
        _out(f"logged: {logged(got)} -> {result}")
        _out()
        rows.append((inj.req, ", ".join(inj.expected), logged(got), result))
    if sticky:
        _out(
            f"operator reset (left violated by design: {', '.join(sticky)}): {request_reset(player.out)}"
        )
    for line in columns(("requirement", "expected", "logged", "result"), rows):
        _out(line)
    for line in _skipped(cfg, planner, plans, skipped):
        _out(line)
    ok = len(rows) - failures
    _out(
        f"{len(rows)} injected in {time.monotonic() - t_all:.1f} s: {ok} as expected"
        + (f", {failures} MISMATCH" if failures else "")
    )
    _out(STOPPED)
    return EXIT_FAIL if failures else EXIT_OK


def _reset_wait(entry: Any) -> float:
    """How long a reset: after_ms policy needs the nominal state to re-arm."""
    pc = entry.policy_config
    if pc.reset == "after_ms" and pc.reset_after_ms is not None:
        return pc.reset_after_ms / 1000 + 0.2
    return 0.0
