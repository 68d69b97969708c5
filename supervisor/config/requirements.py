"""The ``requirements:``, ``requirements_from:`` and ``requirement_defaults:`` sections.

Requirement texts are only collected here; the pipeline parses and formalizes
them.  Each requirement's ``policy:`` is checked by :mod:`mitigations.settings`,
given the config's mitigations and variables; this module points its errors at
their lines.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from mitigations.settings import (
    POLICY_KEYS,
    PREDICT_KEYS,
    Mitigation,
    PolicyConfig,
    SettingsError,
    parse_policy,
    parse_predict,
)
from monitors.errors import UserError
from monitors.untrusted import printable
from supervisor.config.fields import (
    as_linedict,
    as_mapping,
    check_keys,
    error_at,
    file_names,
    mitigation_names,
    relative_to,
    suggest,
)
from supervisor.config.fret import load_fret_export
from supervisor.config.imported import Imports, control_at, is_c_identifier
from supervisor.config.limits import MAX_ID_CHARS, MAX_TEXT_CHARS
from supervisor.config.model import RequirementEntry, Variable
from supervisor.config.yamlload import LineDict, LineList

REQ_KEYS = {
    "id",
    "text",
    "rationale",
    "on_violation",
    "policy",
    "predict",
    "assumption",
    "on_pending",
}
DEFAULTS_KEYS = {"on_violation", "policy", "on_pending"}


def load_requirements(
    doc: LineDict, path: Path, notes: list[str] | None = None, imports: Imports | None = None
) -> list[RequirementEntry]:
    """The config's requirements, imported ones first.  What an import leaves out
    (other components' requirements, FRET's parent requirements) is appended to
    ``notes`` for ``check`` to print (docs/reference/config.md)."""
    defaults = _defaults(doc)
    reqs: list[RequirementEntry] = []
    by_id: dict[str, RequirementEntry] = {}
    left_out = _import_requirements(doc, path, defaults, reqs, by_id, imports or Imports())
    if notes is not None:
        notes.extend(left_out)
    raw = doc.get("requirements")
    if raw is None:
        if not reqs:
            raise error_at(
                "no requirements: add 'requirements:' or 'requirements_from:'",
                doc,
                "requirements_from" if left_out else None,
                # An import for the wrong component leaves everything out.
                "; ".join(n.split(": note: ", 1)[1] for n in left_out) or None,
            )
        return reqs
    if not isinstance(raw, list):
        raise error_at("'requirements' must be a list of {id, text, ...}", doc, "requirements")
    for i, item in enumerate(raw):
        item_line = raw.item_line(i) if isinstance(raw, LineList) else None
        if not isinstance(item, dict):
            raise UserError(
                "each requirement must be a mapping with id and text",
                file=str(path),
                line=item_line,
            )
        check_keys(item, REQ_KEYS, "a requirement")
        rid = _requirement_id(item)
        text = _requirement_text(item, rid, path)
        existing = by_id.get(rid)
        if existing is not None and existing.line is not None:
            raise error_at(
                f"duplicate requirement id '{rid}' (first at line {existing.id_line})", item, "id"
            )
        if existing is None and not text:
            raise error_at(
                f"requirement '{rid}' has no text", item, "id", "add text: <FRETISH sentence>"
            )
        entry = existing or RequirementEntry(
            id=rid, text="", file=str(path), line=None, col=1, display=rid
        )
        _fill_entry(entry, item, text, path, existing is None, defaults)
        if existing is None:
            reqs.append(entry)
            by_id[rid] = entry
    return reqs


def _defaults(doc: LineDict) -> LineDict:
    """The ``requirement_defaults:`` section, checked; empty when absent."""
    defaults = as_mapping(
        doc.get("requirement_defaults") or LineDict(),
        doc,
        "requirement_defaults",
        "requirement_defaults",
    )
    if defaults:
        check_keys(defaults, DEFAULTS_KEYS, "requirement_defaults")
    return defaults


def _import_requirements(
    doc: LineDict,
    path: Path,
    defaults: LineDict,
    reqs: list[RequirementEntry],
    by_id: dict[str, RequirementEntry],
    imports: Imports,
) -> list[str]:
    """Appends the ``requirements_from:`` files' requirements to ``reqs`` and
    ``by_id``, with the defaults' mitigations and policy; returns the notes on
    what the imports left out."""
    component = doc.get("component")
    left_out: list[str] = []
    for entry_path in file_names(doc.get("requirements_from"), doc, "requirements_from"):
        file_notes: list[str] = []
        fret_file = relative_to(path, entry_path)
        imports.read_named(fret_file, "FRET file", doc, "requirements_from", entry_path)
        imported, _internal, _other = load_fret_export(
            fret_file,
            str(component) if isinstance(component, str) else None,
            file_notes,
            taken=frozenset(by_id),
            imports=imports,
        )
        line = doc.key_line("requirements_from")
        left_out += [f"{path}:{line}: note: {entry_path}: {n}" for n in file_notes]
        for r in imported:
            if r.id in by_id:
                raise error_at(
                    f"duplicate requirement id '{r.id}' in {printable(str(entry_path))}",
                    doc,
                    "requirements_from",
                )
            r.on_violation = mitigation_names(
                defaults.get("on_violation"), defaults, "on_violation"
            )
            r.policy = dict(defaults.get("policy") or {})
            r.id_line = doc.key_line("requirements_from")
            reqs.append(r)
            by_id[r.id] = r
    return left_out


def _requirement_id(item: LineDict) -> str:
    """The item's ``id:``, refused unless it is a C identifier."""
    rid = item.get("id")
    if not isinstance(rid, str) or not is_c_identifier(rid):
        # An id names C functions and log records (docs/reference/config.md).
        shown = printable(rid) if isinstance(rid, str) else rid
        raise error_at(
            f"requirement id '{shown}' must be a C identifier (letters, digits, '_', "
            f"at most {MAX_ID_CHARS} characters, not starting with a digit)",
            item,
            "id" if rid else None,
        )
    return str(rid)


def _requirement_text(item: LineDict, rid: str, path: Path) -> str | None:
    """The item's ``text:`` (None when absent), refused when it is not a string,
    holds a control character or is over the length limit."""
    text = item.get("text")
    if text is not None and not isinstance(text, str):
        raise error_at(
            f"requirement '{rid}': text must be a FRETISH sentence, not {_kind(text)}",
            item,
            "text",
        )
    bad = control_at(text) if text is not None else None
    if bad is not None:
        raise UserError(
            f"requirement '{rid}': its text holds {bad}",
            file=str(path),
            line=getattr(text, "line", item.key_line("text")),
            col=getattr(text, "col", None),
        )
    if text is not None and len(text) > MAX_TEXT_CHARS:
        # Refused before the parser sees it: its time and memory grow with the text.
        raise UserError(
            f"requirement '{rid}': its text is longer than {MAX_TEXT_CHARS} characters",
            file=str(path),
            line=getattr(text, "line", item.key_line("text")),
            col=getattr(text, "col", None),
            hint="a FRETISH sentence is one requirement; split it, or name parts with "
            "internal variables (docs/reference/config.md, Limits)",
        )
    return text


def _fill_entry(
    entry: RequirementEntry,
    item: LineDict,
    text: str | None,
    path: Path,
    new: bool,
    defaults: LineDict,
) -> None:
    """Sets ``entry``'s fields from the item; an item naming an imported
    requirement (``new`` false) overrides only the keys it gives."""
    if text:
        entry.text = str(text)
        entry.line = getattr(text, "line", item.key_line("text"))
        entry.col = getattr(text, "col", 1)
        entry.file = str(path)
        entry.fret_ptltl = None if new else entry.fret_ptltl
    entry.id_line = item.key_line("id")
    entry.rationale = str(item.get("rationale") or "")
    entry.on_violation_line = (
        item.key_line("on_violation") if "on_violation" in item else entry.id_line
    )
    if "on_violation" in item or new:
        entry.on_violation = mitigation_names(
            item.get("on_violation", defaults.get("on_violation")), item, "on_violation"
        )
    pol = item.get("policy", defaults.get("policy"))
    if pol is not None:
        pol = as_mapping(pol, item, "policy", "policy")
        check_keys(pol, POLICY_KEYS, f"policy of '{entry.id}'")
        entry.policy = pol
        entry.policy_line = pol.line if isinstance(pol, LineDict) else item.key_line("policy")
    if "predict" in item:
        raw = item["predict"]  # a bare "predict:" takes every default
        pred = as_mapping(as_linedict({}, item) if raw is None else raw, item, "predict", "predict")
        check_keys(pred, PREDICT_KEYS, f"predict of '{entry.id}'")
        entry.predict = pred
        entry.predict_line = item.key_line("predict")
    if "assumption" in item:
        entry.assumption = str(item["assumption"]).lower() == "true"
    else:
        entry.assumption = entry.assumption or "assumption" in entry.id.lower()


def _kind(value: object) -> str:
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "a mapping"
    return "a number or true/false"


def check_on_violation(
    requirements: list[RequirementEntry], mitigations: dict[str, Mitigation]
) -> None:
    """Every mitigation a requirement names is defined."""
    for r in requirements:
        for name in r.on_violation:
            if name not in mitigations:
                raise UserError(
                    f"requirement '{r.id}' names undefined mitigation '{name}'",
                    file=r.file,
                    line=r.on_violation_line or r.id_line or r.line,
                    hint=suggest(name, mitigations),
                )


def policy_config(
    r: RequirementEntry,
    mitigations: dict[str, Mitigation],
    variables: dict[str, Variable],
    file: str,
) -> PolicyConfig:
    """``r``'s policy, validated by :func:`mitigations.settings.parse_policy`, with
    its ``predict:`` (:func:`mitigations.settings.parse_predict`); an error points at
    the line of the key it is about."""
    config = _policy(r, mitigations, variables)
    if r.predict is None:
        return config
    pred = r.predict
    if not isinstance(pred, LineDict):
        pred = as_linedict(pred, None, r.predict_line or r.id_line)
    pred.file = pred.file or r.file
    try:
        predict = parse_predict(r.id, pred, mitigations=mitigations)
    except SettingsError as e:
        raise error_at(e.message, pred, e.key, e.hint) from None
    return replace(config, predict=predict)


def _policy(
    r: RequirementEntry, mitigations: dict[str, Mitigation], variables: dict[str, Variable]
) -> PolicyConfig:
    raw = r.policy
    if not raw:
        return PolicyConfig()
    pol = raw if isinstance(raw, LineDict) else as_linedict(raw, None, r.policy_line or r.id_line)
    pol.file = pol.file or r.file
    types = {name: (None if v.define is not None else v.type) for name, v in variables.items()}
    try:
        return parse_policy(r.id, pol, mitigations=mitigations, variables=types)
    except SettingsError as e:
        if e.key is not None and e.setting is not None:
            raise error_at(e.message, as_linedict(pol[e.key], pol), e.setting, e.hint) from None
        raise error_at(e.message, pol, e.key, e.hint) from None
