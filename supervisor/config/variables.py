"""The ``variables:`` and ``variables_from:`` sections: inputs (a topic field each) and defines."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from monitors.ir.formula import Formula, FormulaSyntaxError, name_problem, parse_formula
from monitors.ir.spec import TYPE_ALIASES
from monitors.untrusted import printable
from supervisor.config.fields import (
    as_mapping,
    check_keys,
    error_at,
    file_names,
    number,
    relative_to,
    suggest,
    to_number,
    typed_value,
    whole_number,
)
from supervisor.config.fret import load_fret_export
from supervisor.config.imported import Imports
from supervisor.config.model import Variable
from supervisor.config.ogma import load_ogma_variables
from supervisor.config.yamlload import LineDict
from supervisor.inputs.interfaces import (
    ACTION_STATUS_MSG,
    SERVICE_CALLS,
    action_status_topic,
    goal_statuses,
    service_event_type,
    service_topic,
)
from supervisor.inputs.paths import parse_path
from supervisor.inputs.reductions import REDUCTIONS

ROLES = ("input", "output", "internal")
QOS_PRESETS = ("auto", "reliable", "best_effort", "sensor_data")
# Messages an input's subscription queues while the loop is busy elsewhere:
# 1000 per topic hold a 50 ms backlog at 20k msg/s on one topic, far more than
# the loop's 20 ms turn budget (docs/reference/config.md, ``depth``).
DEFAULT_DEPTH = 1000
MAX_DEPTH = 1_000_000  # messages queued per topic; more is a typo, not a plan
VAR_KEYS = {
    "type",
    "topic",
    "msg",
    "field",
    "define",
    "qos",
    "depth",
    "initial",
    "stale_after_ms",
    "role",
    "range",
    "event",
    "reduce",
    "service",
    "srv",
    "call",
    "action",
    "status",
    "age_of",
    "stamp",
    "rate_of",
    "window_ms",
}
# Where an input's value comes from: exactly one of these (or define:).
SOURCES = ("topic", "service", "action", "age_of", "rate_of")
# The keys each source takes besides the common ones.
SOURCE_KEYS = {
    "topic": {"msg", "field", "reduce", "event"},
    "service": {"srv", "call", "field", "reduce", "event"},
    "action": {"status", "event"},
    "age_of": {"stamp"},
    "rate_of": {"window_ms"},
}
MAX_WINDOW_MS = 3_600_000.0  # an hour: longer is a typo, and the arrivals are kept


def check_name(name: str, where: Any, key: str | None = None) -> None:
    # Any name FRET takes quoted is usable (`T`, `left wheel`): sentences write it
    # quoted, formula text in FRET's renaming (docs/reference/config.md, "Names").
    why = name_problem(name)
    if why is not None:
        raise error_at(f"'{printable(name)}' is not a usable variable name", where, key, why)


def parse_define(text: str, file: str, line: int | None) -> Formula:
    # FRET's variable mapper writes constants as 'constant 7' (thesis Fig. 29).
    cleaned = re.sub(r"\bconstant\s+", "", str(text))
    try:
        return parse_formula(cleaned)
    except FormulaSyntaxError as e:
        raise UserError(
            f"cannot parse define '{printable(str(text))}': {printable(str(e))}",
            file=file,
            line=line,
        ) from None


def _imported(doc: LineDict, path: Path, imports: Imports) -> dict[str, Variable]:
    """Variables from FRET's files, then OGMA's databases: a later source refines an
    earlier one, and ``variables:`` refines both (docs/reference/config.md)."""
    out: dict[str, Variable] = {}
    declared = doc.get("variables") if isinstance(doc.get("variables"), dict) else {}
    line = doc.key_line("requirements_from")
    for entry_path in file_names(doc.get("requirements_from"), doc, "requirements_from"):
        fret_file = relative_to(path, entry_path)
        imports.read_named(fret_file, "FRET file", doc, "requirements_from", entry_path)
        component = doc.get("component")
        _reqs, internal, other = load_fret_export(
            fret_file, str(component) if isinstance(component, str) else None, imports=imports
        )
        for v in other + internal:
            check_name(v["name"], doc, "requirements_from")
            var = Variable(
                name=v["name"],
                type=v["type"],
                role=v.get("role", "input"),
                line=line,
                depth=DEFAULT_DEPTH,
                imported_from=str(entry_path),
            )
            # A define the config declares again is the config's: FRET's Lustre
            # assignments need not parse then.
            if v.get("define") and v["name"] not in declared:
                var.role = "internal"
                var.define_text = str(v["define"])
                try:
                    var.define = parse_define(var.define_text, str(fret_file), None)
                except UserError as e:
                    e.message = f"internal variable '{v['name']}': {e.message}"
                    e.hint = "declare it under variables: with a define: in FRETISH's syntax"
                    raise
            out[v["name"]] = var
    for entry_path in file_names(doc.get("variables_from"), doc, "variables_from"):
        ogma_file = relative_to(path, entry_path)
        what = "OGMA variable database"
        imports.read_named(ogma_file, what, doc, "variables_from", entry_path)
        for v in load_ogma_variables(ogma_file, imports):
            check_name(v["name"], doc, "variables_from")
            fret = out.get(v["name"])
            out[v["name"]] = Variable(
                name=v["name"],
                type=v["type"],
                role=fret.role if fret is not None and fret.role != "internal" else "input",
                line=doc.key_line("variables_from"),
                topic=v["topic"],
                msg=v["msg"],
                field=v["field"],
                depth=DEFAULT_DEPTH,
                imported_from=str(entry_path),
            )
    return out


def load_variables(
    doc: LineDict, path: Path, imports: Imports | None = None
) -> dict[str, Variable]:
    out = _imported(doc, path, imports or Imports())
    raw = doc.get("variables")
    if raw is None:
        return out
    vs = as_mapping(raw, doc, "variables", "variables")
    derived_lines: dict[str, int] = {}  # the age_of/rate_of key's line, for errors
    for name, spec in vs.items():
        line = vs.key_line(name)
        check_name(name, vs, name)
        if spec is None:
            spec = LineDict()
        spec = as_mapping(spec, vs, f"variable '{name}'", name)
        check_keys(spec, VAR_KEYS, f"variable '{name}'")
        base = out.get(name)  # a YAML entry may refine one imported from OGMA
        tname = spec.get("type", base.type if base else None)
        if tname is None:
            raise error_at(f"variable '{name}' needs a type (bool, int64 or double)", vs, name)
        vtype = TYPE_ALIASES.get(str(tname))
        if vtype is None:
            raise error_at(
                f"variable '{name}' has unknown type '{tname}'",
                spec,
                "type",
                "use bool, int64 or double",
            )
        define_text = spec.get("define")
        if define_text is None and base is not None and not spec.get("topic"):
            define_text = base.define_text  # refining FRET's internal variable
        imported_role = base.role if base is not None and base.role != "internal" else "input"
        role = str(spec.get("role") or ("internal" if define_text is not None else imported_role))
        if role not in ROLES:
            raise error_at(
                f"variable '{name}': role must be one of {', '.join(ROLES)}", spec, "role"
            )
        var = Variable(name=name, type=vtype, role=role, line=line)
        if define_text is not None:
            if spec.get("topic") or spec.get("msg"):
                raise error_at(
                    f"variable '{name}' has both define and topic: an internal variable is computed, not subscribed",
                    spec,
                    "define",
                )
            var.define_text = str(define_text)
            var.define = parse_define(str(define_text), vs.file, spec.key_line("define"))
        else:
            _source(var, spec, base, vs)
        var.qos = str(spec.get("qos", "auto"))
        if var.qos not in QOS_PRESETS:
            raise error_at(
                f"variable '{name}': unknown qos '{var.qos}'",
                spec,
                "qos",
                "one of: " + ", ".join(QOS_PRESETS),
            )
        depth = spec.get("depth", base.depth if base else DEFAULT_DEPTH)
        var.depth = whole_number(
            spec, "depth", f"variable '{name}'", default=depth, minimum=1, maximum=MAX_DEPTH
        )
        var.stale_after_ms = number(spec, "stale_after_ms", f"variable '{name}'")
        _reduce_and_event(var, spec)
        if "initial" in spec:
            var.initial = typed_value(spec["initial"], vtype, spec, "initial", name)
        if "range" in spec:
            rng = spec["range"]
            if not isinstance(rng, list) or len(rng) != 2:
                raise error_at(f"variable '{name}': range must be [min, max]", spec, "range")
            lo, hi = (to_number(x, spec, "range", f"variable '{name}': range") for x in rng)
            if lo > hi:
                raise error_at(f"variable '{name}': range [{lo:g}, {hi:g}] is empty", spec, "range")
            var.range = (lo, hi)
        for key in ("age_of", "rate_of"):
            if key in spec:
                derived_lines[name] = spec.key_line(key)
        out[name] = var
    _derived_sources(out, vs.file, derived_lines)
    return out


def _source(var: Variable, spec: LineDict, base: Variable | None, vs: LineDict) -> None:
    """Where input ``var`` reads its value: a topic's field, a service's calls, an
    action's goal states, or another input's stamps or arrivals."""
    source = _source_key(var.name, spec, base)
    if source == "topic":
        _topic_source(var, spec, base, vs)
    elif source == "service":
        _service_source(var, spec)
    elif source == "action":
        _action_source(var, spec)
    else:  # age_of, rate_of: resolved against their input in _derived_sources
        _derived_source(var, spec, source)
    if var.field != "data" or "field" in spec:
        _path(var.field, spec, "field", var.name)


def _source_key(name: str, spec: LineDict, base: Variable | None) -> str:
    """The one source key the spec gives (``topic`` when none), refusing a
    second source and keys that belong to another source."""
    given = [k for k in SOURCES if spec.get(k) is not None]
    if len(given) > 1:
        raise error_at(
            f"variable '{name}' has both {given[0]} and {given[1]}: one source each",
            spec,
            given[1],
        )
    source = given[0] if given else "topic"
    allowed = SOURCE_KEYS[source]
    for key in set().union(*SOURCE_KEYS.values()) - allowed:
        if key in spec and not (key in ("msg", "field") and base is not None):
            raise error_at(
                f"variable '{name}': {key} does not go with {source}",
                spec,
                key,
                f"{source} takes: {', '.join(sorted(allowed)) or 'no other key'}",
            )
    return source


def _topic_source(var: Variable, spec: LineDict, base: Variable | None, vs: LineDict) -> None:
    """A topic's field; an entry refining an imported variable (``base``) keeps
    the topic, msg and field it does not give."""
    name = var.name
    var.topic = str(spec.get("topic") or (base.topic if base else "") or "") or None
    var.msg = str(spec.get("msg") or (base.msg if base else "") or "") or None
    var.field = str(spec.get("field") or (base.field if base else "data"))
    if not var.topic:
        raise error_at(
            f"variable '{name}' has no topic (and no define)",
            vs,
            name,
            "add topic: /name and msg: pkg/msg/Type, or define: <expression>",
        )
    _absolute(var.topic, spec, "topic", name)
    if not var.msg:
        raise error_at(
            f"variable '{name}' needs msg: the ROS 2 message type of {var.topic}", vs, name
        )


def _service_source(var: Variable, spec: LineDict) -> None:
    """A service's requests or responses, read from its service-event topic."""
    name = var.name
    var.service = str(spec["service"])
    _absolute(var.service, spec, "service", name)
    if not spec.get("srv"):
        raise error_at(
            f"variable '{name}' needs srv: the service's type (pkg/srv/Name)", spec, "service"
        )
    var.srv = str(spec["srv"])
    call = spec.get("call")
    if call not in SERVICE_CALLS:
        raise error_at(
            f"variable '{name}': call must be request or response",
            spec,
            "call" if "call" in spec else "service",
            "request: the call was made (its fields); response: it came back",
        )
    var.call = str(call)
    try:
        var.msg = service_event_type(var.srv)
    except UserError as e:
        raise error_at(f"variable '{name}': {e.message}", spec, "srv", e.hint) from None
    var.topic = service_topic(var.service)
    if spec.get("field") is not None:
        var.field = str(spec["field"])
    elif not spec.get("event"):
        raise error_at(
            f"variable '{name}' reads no field of the {call}",
            spec,
            "service",
            f"add field: (a field of {var.srv}'s {call}) or event: true",
        )
    elif spec.get("reduce") is not None:
        raise error_at(f"variable '{name}': reduce needs a field:", spec, "reduce")
    if not spec.get("event") and "initial" not in spec:
        raise error_at(
            f"variable '{name}' has no value before the first {call}: give it initial:",
            spec,
            "service",
        )


def _action_source(var: Variable, spec: LineDict) -> None:
    """Whether (bool) or how many (int64) of an action's goals are in given states."""
    name = var.name
    var.action = str(spec["action"])
    _absolute(var.action, spec, "action", name)
    if spec.get("status") is None:
        raise error_at(
            f"variable '{name}' needs status: the goal states it watches",
            spec,
            "action",
            "e.g. status: [accepted, executing], or status: aborted with event: true",
        )
    try:
        var.statuses = goal_statuses(spec["status"])
    except UserError as e:
        raise error_at(f"variable '{name}': {e.message}", spec, "status", e.hint) from None
    if var.type == "double":
        raise error_at(
            f"variable '{name}': goal states feed a bool (some goal is in them) or an "
            "int64 (how many are), not a double",
            spec,
            "type",
        )
    var.topic, var.msg = action_status_topic(var.action), ACTION_STATUS_MSG
    if var.type == "int64" and spec.get("event"):
        raise error_at(f"variable '{name}': an event is bool", spec, "event")
    if "initial" not in spec and not spec.get("event"):
        var.initial = False if var.type == "bool" else 0  # no goal before the first status


def _derived_source(var: Variable, spec: LineDict, source: str) -> None:
    """``age_of`` or ``rate_of`` another input, named here and resolved later."""
    name = var.name
    of = spec[source]
    if not isinstance(of, str):
        raise error_at(f"variable '{name}': {source} names an input variable", spec, source)
    if var.type != "double":
        unit = "milliseconds" if source == "age_of" else "messages per second"
        raise error_at(
            f"variable '{name}': {source} is in {unit}, a double, not {var.type}",
            spec,
            "type",
        )
    if source == "age_of":
        var.age_of = of
        if spec.get("stamp") is not None:
            var.stamp = str(spec["stamp"])
            _path(var.stamp, spec, "stamp", name)
    else:
        var.rate_of = of
        window = number(spec, "window_ms", f"variable '{name}'", maximum=MAX_WINDOW_MS)
        if window is not None:
            var.window_ms = window


def _absolute(value: str, spec: LineDict, key: str, name: str) -> None:
    if not value.startswith("/"):
        raise error_at(
            f"variable '{name}': {key} '{value}' must be absolute (start with '/')", spec, key
        )


def _path(text: str, spec: LineDict, key: str, name: str) -> None:
    try:
        parse_path(text)
    except UserError as e:
        raise error_at(f"variable '{name}': {e.message}", spec, key, e.hint) from None


def _reduce_and_event(var: Variable, spec: LineDict) -> None:
    name, vtype = var.name, var.type
    reduce = spec.get("reduce")
    if reduce is not None:
        if var.define is not None:
            raise error_at(
                f"variable '{name}': reduce reads a topic's array field, not a define",
                spec,
                "reduce",
            )
        if reduce not in REDUCTIONS:
            raise error_at(
                f"variable '{name}': unknown reduce '{reduce}'",
                spec,
                "reduce",
                "one of: " + ", ".join(REDUCTIONS),
            )
        if "field" not in spec and var.field == "data":
            raise error_at(f"variable '{name}': reduce needs the array's field:", spec, "reduce")
        var.reduce = str(reduce)
    event = spec.get("event", False)
    if not isinstance(event, bool):
        raise error_at(f"variable '{name}': event must be true or false", spec, "event")
    if not event:
        return
    if var.define is not None:
        raise error_at(
            f"variable '{name}': an event comes from a topic, not a define", spec, "event"
        )
    if vtype != "bool":
        raise error_at(
            f"variable '{name}': an event is bool (true at the tick its message "
            f"arrived), not {vtype}",
            spec,
            "type",
        )
    for key in ("field", "initial", "reduce"):
        if key in spec:
            raise error_at(
                f"variable '{name}': an event reads no {key} (its message's arrival is the value)",
                spec,
                key,
            )
    var.event = True


def _derived_sources(variables: dict[str, Variable], file: str, lines: dict[str, int]) -> None:
    """An age or rate reads its input's topic: the same subscription."""
    for var in variables.values():
        of = var.age_of or var.rate_of
        if of is None:
            continue
        key = "age_of" if var.age_of else "rate_of"
        src = variables.get(of)
        if src is not None and (src.age_of or src.rate_of):
            raise UserError(
                f"variable '{var.name}': {key} '{of}', which is itself an age or a rate",
                file=file,
                line=lines.get(var.name, var.line),
                hint=f"name the input '{of}' reads",
            )
        if src is None or src.topic is None:
            hint = suggest(of, {n: v for n, v in variables.items() if v.topic})
            raise UserError(
                f"variable '{var.name}': {key} '{of}' is not an input variable with a topic",
                file=file,
                line=lines.get(var.name, var.line),
                hint=hint,
            )
        var.topic, var.msg, var.qos, var.depth = src.topic, src.msg, src.qos, src.depth
