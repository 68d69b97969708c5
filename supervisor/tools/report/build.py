"""Gathering a report: the logs, the config, the inputs, the windows, the why-trees."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from supervisor.config.model import Config
from supervisor.tools.report.data import (
    LogData,
    changed_imports,
    load_logs,
    median,
    resolve_config,
)
from supervisor.tools.report.inputs import (
    SHOWN_PER_REQUIREMENT,
    Series,
    bag_paths,
    series_from_bag,
    series_from_log,
    windows_from_bag,
)
from supervisor.tools.report.margins import margin_series
from supervisor.tools.why import Why, Window, why_of, windows_from_log


@dataclass
class Requirement:
    id: str
    text: str = ""
    formula: str = ""
    reading: str | None = None
    rationale: str | None = None
    violations: list[int] = field(default_factory=list)  # indices into the records
    # action -> {"kind", "ok", "failed", "dry_run"}
    actions: dict[str, dict[str, Any]] = field(default_factory=dict)
    latencies: list[float] = field(default_factory=list)  # ms, actions actually run
    predictions: int = 0  # its `prediction` records
    expired: int = 0  # its `prediction_expired` records
    leads: list[float] = field(default_factory=list)  # ms, its violations' predicted_ms

    @property
    def latency(self) -> tuple[float, float] | None:
        """(p50, max) from detection to the end of each attempt."""
        if not self.latencies:
            return None
        return median(self.latencies), max(self.latencies)


@dataclass
class Report:
    data: LogData
    config: Path | None
    no_config: str  # why there is none
    cfg: Config | None
    bags: list[str]
    series: dict[str, Series]
    series_source: str
    requirements: list[Requirement]
    whys: dict[int, Why]
    notes: list[str]
    # each violated requirement's margin over its why-trees' windows (margins.py)
    margins: dict[str, Series] = field(default_factory=dict)


def build(
    logs: list[str],
    bags: list[str],
    config: str | None,
    quiet: bool = False,
    namespace: str | None = None,
) -> Report:
    """``namespace``: the robot's namespace in ``bags`` (None: the config's
    ``ros.namespace``), as replay's ``--namespace``."""
    data = load_logs(logs)
    cfg_path, no_config = resolve_config(config, data, "--bag" if bags else None, bags)
    project = None
    if cfg_path is not None:
        from supervisor.config import load_config
        from supervisor.pipeline import build_project

        loaded: Config | None
        try:
            loaded = load_config(cfg_path)
        except UserError as e:
            if config is not None or bags:
                raise
            # found beside the log, the log's bytes: what fails now is what it imports
            # (gone, or edited), so it is not the log's config, as an edited import
            loaded, cfg_path, no_config = None, None, str(e)
        changed = None
        if loaded is not None:
            changed = changed_imports(data, loaded.sha256, loaded.import_digests)
        if changed is not None and (config is not None or bags):
            raise UserError(f"{changed}; give the files as they were", file=str(cfg_path))
        if changed is not None:  # found beside the log: the report goes on without it
            cfg_path, no_config = None, f"{cfg_path}: {changed}"
        elif loaded is not None:
            project = build_project(loaded, ros=False)
    cfg = project.config if project is not None else None
    notes: list[str] = []
    reqs = _requirements(data, project)
    shown = {
        i: (r.id, data.records[i]["tick"])
        for r in reqs
        for i in r.violations[:SHOWN_PER_REQUIREMENT]
    }
    windows: dict[int, Window] = windows_from_log(data.records)
    if bags:
        assert cfg is not None and cfg_path is not None
        paths = bag_paths(bags)
        series, more = series_from_bag(paths, cfg, quiet, namespace)
        notes += more
        replayed, more = windows_from_bag(cfg_path, paths, data, shown, quiet, namespace)
        windows.update(replayed)
        notes += more
        source = "the recording (" + ", ".join(bags) + "), every message at its receive time"
    else:
        series = series_from_log(data, cfg)
        source = (
            "the violation records' recent ticks only (give --bag for the whole run); "
            "tick times are estimated from the records' ticks and times"
        )
    whys = {i: why_of(data.records[i], windows.get(i)) for i in shown}
    margins, more = margin_series(data, {i: windows[i] for i in shown if i in windows}, cfg)
    notes += more
    return Report(data, cfg_path, no_config, cfg, bags, series, source, reqs, whys, notes, margins)


def _requirements(data: LogData, project: Any) -> list[Requirement]:
    """Every requirement of the config (in its order), then any other the records
    name (a reload's, or on_stale actions)."""
    out: dict[str, Requirement] = {}
    if project is not None:
        from monitors.frontend.formalize import describe
        from monitors.ir.formula import to_fret

        period = project.config.step.period_ms
        for r in project.requirements:
            q = out[r.id] = Requirement(r.id, r.entry.text, rationale=r.entry.rationale or "")
            if r.parsed is not None and r.formalization is not None:
                q.formula = to_fret(r.formula)
                q.reading = describe(r.parsed, period)
    for i, rec in enumerate(data.records):
        rid = rec.get("requirement")
        if rid is None or rid == "*":
            continue
        q = out.setdefault(str(rid), Requirement(str(rid)))
        ev = rec.get("event")
        if ev == "violation":
            q.violations.append(i)
            q.text = q.text or str(rec.get("text") or "")
            q.formula = q.formula or str(rec.get("formula") or "")
            lead = rec.get("predicted_ms")
            if isinstance(lead, int | float) and not isinstance(lead, bool):
                q.leads.append(float(lead))
        elif ev == "prediction":
            q.predictions += 1
        elif ev == "prediction_expired":
            q.expired += 1
        elif ev == "mitigation":
            name = str(rec.get("action"))
            a = q.actions.setdefault(
                name, {"kind": rec.get("kind"), "ok": 0, "failed": 0, "dry_run": 0}
            )
            a["ok" if rec.get("ok") else "failed"] += 1
            if rec.get("dry_run"):
                a["dry_run"] += 1
            lat = rec.get("latency_ms")
            # a confirmation's latency counts from the incident, not the detection
            if (
                rec.get("kind") != "confirm"
                and not rec.get("dry_run")
                and isinstance(lat, int | float)
            ):
                q.latencies.append(float(lat))
    return list(out.values())
