"""The analyses for a loaded project, and their plain-text report.

``check`` prints ``format_analysis``; ``explain`` prints ``explain_lines`` per
requirement.  Findings are tables a safety engineer reads without knowing z3:
the requirement ids, a trace tick by tick (one column per variable, then the
reference interpreter's verdict per requirement), and what to change.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from monitors.ir.spec import Define, expand_defines
from monitors.verify.analysis import (
    DEFAULT_TIMEOUT_S,
    Analysis,
    Example,
    Finding,
    Limit,
    Remedy,
    Req,
    Skip,
    VarInfo,
    activation,
)
from monitors.verify.interpret import Value
from supervisor.cache import Cache
from supervisor.config import Config
from supervisor.pipeline import Project, project_for

ANALYSIS_KEYS = {"k", "timeout_s", "enabled"}
MAX_K = 100_000  # ticks; far past what the analyses' memory limit lets run
LABEL = {"error": "ERROR", "warning": "warning", "info": "info"}
BUDGET_KEY = "limits.analysis_budget_s"
# Each limit of the analyses as the user sets it (docs/reference/config.md).
SETTING = {
    Limit.TRACE_LENGTH: "analysis.k",
    Limit.SOLVER_TIMEOUT: "analysis.timeout_s",
    Limit.TIME_BUDGET: BUDGET_KEY,
    Limit.MEMORY: "limits.analysis_memory_mb",
}


# ------------------------------------------------------------------ settings


def _key_line(cfg: Config, key: str | None) -> int | None:
    """The line of ``analysis:`` (or one of its keys) in the config file, for errors:
    Config keeps the section as a plain dict, so the file is read again here."""
    from supervisor.config.yamlload import LineDict, load_yaml

    try:
        doc = load_yaml(cfg.path)
    except UserError:
        return None
    if not isinstance(doc, LineDict):
        return None
    if key is None or not isinstance(doc.get("analysis"), LineDict):
        return doc.key_line("analysis")
    return doc["analysis"].key_line(key)


def analysis_settings(cfg: Config) -> tuple[int | None, float, bool]:
    """(k, timeout_s, enabled) from the config's ``analysis:`` section."""
    sec: dict[str, Any] = cfg.analysis or {}
    for key in sec:
        if key not in ANALYSIS_KEYS:
            raise UserError(
                f"unknown key '{key}' in analysis",
                file=cfg.path,
                line=_key_line(cfg, key),
                hint=f"known keys: {', '.join(sorted(ANALYSIS_KEYS))}",
            )
    k = sec.get("k")
    if k is not None:
        try:
            k = int(str(k))
        except ValueError:
            k = 0
        if not 1 <= k <= MAX_K:
            raise UserError(
                f"analysis.k must be a whole number of ticks from 1 to {MAX_K}",
                file=cfg.path,
                line=_key_line(cfg, "k"),
            )
    timeout = sec.get("timeout_s", DEFAULT_TIMEOUT_S)
    try:
        timeout = float(str(timeout))
    except ValueError:
        timeout = -1.0
    if not timeout > 0 or math.isinf(timeout):
        raise UserError(
            "analysis.timeout_s must be a positive number of seconds",
            file=cfg.path,
            line=_key_line(cfg, "timeout_s"),
        )
    enabled = str(sec.get("enabled", True)).lower() not in ("false", "no", "0", "off")
    return k, timeout, enabled


def k_arg(text: str) -> int:
    """argparse type of ``--k``: a trace length of at least one tick (else usage error)."""
    import argparse

    try:
        k = int(text)
    except ValueError:
        k = 0
    if k < 1:
        raise argparse.ArgumentTypeError(f"--k needs a whole number of ticks >= 1, not '{text}'")
    return k


# ------------------------------------------------------------------ project -> analysis


def project_requirements(project: Project) -> tuple[list[Req], list[VarInfo]]:
    """Every requirement that formalized, over declared variables (defines expanded)."""
    cfg = project.config
    defines = tuple(Define(v.name, v.type, v.define) for v in cfg.defines if v.define is not None)
    reqs = []
    for r in project.requirements:
        if not r.ok or r.formalization is None or r.parsed is None:
            continue
        reqs.append(
            Req(
                r.id,
                expand_defines(r.formula, defines),
                assumption=r.entry.assumption,
                monotone=r.formalization.monotone,
                activation=expand_defines(activation(r.parsed), defines),
                note=r.formalization.note,
                text=r.entry.text,
            )
        )
    roles = [VarInfo(v.name, v.type, v.role, v.range) for v in cfg.inputs]
    return reqs, roles


def analyse_project(project: Project, k: int | None = None) -> Analysis | None:
    """The analyses with the config's settings (``k`` overrides analysis.k); None
    when the config switches them off."""
    cfg_k, timeout, enabled = analysis_settings(project.config)
    if not enabled:
        return None
    from monitors.verify.analysis import analyse  # z3: only when the analyses run

    reqs, roles = project_requirements(project)
    limits = project.config.limits
    return analyse(
        reqs,
        roles,
        k=k or cfg_k,
        timeout_s=timeout,
        budget_s=limits.analysis_budget_s,
        memory_mb=max(1, round(limits.analysis_memory_mb)),
    )


# ------------------------------------------------------------------ validation


@dataclass
class Validation:
    """What ``check`` judges and ``run`` and reload require: the project and its
    analyses.  ``skipped`` says why the analyses did not run (or ran only in part)."""

    project: Project
    analysis: Analysis | None
    skipped: str | None
    # The analyses' errors when they ran in a child process (run, reload) or come
    # from the start-up cache: only the findings, not the solver.
    child_errors: list[Finding] | None = None
    # The start-up cache (supervisor/cache.py) and this project's key in it; the
    # analyses' printed report when it came from the cache.
    cache: Cache | None = None
    key: str | None = None
    report: str | None = None

    @property
    def errors(self) -> list[Finding]:
        if self.analysis is not None:
            return self.analysis.errors
        return self.child_errors or []

    @property
    def ok(self) -> bool:
        return self.project.ok and not self.errors

    def first_error(self) -> UserError | None:
        err = self.project.first_error()
        if err is not None or not self.errors:
            return err
        f = self.errors[0]
        cfg = self.project.config
        lines = [r.id_line or r.line for r in cfg.requirements if r.id in f.requirements]
        ids = ", ".join(f.requirements) or "the whole set"
        return UserError(
            f"analysis: {f.kind} ({ids}): {f.message}",
            file=cfg.path,
            line=min((n for n in lines if n is not None), default=None),
            hint=f"{fix_text(f)}; `safety-supervisor check` prints the trace",
        )


def validate(path: str | Path, k: int | None = None) -> Validation:
    """The one validation of a config, for ``check``, ``run`` and reload alike (the
    daemon through :class:`Aside`)."""
    cache = open_cache()
    return validate_project(project_for(path), k, cache)


def validate_project(
    project: Project,
    k: int | None = None,
    cache: Cache | None = None,
    key: str | None = None,
) -> Validation:
    """:func:`validate` of a loaded project: the analyses' findings from the start-up
    cache when it holds them, else the analyses (whose complete results are stored)."""
    if not project.ok:
        return Validation(project, None, "the config has errors")
    if key is None:
        cache, key = startup_key(project, k, cache)
    if not analysis_settings(project.config)[2]:
        return Validation(project, None, "analysis.enabled is false", cache=cache, key=key)
    cached = cached_findings(project, cache, key)
    if cached is not None:
        return cached
    analysis = analyse_project(project, k)
    assert analysis is not None  # enabled, as judged above
    checked = Validation(project, analysis, _partial(analysis.findings), cache=cache, key=key)
    if cache is not None and key is not None and checked.skipped is None:
        # Only a complete analysis: one the time budget cut short may finish next time.
        found = [_finding_json(f) for f in analysis.findings]
        doc = {"report": format_analysis(analysis), "findings": found}
        cache.put(key, FINDINGS, json.dumps(doc).encode())
    return checked


# ------------------------------------------------------------------ start-up cache

FINDINGS = "findings.json"
_FINDING_KEYS = ("kind", "severity", "requirements", "message", "fix")


def _finding_json(f: Finding) -> dict[str, Any]:
    """A finding without its trace, its fix worded (the start-up cache, the child)."""
    return {**{key: getattr(f, key) for key in _FINDING_KEYS}, "fix": fix_text(f)}


def open_cache() -> Cache | None:
    """The start-up cache (None without one); the parsers keep their tables in it
    too, so open it before the config is read."""
    cache = Cache.open()
    if cache is not None:
        from monitors.ir.formula import use_parser_cache

        use_parser_cache(cache.root)
    return cache


def startup_key(
    project: Project, k: int | None, cache: Cache | None
) -> tuple[Cache | None, str | None]:
    """``cache`` and the project's key in it: the config file's hash, the monitor's
    C, the compiler, cffi and Python (build_identity), everything the analyses
    read, their settings and this package's version.  (None, None) without a
    cache (no ``STATE_DIRECTORY``)."""
    if cache is None:
        return None, None
    from importlib.metadata import version

    from monitors.backends.build import build_identity
    from monitors.backends.c99 import generate

    cfg = project.config
    spec = project.spec()
    reqs, roles = project_requirements(project)
    limits = (cfg.limits.analysis_budget_s, cfg.limits.analysis_memory_mb)
    h = hashlib.sha256()
    for part in (
        "safety-supervisor start-up cache 1",
        version("safety-supervisor"),
        cfg.sha256,
        *generate(spec),
        build_identity(spec, reset=True, reset_each=True),
        repr(reqs),
        repr(roles),
        repr((analysis_settings(cfg), k, limits)),
    ):
        h.update(part.encode() + b"\0")
    return cache, h.hexdigest()


def cached_findings(project: Project, cache: Cache | None, key: str | None) -> Validation | None:
    """The validation from the analyses' cached findings, or None on a miss."""
    if cache is None or key is None:
        return None
    data = cache.read(key, FINDINGS)
    if data is None:
        return None
    try:
        doc = json.loads(data)
        findings = [
            Finding(**{**f, "requirements": tuple(f["requirements"])}) for f in doc["findings"]
        ]
        report = str(doc["report"])
    except (ValueError, KeyError, TypeError):
        return None  # ours and intact, yet not what this version writes: analyse again
    errors = [f for f in findings if f.severity == "error"]
    return Validation(project, None, None, errors, cache=cache, key=key, report=report)


def _partial(findings: list[Finding]) -> str | None:
    return "; ".join(f.message for f in findings if f.kind == "not-analysed") or None


CHILD_GRACE_S = 60.0  # beyond the analyses' budget: start-up, the project, exit
# Unrollings up to this many solver terms are analysed in the daemon itself: a
# fraction of a second and a few MB (sRobot: 222, mobile-base: 672), where a child
# would add its start (about 1.5 s) to every start and reload.
IN_PROCESS_CELLS = 20_000


def _unrolling_cells(project: Project, k: int | None) -> int:
    from monitors.verify.analysis.requirements import default_k
    from monitors.verify.bmc import encoding_cells

    reqs, _ = project_requirements(project)
    k = k or analysis_settings(project.config)[0] or default_k(reqs)
    return encoding_cells([f for r in reqs for f in (r.formula, r.activation)], k)


class Aside:
    """:func:`validate` for the daemon (``run``, reload): the project is judged here,
    the analyses in a child process, of which only the findings come back.  z3
    keeps memory after it is done with it (1.2 GB after the analyses of 10
    generated requirements, malloc_trim included; docs/BENCHMARKS.md, "Scaling"),
    which the daemon must not carry for the rest of its run; and the monitor can be
    compiled while the child works (:meth:`result` waits for it)."""

    def __init__(self, path: str | Path, k: int | None = None) -> None:
        import subprocess
        import sys

        from supervisor.children import child_env, start

        cache = open_cache()
        self.project = project_for(path)
        self._proc: subprocess.Popen[bytes] | None = None
        self._done: Validation | None = None
        self.cache: Cache | None = None
        self.key: str | None = None
        if not self.project.ok:
            self._done = Validation(self.project, None, "the config has errors")
            return
        self.cache, self.key = startup_key(self.project, k, cache)
        if not analysis_settings(self.project.config)[2]:
            self._done = Validation(self.project, None, "analysis.enabled is false")
        elif (hit := cached_findings(self.project, self.cache, self.key)) is not None:
            self._done = hit
        elif _unrolling_cells(self.project, k) <= IN_PROCESS_CELLS:
            # Small: not worth a process start.
            self._done = validate_project(self.project, k, self.cache, self.key)
            if self._done.analysis is not None:
                self._done.analysis.find_examples = None  # nothing asks the solver again
        else:
            argv = [sys.executable, "-m", "supervisor.analysis_report", str(path)]
            argv += [] if k is None else ["--k", str(k)]
            self._proc = start(
                argv, env=child_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE
            )

    def result(self) -> Validation:
        import subprocess

        if self._done is not None:
            return self._done
        assert self._proc is not None
        project, proc = self.project, self._proc
        wait_s = project.config.limits.analysis_budget_s + CHILD_GRACE_S
        try:
            out, err = proc.communicate(timeout=wait_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            self._done = Validation(project, None, f"the analyses did not end within {wait_s:g} s")
            return self._done
        try:
            found = json.loads(out.decode().strip().splitlines()[-1])
            findings = [Finding(**{**f, "requirements": tuple(f["requirements"])}) for f in found]
        except (ValueError, IndexError, KeyError, TypeError):
            last = (err.decode(errors="replace").strip().splitlines() or ["no output"])[-1]
            why = f"the analyses' process failed (exit {proc.returncode}): {last}"
            self._done = Validation(project, None, why)
            return self._done
        errors = [f for f in findings if f.severity == "error"]
        self._done = Validation(project, None, _partial(findings), child_errors=errors)
        return self._done

    def cancel(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.communicate()


def _child_main(argv: list[str]) -> int:
    """``python -m supervisor.analysis_report CONFIG [--k K]``: the analyses of
    CONFIG, their findings (no traces) as one JSON line on stdout."""
    import argparse

    p = argparse.ArgumentParser(prog="python -m supervisor.analysis_report")
    p.add_argument("config")
    p.add_argument("--k", type=int, default=None)
    args = p.parse_args(argv)
    checked = validate(args.config, args.k)
    findings = checked.analysis.findings if checked.analysis is not None else []
    print(json.dumps([_finding_json(f) for f in findings]), flush=True)
    return 0


# ------------------------------------------------------------------ reasons


def remedy_text(r: Remedy) -> str:
    """What to raise, in the user's terms."""
    if r.limit is Limit.TRACE_LENGTH and r.at_least is not None:
        return f"analyse longer traces: --k {r.at_least} or more"
    return f"raise {SETTING[r.limit]}"


def fix_text(f: Finding) -> str:
    """The finding's "what to change": the limit to raise first, then the fix."""
    if f.remedy is None:
        return f.fix
    return f"{remedy_text(f.remedy)}, or {f.fix}" if f.fix else remedy_text(f.remedy)


def _shorter_or_larger(limit: Limit) -> str:
    if limit is Limit.TRACE_LENGTH:
        return "a shorter k (analysis.k, --k)"
    return f"a larger {SETTING[limit]}"


def skip_text(s: Skip) -> str:
    """Why an analysis was skipped, with what would let it run and the setting of
    the limit it reached."""
    out = s.reason
    if s.remedies:
        what = " or ".join(_shorter_or_larger(r) for r in s.remedies)
        only_k = s.remedies == (Limit.TRACE_LENGTH,)
        out += f"; {what} {'analyses shorter traces' if only_k else 'analyses it'}"
    return f"{out} ({SETTING[s.limit]})"


# ------------------------------------------------------------------ text


def _value(v: Value) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v) if not math.isnan(v) else "nan"
    return str(v)


def format_trace(
    trace: list[dict[str, Value]],
    verdicts: dict[str, list[bool]],
    variables: dict[str, VarInfo],
    indent: str = "    ",
) -> list[str]:
    """A trace as a table: tick, one column per variable (its role below the name),
    then one column per requirement with the interpreter's verdict."""
    names = list(trace[0]) if trace else []
    head = ["tick", *names]
    roles = ["", *(variables[n].role if n in variables else "" for n in names)]
    rows = [[str(t), *(_value(row[n]) for n in names)] for t, row in enumerate(trace)]
    reqs = list(verdicts)
    head += reqs
    roles += ["" for _ in reqs]
    for t, row in enumerate(rows):
        row += ["ok" if verdicts[r][t] else "VIOLATED" for r in reqs]
    width = [max(len(x[i]) for x in [head, roles, *rows]) for i in range(len(head))]
    sep = len(names) + 1  # a bar between the values and the verdicts

    def line(cells: list[str]) -> str:
        parts = [
            c.rjust(width[i]) if i <= len(names) else c.ljust(width[i]) for i, c in enumerate(cells)
        ]
        if reqs:
            return (indent + "  ".join(parts[:sep]) + " | " + "  ".join(parts[sep:])).rstrip()
        return (indent + "  ".join(parts)).rstrip()

    out = [line(head)]
    if any(roles):
        out.append(line(roles))
    out.append(line(["-" * w for w in width]))
    out.extend(line(r) for r in rows)
    return out


def format_finding(f: Finding, variables: dict[str, VarInfo]) -> list[str]:
    ids = ", ".join(f.requirements) if f.requirements else "(whole set)"
    out = [f"{LABEL[f.severity]} {f.kind}: {ids}", f"  {f.message}"]
    if f.trace:
        out.append(f"  trace: {f.trace_note}" if f.trace_note else "  trace:")
        out.extend(format_trace(f.trace, f.verdicts, variables))
    out.append(f"  what to change: {fix_text(f)}")
    return out


def _count(n: int, what: str) -> str:
    return f"{n} {what}{'' if n == 1 else 's'}"


def format_analysis(a: Analysis) -> str:
    n_a = sum(1 for r in a.requirements if r.assumption)
    n = len(a.requirements)
    out = [
        f"analysis: {_count(n, 'requirement')} ({_count(n_a, 'assumption')}, "
        f"{_count(n - n_a, 'guarantee')}), "
        f"traces of k = {a.k} ticks, {a.seconds.get('total', 0.0):.2f} s",
        f"  consistency:   {a.consistency}",
        f"  realizability: {a.realizability}",
    ]
    errors, warnings = len(a.errors), len(a.warnings)
    out.append(f"  findings:      {_count(errors, 'error')}, {_count(warnings, 'warning')}")
    out.extend(skipped_lines(a))
    for f in a.findings:
        out.append("")
        out.extend(format_finding(f, a.variables))
    return "\n".join(out)


def skipped_lines(a: Analysis) -> list[str]:
    """One line per reason the time budget skipped or cut analyses short, naming them."""
    by_why: dict[str, list[str]] = {}
    for name, why in a.skipped.items():
        by_why.setdefault(skip_text(why), []).append(name)
    return [f"  skipped:       {', '.join(ns)}: {why}" for why, ns in by_why.items()]


def format_example(ex: Example | None, what: str, variables: dict[str, VarInfo]) -> list[str]:
    if ex is None:
        return [f"  {what}: none within the analysed traces"]
    return [f"  {what}: {ex.note}", *format_trace(ex.trace, ex.verdicts, variables)]


def explain_lines(a: Analysis, rid: str) -> list[str]:
    """What ``explain`` adds per requirement: the analysis results that concern it
    and an example trace satisfying it and one violating it."""
    out = []
    found = a.concerning(rid)
    if found:
        for f in found:
            out.append(f"  analysis:  {LABEL[f.severity]} {f.kind}: {f.message}")
    elif not a.skipped:
        out.append(f"  analysis:  no findings (traces of {a.k} ticks)")
    sat, viol = a.examples(rid)
    if "examples" in a.skipped:
        out.append(f"  analysis:  skipped: {skip_text(a.skipped['examples'])}")
        return out
    out.extend(format_example(sat, "satisfied by", a.variables))
    out.extend(format_example(viol, "violated by", a.variables))
    return out


if __name__ == "__main__":
    import sys

    raise SystemExit(_child_main(sys.argv[1:]))
