"""``validate``: the one validation of a config that ``check``, ``run`` and reload
share: the project (config -> requirements -> formulas) and the analyses, with the
config's ``analysis:`` and ``limits:`` settings, their findings kept in the
start-up cache (supervisor/cache.py).

The config comes in as read once (:class:`~supervisor.config.ConfigSource`): the
project, the analyses and the cache key all judge the same bytes.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from monitors.ir.spec import Define, expand_defines
from monitors.verify.analysis import Analysis, Finding, Req, VarInfo, activation
from supervisor.analysis_report import fix_text, format_analysis
from supervisor.cache import Cache
from supervisor.config import ConfigSource, load_config
from supervisor.pipeline import Project, build_project
from supervisor.progress import Progress

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


def analyse_project(
    project: Project, k: int | None = None, progress: Progress | None = None
) -> Analysis | None:
    """The analyses with the config's settings (``k`` overrides analysis.k); None
    when the config switches them off.  ``progress`` shows each analysis."""
    settings = project.config.analysis
    if not settings.enabled:
        return None
    from monitors.verify.analysis import analyse  # z3: only when the analyses run

    reqs, roles = project_requirements(project)
    limits = project.config.limits
    return analyse(
        reqs,
        roles,
        k=k or settings.k,
        timeout_s=settings.timeout_s,
        rlimit=settings.rlimit,
        budget_s=limits.analysis_budget_s,
        memory_mb=max(1, round(limits.analysis_memory_mb)),
        progress=None if progress is None else progress.step,
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


def validate(
    config: str | Path | ConfigSource, k: int | None = None, progress: Progress | None = None
) -> Validation:
    """The one validation of a config, for ``check``, ``run`` and reload alike (the
    daemon through :class:`supervisor.analysis_child.Aside`); ``progress`` shows
    each stage (``check`` on a terminal)."""
    progress = progress or Progress(on=False)
    cache = open_cache()
    with progress.stage("parse"):
        cfg = load_config(config)
    with progress.stage("formalize"):
        project = build_project(cfg)
    return validate_project(project, k, cache, progress=progress)


def validate_project(
    project: Project,
    k: int | None = None,
    cache: Cache | None = None,
    key: str | None = None,
    progress: Progress | None = None,
) -> Validation:
    """:func:`validate` of a loaded project: the analyses' findings from the start-up
    cache when it holds them, else the analyses (whose complete results are stored)."""
    if not project.ok:
        return Validation(project, None, "the config has errors")
    if key is None:
        cache, key = startup_key(project, k, cache)
    if not project.config.analysis.enabled:
        return Validation(project, None, "analysis.enabled is false", cache=cache, key=key)
    cached = cached_findings(project, cache, key)
    if cached is not None:
        return cached
    analysis = analyse_project(project, k, progress)
    assert analysis is not None  # enabled, as judged above
    checked = Validation(project, analysis, partial(analysis.findings), cache=cache, key=key)
    if cache is not None and key is not None and checked.skipped is None:
        # Only a complete analysis: one the time budget cut short may finish next time.
        found = [finding_json(f) for f in analysis.findings]
        doc = {"report": format_analysis(analysis), "findings": found}
        cache.put(key, FINDINGS, json.dumps(doc).encode())
    return checked


# ------------------------------------------------------------------ findings as JSON

FINDINGS = "findings.json"


def finding_json(f: Finding) -> dict[str, Any]:
    """A finding without its trace, its fix worded (the start-up cache, the child)."""
    return {
        "kind": f.kind,
        "severity": f.severity,
        "requirements": list(f.requirements),
        "message": f.message,
        "fix": fix_text(f),
    }


def finding_of(doc: dict[str, Any]) -> Finding:
    """The finding of :func:`finding_json`; raises KeyError or TypeError on another shape."""
    return Finding(**{**doc, "requirements": tuple(doc["requirements"])})


def partial(findings: list[Finding]) -> str | None:
    """Why the analyses judged only part of the set (their not-analysed findings)."""
    return "; ".join(f.message for f in findings if f.kind == "not-analysed") or None


# ------------------------------------------------------------------ start-up cache


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
    settings = (cfg.analysis.k, cfg.analysis.rlimit, cfg.analysis.timeout_s, cfg.analysis.enabled)
    h = hashlib.sha256()
    for part in (
        "safety-supervisor start-up cache 1",
        version("safety-supervisor"),
        cfg.sha256,
        *generate(spec),
        build_identity(spec, reset=True, reset_each=True),
        repr(reqs),
        repr(roles),
        repr((settings, k, limits)),
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
        findings = [finding_of(f) for f in doc["findings"]]
        report = str(doc["report"])
    except (ValueError, KeyError, TypeError):
        return None  # ours and intact, yet not what this version writes: analyse again
    errors = [f for f in findings if f.severity == "error"]
    return Validation(project, None, None, errors, cache=cache, key=key, report=report)
