"""A monitoring session: the project, its runtime and policies, as one swappable unit.

Built off the receive loop (at start and on reload) and swapped in between two
iterations, so a reload never leaves the loop with half a configuration.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mitigations.policy import RequirementPolicy
from monitors.backends.load import compile_spec
from monitors.ir.formula import to_fret, variables
from monitors.ir.spec import Define, expand_defines
from supervisor.config import Config
from supervisor.daemon.runtime import InputSpec, Runtime
from supervisor.inputs.readers import kind_of, sporadic
from supervisor.pipeline import CompiledRequirement, Project


@dataclass
class Session:
    """What a config reload replaces, built off the loop and swapped in at once."""

    project: Project
    runtime: Runtime
    requirements: list[CompiledRequirement] = field(default_factory=list)
    formulas: list[str] = field(default_factory=list)
    policies: list[RequirementPolicy] = field(default_factory=list)
    cleanup: Callable[[], None] | None = None  # e.g. remove the build directory
    # Each formula over inputs only (internal variables expanded), where it differs:
    # what a violation record's recent inputs can be judged by (monitors/verify/why.py).
    formulas_inputs: list[str | None] = field(default_factory=list)
    # The inputs each requirement reads (defines expanded), worked out once here:
    # the status document names the stale ones every half second.
    reads: list[list[str]] = field(default_factory=list)

    @property
    def config(self) -> Config:
        return self.project.config


def build_runtime(project: Project, monitor: Any) -> Runtime:
    cfg = project.config
    step = cfg.step
    specs = [
        InputSpec(
            v.name,
            v.type,
            initial=v.initial,
            stale_after_ns=int(v.stale_after_ms * 1e6) if v.stale_after_ms else None,
            event=v.event,
            kind=kind_of(v),
            sporadic=sporadic(v),
            window_ns=int(v.window_ms * 1e6),
        )
        for v in cfg.inputs
    ]
    return Runtime(
        inputs=specs,
        monitor=monitor,
        policy=step.policy,
        trigger=step.trigger,
        period_ns=int(step.period_ms * 1e6) if step.period_ms else None,
        max_skew_ns=int(step.max_skew_ms * 1e6) if step.max_skew_ms else None,
        recent_len=cfg.recent,
    )


def build_session(
    project: Project, monitor: Any, cleanup: Callable[[], None] | None = None
) -> Session:
    margin_monitor = None
    if project.predicts:
        # Off the receive loop, as the whole session is: the predictions' own
        # monitor (Project.prediction_spec), built once per start or reload.
        margin_monitor, cleanup = _margin_monitor(project, cleanup)
    cfg = project.config
    reqs = [r for r in project.requirements if r.ok]  # monitor order
    publish = {n for n, m in cfg.mitigations.items() if m.kind == "publish"}
    policies = [
        RequirementPolicy(
            r.entry.policy_config,
            tuple(r.entry.on_violation),
            tuple(a for a in r.entry.on_violation if a in publish),
        )
        for r in reqs
    ]
    defines = tuple(Define(v.name, v.type, v.define) for v in cfg.defines if v.define is not None)
    formulas = [to_fret(r.formula) for r in reqs]
    expanded = [expand_defines(r.formula, defines) for r in reqs]
    over_inputs = [to_fret(f) for f in expanded]
    runtime = build_runtime(project, monitor)
    runtime.margin_monitor = margin_monitor
    return Session(
        project,
        runtime,
        reqs,
        formulas,
        policies,
        cleanup,
        [x if x != f else None for f, x in zip(formulas, over_inputs, strict=True)],
        [variables(f) for f in expanded],
    )


def _margin_monitor(
    project: Project, cleanup: Callable[[], None] | None
) -> tuple[Any, Callable[[], None]]:
    """The margin monitor of ``project``'s predictions, built in a directory of its
    own that the returned cleanup removes (after ``cleanup``)."""
    build = Path(tempfile.mkdtemp(prefix="safety-supervisor-predict-"))
    try:
        monitor = compile_spec(project.prediction_spec(), build)
    except BaseException:
        shutil.rmtree(build, ignore_errors=True)
        raise

    def both() -> None:
        try:
            if cleanup is not None:
                cleanup()
        finally:
            shutil.rmtree(build, ignore_errors=True)

    return monitor, both
