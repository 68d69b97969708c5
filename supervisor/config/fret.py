"""FRET's files (``requirements_from:``): requirements, FRET's own formulas and variables.

FRET writes three shapes, told apart by their content (docs/reference/config.md,
"variables_from and requirements_from"):

- the component export for Copilot, ``{"<Component>Spec": {"Requirements": [...],
  "Internal_variables": [...], "Other_variables": [...]}}`` (the file OGMA reads);
- the requirements export, a list of ``{reqid, fulltext, semantics, ...}``;
- the "requirements and variables" export, ``{"requirements": [...], "variables": [...]}``,
  whose variables carry FRET's ``idType`` (Input, Output, Internal, Mode, Function).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from monitors.untrusted import printable
from supervisor.config.imported import (
    Fields,
    Imports,
    c_identifiers,
    named,
    read_json,
    top_list,
)
from supervisor.config.limits import MAX_FORMULA_CHARS, MAX_ID_CHARS, MAX_TEXT_CHARS
from supervisor.config.model import RequirementEntry

SHAPES = (
    'the Copilot component export {"<Component>Spec": {"Requirements": [...]}}, '
    "the requirements export [{reqid, fulltext, semantics}, ...] or "
    'the requirements and variables export {"requirements": [...], "variables": [...]}'
)
_HTML = re.compile(r"</?[bi]>")
# The component a FRETISH sentence names stands right before "shall": the fallback
# for a requirement FRET has not formalized (no semantics.component_name).
_SHALL = re.compile(r"([A-Za-z_][A-Za-z0-9_.]*)\s+shall\b")
# A FRET name before mapping; longer is no name anybody typed.
MAX_NAME_CHARS = 4 * MAX_ID_CHARS
_SHOWN = 10  # mapped ids a note lists by name


def fret_type(name: str) -> str | None:
    """FRET's data types (boolean, integer, unsigned integer, single, double; the
    Copilot export's bool, int, real) as a monitor type."""
    t = str(name).strip().lower()
    if t in ("bool", "boolean"):
        return "bool"
    if "int" in t:
        return "int64"
    if t in ("real", "single", "double", "float"):
        return "double"
    return None


def _variable(name: str, ftype: str, file: str) -> str:
    vtype = fret_type(ftype)
    if vtype is None:
        raise UserError(
            f"variable '{printable(name)}' has FRET data type '{printable(ftype)}', "
            "which has no monitor type",
            file=file,
            hint="FRET's types are boolean, integer, unsigned integer, single and double",
        )
    return vtype


def load_fret_export(
    path: Path,
    component: str | None = None,
    notes: list[str] | None = None,
    taken: set[str] | frozenset[str] = frozenset(),
    imports: Imports | None = None,
) -> tuple[list[RequirementEntry], list[dict[str, Any]], list[dict[str, Any]]]:
    """Any of FRET's files: its requirements, its internal variables (with a define)
    and its other variables (inputs and outputs, to be read from topics).  With a
    ``component``, only that component's requirements and variables (a project's
    export holds every component's, and two components may give one name different
    kinds).  What is left out is said in ``notes`` (docs/reference/config.md,
    "variables_from and requirements_from"): the other components' requirements and
    FRET's parent requirements (no text).  A requirement name that is not a C
    identifier is mapped to one, avoiding ``taken`` (ids of earlier files), the
    name kept in ``display`` and the mapping said in ``notes``.

    The file is read within the import bounds and every field read is type-checked
    here, where it enters (supervisor/config/imported.py)."""
    file = str(path)
    data = read_json(path, "FRET file", imports=imports)
    if isinstance(data, list):
        reqs, internal, other = _database(data, [], file, component, notes)
    elif isinstance(data, dict) and isinstance(data.get("requirements"), list):
        variables = top_list(data, "variables", file)
        reqs, internal, other = _database(data["requirements"], variables, file, component, notes)
    elif isinstance(data, dict) and len(data) == 1 and isinstance(next(iter(data.values())), dict):
        spec = next(iter(data.values()))
        if not isinstance(spec.get("Requirements", []), list):
            raise UserError(f"not a FRET file: expected {SHAPES}", file=file)
        reqs, internal, other = _copilot(Fields(spec, f"'{printable(next(iter(data)))}'", file))
    else:
        raise UserError(f"not a FRET file: expected {SHAPES}", file=file)
    _map_ids(reqs, file, notes, taken)
    return reqs, internal, other


def _map_ids(
    reqs: list[RequirementEntry],
    file: str,
    notes: list[str] | None,
    taken: set[str] | frozenset[str],
) -> None:
    """Give every requirement a C identifier for its id (docs/reference/config.md,
    "requirements"): raw names would otherwise reach C, the logs and terminals."""
    seen: set[str] = set()
    for r in reqs:
        if r.display in seen:
            raise UserError(f"duplicate requirement '{printable(r.display)}'", file=file)
        seen.add(r.display)
    ids = c_identifiers([r.display for r in reqs], taken)
    mapped = [(r.display, ids[r.display]) for r in reqs if ids[r.display] != r.display]
    for r in reqs:
        r.id = ids[r.display]
    if mapped and notes is not None:
        shown = ", ".join(f"'{printable(a)}' -> '{b}'" for a, b in mapped[:_SHOWN])
        more = f" and {len(mapped) - _SHOWN} more" if len(mapped) > _SHOWN else ""
        notes.append(
            f"{len(mapped)} requirement name{'s' if len(mapped) != 1 else ''} "
            f"{'are' if len(mapped) != 1 else 'is'} not C identifiers, so the ids are: "
            f"{shown}{more} (other characters as '_'); refine them by these ids"
        )


def _copilot(
    spec: Fields,
) -> tuple[list[RequirementEntry], list[dict[str, Any]], list[dict[str, Any]]]:
    file = spec.file
    reqs: list[RequirementEntry] = []
    for i, item in enumerate(spec.list("Requirements"), 1):
        r = Fields(item, f"requirement {i}", file)
        name = r.text("name", max_chars=MAX_NAME_CHARS)
        r.where = named(name, i, "requirement")
        text = r.sentence("fretish", max_chars=MAX_TEXT_CHARS)
        if not name or not text or not text.strip():
            raise r.error("has no name or fretish text")
        reqs.append(
            RequirementEntry(
                id=name,
                display=name,
                text=text,
                file=file,
                line=None,
                col=1,
                fret_ptltl=_HTML.sub("", r.sentence("ptLTL", max_chars=MAX_FORMULA_CHARS) or "")
                or None,
                assumption="assumption" in name.lower(),
            )
        )
    internal = []
    for i, item in enumerate(spec.list("Internal_variables"), 1):
        v = _named_variable(item, i, "name", file)
        define = v.text("assignmentCopilot", max_chars=MAX_TEXT_CHARS) or v.text(
            "assignmentLustre", max_chars=MAX_TEXT_CHARS
        )
        name = str(v.obj["name"])
        vtype = _variable(name, v.text("type") or "bool", file)
        internal.append({"name": name, "type": vtype, "define": define or None})
    other = []
    for i, item in enumerate(spec.list("Other_variables"), 1):
        v = _named_variable(item, i, "name", file)
        name = str(v.obj["name"])
        other.append({"name": name, "type": _variable(name, v.text("type") or "", file)})
    return reqs, internal, other


def _named_variable(item: object, index: int, key: str, file: str) -> Fields:
    """A variable's entry, its name text of a bounded length."""
    v = Fields(item, f"variable {index}", file)
    name = v.text(key, max_chars=MAX_NAME_CHARS)
    if not name:
        raise v.error(f"has no '{key}'")
    v.where = named(name, index, "variable")
    return v


def requirement_component(r: dict[str, Any]) -> str | None:
    """The component a FRET requirement record names: FRET's own parse
    (``semantics.component_name``), else the word before "shall" in its text."""
    sem = r.get("semantics") if isinstance(r.get("semantics"), dict) else {}
    if isinstance(sem.get("component_name"), str) and sem["component_name"]:
        return str(sem["component_name"])
    found = _SHALL.search(r["fulltext"] if isinstance(r.get("fulltext"), str) else "")
    return found.group(1) if found else None


def _database(
    requirements: list[Any],
    variables: list[Any],
    file: str,
    component: str | None,
    notes: list[str] | None = None,
) -> tuple[list[RequirementEntry], list[dict[str, Any]], list[dict[str, Any]]]:
    reqs = _database_requirements(requirements, file, component, notes)
    internal, other = _database_variables(variables, file, component)
    return reqs, internal, other


def _database_requirements(
    requirements: list[Any], file: str, component: str | None, notes: list[str] | None
) -> list[RequirementEntry]:
    """The database's requirements of ``component``; the ones left out (other
    components', FRET's parent requirements) are told in ``notes``."""
    reqs: list[RequirementEntry] = []
    others: dict[str, int] = {}  # left out: component -> how many
    parents: list[str] = []
    for i, item in enumerate(requirements, 1):
        if not isinstance(item, dict) or "reqid" not in item or "fulltext" not in item:
            raise UserError(f"not a FRET file: expected {SHAPES}", file=file)
        r = Fields(item, f"requirement {i}", file)
        rid = r.text("reqid", max_chars=MAX_NAME_CHARS)
        r.where = named(rid, i, "requirement")
        text = r.sentence("fulltext", max_chars=MAX_TEXT_CHARS) or ""
        rationale = r.sentence("rationale", max_chars=MAX_TEXT_CHARS) or ""
        sem = r.object("semantics")
        sem.text("component_name", max_chars=MAX_NAME_CHARS)
        ptltl = sem.sentence("ptExpanded", max_chars=MAX_FORMULA_CHARS)
        owner = requirement_component(item)
        if component is not None and owner is not None and owner != component:
            # A project's export holds every component's requirements; a config
            # monitors one component (docs/reference/config.md).
            others[owner] = others.get(owner, 0) + 1
            continue
        if not text.strip():
            # FRET's parent requirements group others and have no text to monitor.
            parents.append(rid or "(no id)")
            continue
        if not rid:
            raise UserError(
                f"a requirement in the FRET export has no reqid: '{printable(text[:200])}'",
                file=file,
            )
        reqs.append(
            RequirementEntry(
                id=rid,
                display=rid,
                text=text,
                file=file,
                line=None,
                col=1,
                rationale=rationale,
                # ptExpanded is the formula the Copilot export calls ptLTL.
                fret_ptltl=_HTML.sub("", ptltl or "") or None,
                assumption="assumption" in rid.lower(),
            )
        )
    if notes is not None:
        if others:
            count = sum(others.values())
            names = ", ".join(f"'{printable(c)}' ({n})" for c, n in sorted(others.items()))
            notes.append(
                f"{count} requirement{'s' if count != 1 else ''} of other components "
                f"left out: {names}; this config is for '{printable(component or '')}'"
            )
        for rid in parents:
            notes.append(
                f"requirement '{printable(rid)}' has no text (a parent requirement in FRET); "
                "left out"
            )
    return reqs


def _database_variables(
    variables: list[Any], file: str, component: str | None
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The database's variables of ``component``: internal ones (with their
    definitions) and the others (inputs and outputs)."""
    internal: list[dict[str, Any]] = []
    other: list[dict[str, Any]] = []
    for i, item in enumerate(variables, 1):
        # Entries without idType are the imported model's ports (modeldoc), and an
        # empty idType is a variable not yet completed in FRET: neither declares one.
        if not isinstance(item, dict) or not item.get("idType") or not item.get("variable_name"):
            continue
        v = _named_variable(item, i, "variable_name", file)
        kind = v.text("idType") or ""
        owner = v.text("component_name", max_chars=MAX_NAME_CHARS)
        if component is not None and owner is not None and owner != component:
            continue
        name = str(item["variable_name"])
        if kind == "Function":
            continue  # a function name in formulas, not a value
        dtype = v.text("dataType") or ""
        if kind in ("Internal", "Mode"):
            keys = ("modeRequirement",) if kind == "Mode" else ("copilotAssignment", "assignment")
            define = next((d for k in keys if (d := v.text(k, max_chars=MAX_TEXT_CHARS))), None)
            # A Mode's data type is fixed by FRET (boolean) and may be left out.
            vtype = _variable(name, dtype or ("boolean" if kind == "Mode" else ""), file)
            internal.append({"name": name, "type": vtype, "define": define or None})
        else:
            # FRET's Output is what the component sets: the analyses' role: output.
            role = "output" if kind == "Output" else "input"
            other.append({"name": name, "type": _variable(name, dtype, file), "role": role})
    return internal, other
