"""FRET's Copilot export (``requirements_from:``): requirements and FRET's own formulas."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from supervisor.config.model import RequirementEntry


def load_fret_export(
    path: Path,
) -> tuple[list[RequirementEntry], list[dict[str, Any]], list[dict[str, Any]]]:
    """FRET's Copilot export (the file OGMA reads): requirements, internal and other variables."""
    file = str(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise UserError(f"cannot read FRET export: {e.strerror}", file=file) from None
    except json.JSONDecodeError as e:
        raise UserError(f"invalid JSON: {e.msg}", file=file, line=e.lineno, col=e.colno) from None
    if (
        not isinstance(data, dict)
        or len(data) != 1
        or not isinstance(next(iter(data.values())), dict)
    ):
        raise UserError(
            'not a FRET Copilot export (expected {"<Component>Spec": {...}})', file=file
        )
    spec = next(iter(data.values()))
    reqs: list[RequirementEntry] = []
    for r in spec.get("Requirements", []):
        if not r.get("name") or not r.get("fretish"):
            raise UserError("a requirement in the export has no name or fretish text", file=file)
        reqs.append(
            RequirementEntry(
                id=r["name"],
                text=r["fretish"],
                file=file,
                line=None,
                col=1,
                fret_ptltl=r.get("ptLTL") or None,
                assumption="assumption" in r["name"].lower(),
            )
        )
    internal = [
        {
            "name": v["name"],
            "type": v.get("type", "bool"),
            "define": v.get("assignmentCopilot") or v.get("assignmentLustre"),
        }
        for v in spec.get("Internal_variables", [])
    ]
    other = [
        {"name": v["name"], "type": v.get("type", "")} for v in spec.get("Other_variables", [])
    ]
    return reqs, internal, other
