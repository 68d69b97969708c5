"""Shared validation helpers of the config sections: every error is ``FILE:LINE: what``.

The position comes from the YAML loader's LineDict (``.line``, ``.key_line``);
a helper given the mapping and the key reports the key's own line.
"""

from __future__ import annotations

import difflib
import re
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from supervisor.config.yamlload import LineDict


def error_at(
    msg: str, where: Any, key: str | None = None, hint: str | None = None, file: str = ""
) -> UserError:
    """A UserError at ``key``'s line in ``where`` (or ``where``'s own line)."""
    line = (
        where.key_line(key)
        if (key is not None and isinstance(where, LineDict))
        else getattr(where, "line", None)
    )
    return UserError(msg, file=getattr(where, "file", file) or file, line=line, hint=hint)


def check_keys(d: LineDict, allowed: set[str], what: str) -> None:
    """Unknown keys are errors, with the closest known key as a suggestion."""
    for k in d:
        if k not in allowed:
            close = difflib.get_close_matches(k, sorted(allowed), n=1)
            hint = (
                f"did you mean '{close[0]}'?"
                if close
                else f"known keys: {', '.join(sorted(allowed))}"
            )
            raise error_at(f"unknown key '{k}' in {what}", d, k, hint)


def suggest(name: str, known: dict) -> str | None:
    close = difflib.get_close_matches(name, list(known), n=1)
    return f"did you mean '{close[0]}'?" if close else None


def as_mapping(value: Any, where: Any, what: str, key: str | None = None) -> LineDict:
    if not isinstance(value, dict):
        raise error_at(f"{what} must be a mapping", where, key)
    return value  # type: ignore[return-value]


def as_linedict(value: Any, parent: LineDict | None, line: int | None = None) -> LineDict:
    """A nested mapping with line numbers (falls back to the parent's line)."""
    if isinstance(value, LineDict):
        return value
    d = LineDict(value if isinstance(value, dict) else {})
    d.line = parent.line if parent is not None else (line or 0)
    d.file = parent.file if parent is not None else ""
    d._key_lines = {}
    return d


def number(d: LineDict, key: str, what: str, *, positive: bool = True) -> float | None:
    """``d[key]`` as a float (None if absent); positive unless told otherwise."""
    v = d.get(key)
    if v is None:
        return None
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise error_at(f"{what}.{key} must be a number, got '{v}'", d, key) from None
    if positive and x <= 0:
        raise error_at(f"{what}.{key} must be positive", d, key)
    return x


def mitigation_names(value: Any, where: LineDict, key: str) -> list[str]:
    """A mitigation name or a list of them (``on_violation``, ``on_stale``, ...)."""
    if value is None:
        return []
    if isinstance(value, str):
        return [str(value)]
    if not isinstance(value, list) or not all(isinstance(x, str) for x in value):
        raise error_at(f"'{key}' must be a list of mitigation names", where, key)
    return [str(x) for x in value]


def file_names(value: Any, where: LineDict, key: str) -> list[str]:
    """A file name or a list of them (``variables_from``, ``requirements_from``)."""
    if value is None:
        return []
    if isinstance(value, str):
        return [value]
    if isinstance(value, list) and all(isinstance(x, str) for x in value):
        return [str(x) for x in value]
    raise error_at(f"'{key}' must be a file name or a list of file names", where, key)


def relative_to(config: Path, name: str) -> Path:
    """A file named in the config: relative names are relative to the config's folder."""
    p = Path(name)
    return p if p.is_absolute() else config.parent / p


def typed_value(v: Any, vtype: str, where: LineDict, key: str, name: str) -> Any:
    """``v`` as a value of monitor type ``vtype`` (variable ``name``'s ``initial``, ...)."""
    s = str(v).strip()
    if vtype == "bool":
        if s.lower() in ("true", "1"):
            return True
        if s.lower() in ("false", "0"):
            return False
    elif vtype == "int64":
        if re.fullmatch(r"-?\d+", s):
            return int(s)
    else:
        try:
            return float(s)
        except ValueError:
            pass
    raise error_at(f"variable '{name}': {key} '{v}' is not a {vtype}", where, key)
