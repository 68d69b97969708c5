"""The ``variables:`` and ``variables_from:`` sections: inputs (a topic field each) and defines."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from mitigations.rosmsg import REDUCTIONS
from monitors.errors import UserError
from monitors.ir.formula import Formula, FormulaSyntaxError, name_problem, parse_formula
from monitors.ir.spec import TYPE_ALIASES
from supervisor.config.fields import (
    as_mapping,
    check_keys,
    error_at,
    file_names,
    number,
    relative_to,
    to_number,
    typed_value,
    whole_number,
)
from supervisor.config.fret import load_fret_export
from supervisor.config.model import Variable
from supervisor.config.ogma import load_ogma_variables
from supervisor.config.yamlload import LineDict

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
}


def check_name(name: str, where: Any, key: str | None = None) -> None:
    # Any name FRET takes quoted is usable (`T`, `left wheel`): sentences write it
    # quoted, formula text in FRET's renaming (docs/reference/config.md, "Names").
    why = name_problem(name)
    if why is not None:
        raise error_at(f"'{name}' is not a usable variable name", where, key, why)


def parse_define(text: str, file: str, line: int | None) -> Formula:
    # FRET's variable mapper writes constants as 'constant 7' (thesis Fig. 29).
    cleaned = re.sub(r"\bconstant\s+", "", str(text))
    try:
        return parse_formula(cleaned)
    except FormulaSyntaxError as e:
        raise UserError(f"cannot parse define '{text}': {e}", file=file, line=line) from None


def _imported(doc: LineDict, path: Path) -> dict[str, Variable]:
    """Variables from FRET's files, then OGMA's databases: a later source refines an
    earlier one, and ``variables:`` refines both (docs/reference/config.md)."""
    out: dict[str, Variable] = {}
    declared = doc.get("variables") if isinstance(doc.get("variables"), dict) else {}
    line = doc.key_line("requirements_from")
    for entry_path in file_names(doc.get("requirements_from"), doc, "requirements_from"):
        fret_file = relative_to(path, entry_path)
        component = doc.get("component")
        _reqs, internal, other = load_fret_export(
            fret_file, str(component) if isinstance(component, str) else None
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
        for v in load_ogma_variables(relative_to(path, entry_path)):
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


def load_variables(doc: LineDict, path: Path) -> dict[str, Variable]:
    out = _imported(doc, path)
    raw = doc.get("variables")
    if raw is None:
        return out
    vs = as_mapping(raw, doc, "variables", "variables")
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
            if not var.topic.startswith("/"):
                raise error_at(
                    f"variable '{name}': topic '{var.topic}' must be absolute (start with '/')",
                    spec,
                    "topic",
                )
            if not var.msg:
                raise error_at(
                    f"variable '{name}' needs msg: the ROS 2 message type of {var.topic}", vs, name
                )
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
            if "field" not in spec and not (base and base.field != "data"):
                raise error_at(
                    f"variable '{name}': reduce needs the array's field:", spec, "reduce"
                )
            var.reduce = str(reduce)
        event = spec.get("event", False)
        if not isinstance(event, bool):
            raise error_at(f"variable '{name}': event must be true or false", spec, "event")
        if event:
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
            for key in ("field", "initial"):
                if key in spec:
                    raise error_at(
                        f"variable '{name}': an event reads no {key} (its message's arrival "
                        "is the value)",
                        spec,
                        key,
                    )
            var.event = True
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
        out[name] = var
    return out
