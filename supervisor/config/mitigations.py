"""The ``mitigations:`` and ``on_stale:`` sections.

What a mitigation's settings may be is :mod:`mitigations.settings`'; this
module walks the YAML and points each error at its line.
"""

from __future__ import annotations

from mitigations.settings import Mitigation, SettingsError, parse_mitigation
from supervisor.config.fields import as_mapping, error_at, mitigation_names, suggest
from supervisor.config.yamlload import LineDict


def load_mitigations(doc: LineDict) -> dict[str, Mitigation]:
    raw = doc.get("mitigations")
    if raw is None:
        return {}
    ms = as_mapping(raw, doc, "mitigations", "mitigations")
    out: dict[str, Mitigation] = {}
    for name, spec in ms.items():
        spec = as_mapping(spec, ms, f"mitigation '{name}'", name)
        try:
            out[str(name)] = parse_mitigation(str(name), spec, ms.key_line(name))
        except SettingsError as e:
            # Errors about the entry as a whole point at its name, others at their key.
            where, key = (spec, e.key) if e.key is not None else (ms, name)
            raise error_at(e.message, where, key, e.hint) from None
    return out


def load_on_stale(doc: LineDict, mitigations: dict[str, Mitigation]) -> list[str]:
    """The mitigations run when an input goes stale."""
    names = mitigation_names(doc.get("on_stale"), doc, "on_stale")
    for name in names:
        if name not in mitigations:
            raise error_at(
                f"on_stale names undefined mitigation '{name}'",
                doc,
                "on_stale",
                suggest(name, mitigations),
            )
    return names
