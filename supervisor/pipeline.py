"""Config -> requirements -> formulas -> MonitorSpec (and on to C).

One place that runs the stages in order for ``check``, ``explain``,
``compile`` and ``run``.  Errors are collected per requirement so ``check``
can print one status line each instead of stopping at the first.
"""

from __future__ import annotations

import contextlib
import difflib
import json
import math
import random
from dataclasses import dataclass, field, replace
from pathlib import Path

from mitigations.rosmsg import build_message, message_class
from mitigations.settings import PublishSettings, SshSettings
from monitors.backends.build import build_library, building
from monitors.backends.c99 import write_c
from monitors.backends.copilot import compile_copilot
from monitors.backends.load import load_monitor
from monitors.backends.memory import memory_errors
from monitors.errors import UserError
from monitors.frontend.formalize import Formalization, formalize
from monitors.frontend.parse import Requirement, parse_requirement
from monitors.ir.formula import Const, Formula, FormulaSyntaxError, Past, parse_formula, variables
from monitors.ir.functions import expand_functions, user_calls
from monitors.ir.spec import Define, MonitorSpec, RequirementSpec, VarDecl, c_name, expand_defines
from monitors.ir.typecheck import check_bool, type_of
from monitors.verify.interpret import verdicts
from supervisor.cache import Cache
from supervisor.config import Config, ConfigSource, RequirementEntry, Variable, load_config
from supervisor.config.ros import reset_service_warning
from supervisor.inputs.readers import check_input


@dataclass
class CompiledRequirement:
    entry: RequirementEntry
    parsed: Requirement | None = None
    formalization: Formalization | None = None
    error: UserError | None = None
    warnings: list[str] = field(default_factory=list)
    functions: list[str] = field(default_factory=list)  # the config's functions it calls

    @property
    def id(self) -> str:
        return self.entry.id

    @property
    def formula(self) -> Formula:
        assert self.formalization is not None
        return self.formalization.formula

    @property
    def ok(self) -> bool:
        return self.error is None


@dataclass
class Project:
    config: Config
    requirements: list[CompiledRequirement]
    errors: list[UserError]  # config-level errors found after loading (types, topics, unused names)
    warnings: list[str]

    @property
    def ok(self) -> bool:
        return not self.errors and all(r.ok for r in self.requirements)

    def spec(self) -> MonitorSpec:
        """The monitor for every requirement that compiled."""
        cfg = self.config
        return MonitorSpec(
            component=cfg.component,
            inputs=tuple(VarDecl(v.name, v.type) for v in cfg.inputs),
            defines=tuple(
                Define(v.name, v.type, v.define) for v in cfg.defines if v.define is not None
            ),
            requirements=tuple(RequirementSpec(r.id, r.formula) for r in self.requirements if r.ok),
            prefix=cfg.step.prefix,
            margins=cfg.step.margins is not None,
            bool_margin=math.inf if cfg.step.margins is None else cfg.step.margins,
        )

    @property
    def predicts(self) -> bool:
        """A requirement has ``predict:`` (docs/reference/prediction.md)."""
        return any(r.ok and r.entry.policy_config.predict is not None for r in self.requirements)

    def prediction_spec(self) -> MonitorSpec:
        """The monitor whose margins the predictions fit, stepped beside :meth:`spec`'s
        with the same inputs: requirement i's formula without an unbounded ``H`` at
        its top (while ``H f`` holds it breaks exactly when ``f`` next does, and the
        margin of ``f`` follows the robot both ways where ``H``'s running minimum
        only falls), ``true`` for a requirement that does not predict; margins on,
        whatever ``step.margins`` says."""
        spec = self.spec()
        reqs = [r for r in self.requirements if r.ok]
        return replace(
            spec,
            requirements=tuple(
                RequirementSpec(
                    rs.id,
                    _invariant_body(rs.formula)
                    if r.entry.policy_config.predict is not None
                    else Const(True),
                )
                for rs, r in zip(spec.requirements, reqs, strict=True)
            ),
            prefix=f"{spec.prefix}_predict" if spec.prefix else "predict",
            margins=True,
            # an atom's margin is no distance: infinite, so that it clears the trend
            bool_margin=math.inf,
        )

    def first_error(self) -> UserError | None:
        if self.errors:
            return self.errors[0]
        return next((r.error for r in self.requirements if r.error), None)


def _env(cfg: Config) -> dict[str, str]:
    return {v.name: v.type for v in cfg.variables.values()}


def _located(e: UserError, file: str, line: int | None) -> UserError:
    if e.line is None and line is not None:
        e.line = line
    if e.file in ("<input>", ""):
        e.file = file
    return e


def compile_requirement(
    entry: RequirementEntry, cfg: Config, env: dict[str, str]
) -> CompiledRequirement:
    out = CompiledRequirement(entry)
    try:
        req = parse_requirement(entry.text, file=entry.file, line=entry.line or 1, col=entry.col)
        out.parsed = req
        if req.component != cfg.component:
            raise UserError(
                f"requirement '{entry.id}' names component '{req.component}', but the config is for '{cfg.component}'",
                file=entry.file,
                line=entry.line,
                hint=f"write '{cfg.component} shall ...' or change 'component:'",
            )
        form = formalize(req, period_ms=cfg.step.period_ms, file=entry.file, line=entry.line)
        out.functions = list(dict.fromkeys(c.name for c in user_calls(form.formula)))
        try:  # calls FRET passes through are the config's functions
            form = replace(form, formula=expand_functions(form.formula, cfg.functions))
        except UserError as e:
            e.message = f"requirement '{entry.id}' {e.message}"
            raise _located(e, entry.file, entry.line) from None
        for name in variables(form.formula):
            if name not in env:
                raise UserError(
                    f"requirement '{entry.id}' uses undeclared variable '{name}'",
                    file=entry.file,
                    line=entry.line,
                    hint=_suggest_var(name, env),
                )
        try:
            check_bool(form.formula, env)
        except UserError as e:
            raise _located(e, entry.file, entry.line) from None
        out.formalization = form
        if form.note:
            out.warnings.append(form.note)
        if entry.fret_ptltl:
            out.warnings.extend(_cross_check_fret(entry, form.formula, cfg))
    except UserError as e:
        out.error = _located(e, entry.file, entry.line)
    return out


def _suggest_var(name: str, env: dict[str, str]) -> str | None:
    close = difflib.get_close_matches(name, list(env), n=1)
    return f"did you mean '{close[0]}'?" if close else "declare it under 'variables:'"


def _cross_check_fret(entry: RequirementEntry, ours: Formula, cfg: Config) -> list[str]:
    """FRET's export carries its own ptLTL: report if our formalization differs on
    random traces (it should not; a difference means one of the two is wrong)."""
    try:
        theirs = parse_formula(entry.fret_ptltl or "")
    except FormulaSyntaxError as e:
        return [f"FRET's ptLTL for '{entry.id}' could not be parsed ({e}); using our formalization"]
    try:
        theirs = expand_functions(theirs, cfg.functions)
    except UserError as e:
        return [f"FRET's ptLTL for '{entry.id}' {e.message}; not cross-checked"]
    defines = tuple(Define(v.name, v.type, v.define) for v in cfg.defines if v.define is not None)
    a, b = expand_defines(ours, defines), expand_defines(theirs, defines)
    names = sorted(set(variables(a)) | set(variables(b)))
    if any(n not in cfg.variables for n in names):
        return [f"FRET's ptLTL for '{entry.id}' mentions unknown variables; not cross-checked"]
    rng = random.Random(entry.id)
    for _ in range(200):
        n = rng.randint(1, 20)
        trace = [{n_: _random_value(cfg.variables[n_], rng) for n_ in names} for _ in range(n)]
        if verdicts(a, trace) != verdicts(b, trace):
            return [
                f"our formalization of '{entry.id}' differs from FRET's exported ptLTL on a {n}-tick trace"
            ]
    return []


def _random_value(v: Variable, rng: random.Random) -> bool | int | float:
    if v.type == "bool":
        return rng.random() < 0.5
    lo, hi = v.range or (-2, 12)
    x = rng.uniform(lo - 1, hi + 1)
    return round(x) if v.type == "int64" else x


def check_variables(
    cfg: Config, reqs: list[CompiledRequirement], *, ros: bool = True
) -> tuple[list[UserError], list[str]]:
    """Type-check defines, check message types and fields, find unused variables."""
    errors: list[UserError] = []
    warnings: list[str] = []
    if cfg.step.policy == "synchronized" and not cfg.step.max_skew_ms:
        warnings.append(
            f"{cfg.path}:{cfg.step.line}: step.policy synchronized without max_skew_ms: one "
            "partial round (a lost or late message) shifts every later step by one topic; "
            "set max_skew_ms below the robot's publishing period"
        )
    errors += _define_errors(cfg)
    if ros:
        errors += _input_errors(cfg)
    used = _used_variables(cfg, reqs)
    for v in cfg.inputs:
        if v.topic is None and v.name in used:
            errors.append(
                UserError(
                    f"variable '{v.name}' from {v.imported_from} has no topic",
                    file=cfg.path,
                    line=v.line,
                    hint="give it one in variables: (topic:, msg:) or in an OGMA database "
                    "under variables_from:",
                )
            )
    if all(r.ok for r in reqs):  # unused is only meaningful when every requirement was read
        _drop_unused(cfg, used, errors, warnings)
    return errors, warnings


def _define_errors(cfg: Config) -> list[UserError]:
    """Each define reads declared inputs only and has its variable's type."""
    errors: list[UserError] = []
    env = _env(cfg)
    for v in cfg.defines:
        try:
            assert v.define is not None
            for name in variables(v.define):
                if name not in env:
                    raise UserError(
                        f"define of '{v.name}' uses undeclared variable '{name}'",
                        hint=_suggest_var(name, env),
                    )
                if cfg.variables[name].define is not None:
                    raise UserError(
                        f"define of '{v.name}' uses internal variable '{name}'; write it in terms of inputs"
                    )
            t = type_of(v.define, env)
            if t != v.type and not (v.type == "double" and t == "int64"):
                raise UserError(f"'{v.name}' is declared {v.type} but its define is {t}")
        except UserError as e:
            errors.append(_located(e, cfg.path, v.line))
    return errors


def _input_errors(cfg: Config) -> list[UserError]:
    """Each input's message type and field, checked against the ROS interfaces."""
    errors: list[UserError] = []
    for v in cfg.inputs:
        if v.topic is None:
            continue  # imported from FRET without a topic: judged with the unused below
        try:
            check_input(v)
        except UserError as e:
            e.message = f"variable '{v.name}': {e.message}"
            errors.append(_located(e, cfg.path, v.line))
    return errors


def _used_variables(cfg: Config, reqs: list[CompiledRequirement]) -> set[str]:
    """The variables the monitor reads: in formulas, in the defines those use,
    the inputs of ages and rates, the step trigger and policies' confirmations."""
    used: set[str] = set()
    for r in reqs:
        if r.formalization is not None:
            used.update(variables(r.formalization.formula))
    for v in cfg.defines:
        if v.name in used and v.define is not None:
            used.update(variables(v.define))
    for v in cfg.variables.values():  # an age or a rate reads its input's messages
        if v.name in used and (v.age_of or v.rate_of):
            used.add(v.age_of or v.rate_of or "")
    if cfg.step.trigger:
        used.add(cfg.step.trigger)
    for entry in cfg.requirements:  # a policy's confirmation reads its variable too
        if entry.policy_config.confirm is not None:
            used.add(entry.policy_config.confirm.variable)
    return used


def _drop_unused(cfg: Config, used: set[str], errors: list[UserError], warnings: list[str]) -> None:
    """An unused imported variable is a note and leaves the config; an unused
    declared one is an error."""
    for v in list(cfg.variables.values()):
        if v.name not in used and v.imported_from is not None:
            # A FRET or OGMA file shared by many components declares more than
            # this one reads: a note, and the monitor leaves it out.
            warnings.append(
                f"{cfg.path}:{v.line}: note: variable '{v.name}' from {v.imported_from} "
                "is not used by any requirement; it is left out"
            )
            del cfg.variables[v.name]
        elif v.name not in used:
            errors.append(
                UserError(
                    f"variable '{v.name}' is declared but no requirement uses it",
                    file=cfg.path,
                    line=v.line,
                    hint="remove it, or it may be a typo in a requirement",
                )
            )


def check_mitigations(
    cfg: Config, *, ros: bool = True, dry_run: bool = False
) -> tuple[list[UserError], list[str]]:
    """Publish actions: message type and value (errors).  SSH actions: key and
    known_hosts files (warnings: a robot config is often checked on a laptop
    that does not hold the robot's key); ``dry_run`` (replay, which runs no action):
    not looked at, and paramiko not imported (docs/BENCHMARKS.md, "Fleet")."""
    errors: list[UserError] = []
    warnings: list[str] = []
    for m in cfg.mitigations.values():
        found = len(warnings)
        s = m.settings
        if isinstance(s, PublishSettings):
            if ros:
                try:
                    build_message(message_class(s.msg), s.value, "value")
                except UserError as e:
                    e.message = f"mitigation '{m.name}': {e.message}"
                    errors.append(_located(e, cfg.path, m.line))
            readers = [v.name for v in cfg.inputs if v.topic == s.topic]
            for name in readers:
                trigger = (
                    " (the step trigger: each action adds a tick)"
                    if name == cfg.step.trigger
                    else ""
                )
                warnings.append(
                    f"{cfg.path}:{m.line}: mitigation '{m.name}' publishes on {s.topic}, which is "
                    f"also input '{name}'{trigger}: the supervisor reads its own command as the "
                    "robot's state; prefer a command topic the robot echoes on its own topic"
                )
        if isinstance(s, SshSettings) and not dry_run:
            from mitigations.actions.ssh import preflight  # paramiko: only for ssh mitigations

            for problem in preflight(s):
                warnings.append(f"{cfg.path}:{m.line}: mitigation '{m.name}': {problem}")
        if m.expected:  # the config says why: each of its warnings carries the reason
            warnings[found:] = [f"{w} (expected here: {m.expected})" for w in warnings[found:]]
    return errors, warnings


def check_memory(cfg: Config, reqs: list[CompiledRequirement]) -> list[UserError]:
    """limits.monitor_memory_mb, before any C is written: a requirement over it fails
    at its line; a monitor over it as a whole is a config error (docs/reference/faults.md)."""
    ok = [r for r in reqs if r.ok]
    spec = Project(cfg, ok, [], []).spec()
    where = {r.id: (r.entry.file, r.entry.line) for r in ok}
    try:
        found = memory_errors(
            spec,
            cfg.limits.monitor_memory_bytes,
            where,
            (cfg.path, cfg.limits.line),
            "limits.monitor_memory_mb",
        )
    except UserError:
        return []  # a C-name problem: compile_project reports it where it always has
    for rid, e in found:
        for r in ok:
            if r.id == rid:
                r.error = e
    return [e for rid, e in found if rid is None]


def build_project(cfg: Config, *, ros: bool = True, dry_run: bool = False) -> Project:
    """The config's requirements compiled and checked.  ``dry_run``: for a replay,
    whose actions never run (``check_mitigations``)."""
    env = _env(cfg)
    reqs = [compile_requirement(e, cfg, env) for e in cfg.requirements]
    errors = check_memory(cfg, reqs)
    v_errors, warnings = check_variables(cfg, reqs, ros=ros)
    errors += v_errors
    m_errors, m_warnings = check_mitigations(cfg, ros=ros, dry_run=dry_run)
    reset_warning = reset_service_warning(cfg.ros, cfg.path)
    if reset_warning:
        m_warnings.append(reset_warning)
    # The loader's notes (requirements an import left out) print like the unused
    # imported variables' notes above.
    return Project(cfg, reqs, errors + m_errors, cfg.notes + warnings + m_warnings)


def project_for(source: str | Path | ConfigSource, *, ros: bool = True) -> Project:
    """The project of a config file, or of its bytes as already read (ConfigSource)."""
    return build_project(load_config(source), ros=ros)


def _invariant_body(f: Formula) -> Formula:
    """``f`` of ``H f`` (unbounded, from now): the formula a prediction fits."""
    if isinstance(f, Past) and f.op == "H" and not f.lo and f.hi is None:
        return f.arg
    return f


def monitor_library(
    spec: MonitorSpec, build_dir: Path, cache: Cache | None = None, key: str | None = None
) -> Path:
    """The native library of ``spec``: from the start-up cache under ``key`` when it
    holds it, else built in ``build_dir`` and stored there (supervisor/cache.py).
    Returns the library's path; the caller loads it."""
    if cache is not None and key is not None:
        found = cache.read(key, "monitor.json")
        try:
            name = json.loads(found)["library"] if found is not None else None
        except (ValueError, KeyError, TypeError):
            name = None
        if isinstance(name, str) and name.startswith("_ssmon_"):
            with contextlib.suppress(ValueError):  # a name the cache does not hold
                lib = cache.get(key, name)
                if lib is not None:
                    return lib
    with building(build_dir):
        c_path, _ = write_c(spec, build_dir)
        lib = build_library(spec, [c_path], build_dir, build_dir, reset=True, reset_each=True)
    if cache is not None and key is not None:
        stored = cache.put(key, lib.name, lib.read_bytes())
        # The name last: an entry without it is a miss, never half a library.
        if stored is not None and cache.put(key, "monitor.json", _library_json(lib.name)):
            return stored
    return lib


def _library_json(name: str) -> bytes:
    return json.dumps({"library": name}).encode()


def compile_project(project: Project, out_dir: Path, *, backend: str = "native") -> dict:
    """Write the C sources, build the library, load it once (proves it links), and
    write manifest.json.  Returns the manifest."""
    spec = project.spec()
    if backend not in ("copilot", "native"):
        raise UserError(f"unknown backend '{backend}' (native or copilot)")
    with building(out_dir):
        out_dir.mkdir(parents=True, exist_ok=True)
        if backend == "copilot":
            c_files = compile_copilot(spec, out_dir)
            sources = [f for f in c_files if f.suffix == ".c"]
            lib = build_library(spec, sources, out_dir, out_dir, reset=False, reset_each=False)
        else:
            c_path, h_path = write_c(spec, out_dir)
            lib = build_library(spec, [c_path], out_dir, out_dir, reset=True, reset_each=True)
    load_monitor(lib, spec)  # fail here, at compile time, if it does not load
    cfg = project.config
    manifest = {
        "component": cfg.component,
        "config": cfg.path,
        "config_sha256": cfg.sha256,
        "backend": backend,
        "library": lib.name,
        "step_function": spec.step_name,
        "reset_function": spec.reset_name if backend == "native" else None,
        "inputs": [
            {
                "name": v.name,
                "c_name": c_name(v.name),
                "type": v.type,
                "topic": v.topic,
                "msg": v.msg,
                "field": v.field,
            }
            for v in cfg.inputs
        ],
        "defines": [
            {"name": v.name, "c_name": c_name(v.name), "type": v.type, "define": v.define_text}
            for v in cfg.defines
        ],
        "requirements": [
            {
                "id": r.id,
                "text": r.entry.text,
                "formula": str(r.formula),
                "variables": variables(r.formula),
                "handler": f"handler{r.id}",
                "monotone": r.formalization.monotone if r.formalization else None,
                "on_violation": r.entry.on_violation,
            }
            for r in project.requirements
            if r.ok
        ],
    }
    (out_dir / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest
