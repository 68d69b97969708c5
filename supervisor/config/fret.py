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

import json
import re
from pathlib import Path
from typing import Any

from monitors.errors import UserError
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
            f"variable '{name}' has FRET data type '{ftype}', which has no monitor type",
            file=file,
            hint="FRET's types are boolean, integer, unsigned integer, single and double",
        )
    return vtype


def load_fret_export(
    path: Path, component: str | None = None, notes: list[str] | None = None
) -> tuple[list[RequirementEntry], list[dict[str, Any]], list[dict[str, Any]]]:
    """Any of FRET's files: its requirements, its internal variables (with a define)
    and its other variables (inputs and outputs, to be read from topics).  With a
    ``component``, only that component's requirements and variables (a project's
    export holds every component's, and two components may give one name different
    kinds).  What is left out is said in ``notes`` (docs/reference/config.md,
    "variables_from and requirements_from"): the other components' requirements and
    FRET's parent requirements (no text)."""
    file = str(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise UserError(f"cannot read FRET file: {e.strerror}", file=file) from None
    except json.JSONDecodeError as e:
        raise UserError(f"invalid JSON: {e.msg}", file=file, line=e.lineno, col=e.colno) from None
    if isinstance(data, list):
        return _database(data, [], file, component, notes)
    if isinstance(data, dict) and isinstance(data.get("requirements"), list):
        variables = data.get("variables") or []
        if not isinstance(variables, list):
            raise UserError("'variables' of a FRET export must be a list", file=file)
        return _database(data["requirements"], variables, file, component, notes)
    if isinstance(data, dict) and len(data) == 1:
        spec = next(iter(data.values()))
        if isinstance(spec, dict) and isinstance(spec.get("Requirements", []), list):
            return _copilot(spec, file)
    raise UserError(f"not a FRET file: expected {SHAPES}", file=file)


def _copilot(
    spec: dict[str, Any], file: str
) -> tuple[list[RequirementEntry], list[dict[str, Any]], list[dict[str, Any]]]:
    reqs: list[RequirementEntry] = []
    for r in spec.get("Requirements", []):
        if not isinstance(r, dict) or not r.get("name") or not r.get("fretish"):
            raise UserError("a requirement in the export has no name or fretish text", file=file)
        reqs.append(
            RequirementEntry(
                id=r["name"],
                text=r["fretish"],
                file=file,
                line=None,
                col=1,
                fret_ptltl=_HTML.sub("", r.get("ptLTL") or "") or None,
                assumption="assumption" in r["name"].lower(),
            )
        )
    internal = [
        {
            "name": v["name"],
            "type": _variable(v["name"], v.get("type", "bool"), file),
            "define": v.get("assignmentCopilot") or v.get("assignmentLustre"),
        }
        for v in spec.get("Internal_variables", [])
    ]
    other = [
        {"name": v["name"], "type": _variable(v["name"], v.get("type", ""), file)}
        for v in spec.get("Other_variables", [])
    ]
    return reqs, internal, other


def requirement_component(r: dict[str, Any]) -> str | None:
    """The component a FRET requirement record names: FRET's own parse
    (``semantics.component_name``), else the word before "shall" in its text."""
    sem = r.get("semantics") if isinstance(r.get("semantics"), dict) else {}
    if sem.get("component_name"):
        return str(sem["component_name"])
    found = _SHALL.search(str(r.get("fulltext") or ""))
    return found.group(1) if found else None


def _database(
    requirements: list[Any],
    variables: list[Any],
    file: str,
    component: str | None,
    notes: list[str] | None = None,
) -> tuple[list[RequirementEntry], list[dict[str, Any]], list[dict[str, Any]]]:
    reqs: list[RequirementEntry] = []
    others: dict[str, int] = {}  # left out: component -> how many
    parents: list[str] = []
    for r in requirements:
        if not isinstance(r, dict) or "reqid" not in r or "fulltext" not in r:
            raise UserError(f"not a FRET file: expected {SHAPES}", file=file)
        owner = requirement_component(r)
        if component is not None and owner is not None and owner != component:
            # A project's export holds every component's requirements; a config
            # monitors one component (docs/reference/config.md).
            others[owner] = others.get(owner, 0) + 1
            continue
        if not str(r["fulltext"]).strip():
            # FRET's parent requirements group others and have no text to monitor.
            parents.append(str(r["reqid"] or "(no id)"))
            continue
        if not r["reqid"]:
            raise UserError(
                f"a requirement in the FRET export has no reqid: '{r['fulltext']}'", file=file
            )
        sem = r.get("semantics") if isinstance(r.get("semantics"), dict) else {}
        reqs.append(
            RequirementEntry(
                id=str(r["reqid"]),
                text=str(r["fulltext"]),
                file=file,
                line=None,
                col=1,
                rationale=str(r.get("rationale") or ""),
                # ptExpanded is the formula the Copilot export calls ptLTL.
                fret_ptltl=_HTML.sub("", str(sem.get("ptExpanded") or "")) or None,
                assumption="assumption" in str(r["reqid"]).lower(),
            )
        )
    if notes is not None:
        if others:
            count = sum(others.values())
            names = ", ".join(f"'{c}' ({n})" for c, n in sorted(others.items()))
            notes.append(
                f"{count} requirement{'s' if count != 1 else ''} of other components "
                f"left out: {names}; this config is for '{component}'"
            )
        for rid in parents:
            notes.append(
                f"requirement '{rid}' has no text (a parent requirement in FRET); left out"
            )
    internal: list[dict[str, Any]] = []
    other: list[dict[str, Any]] = []
    for v in variables:
        # Entries without idType are the imported model's ports (modeldoc), and an
        # empty idType is a variable not yet completed in FRET: neither declares one.
        if not isinstance(v, dict) or not v.get("idType") or not v.get("variable_name"):
            continue
        if component is not None and v.get("component_name", component) != component:
            continue
        name, kind = str(v["variable_name"]), str(v["idType"])
        if kind == "Function":
            continue  # a function name in formulas, not a value
        if kind in ("Internal", "Mode"):
            keys = ("modeRequirement",) if kind == "Mode" else ("copilotAssignment", "assignment")
            define = next((v[k] for k in keys if v.get(k)), None)
            # A Mode's data type is fixed by FRET (boolean) and may be left out.
            vtype = _variable(
                name, v.get("dataType") or ("boolean" if kind == "Mode" else ""), file
            )
            internal.append({"name": name, "type": vtype, "define": define or None})
        else:
            # FRET's Output is what the component sets: the analyses' role: output.
            role = "output" if kind == "Output" else "input"
            other.append(
                {"name": name, "type": _variable(name, v.get("dataType", ""), file), "role": role}
            )
    return reqs, internal, other
