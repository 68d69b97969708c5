"""Shared validation helpers of the config sections: every error is ``FILE:LINE: what``.

The position comes from the YAML loader's LineDict (``.line``, ``.key_line``);
a helper given the mapping and the key reports the key's own line.
"""

from __future__ import annotations

import difflib
import math
import re
from pathlib import Path
from typing import Any

from mitigations.settings import integral_value
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


# The largest duration any key takes, in ms (about 11.6 days): timers, waits and
# tick counts derived from it stay far inside what rclpy, threading and int64 hold.
MAX_MS = 1e9
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1


def _shown(v: Any) -> str:
    text = str(v) if not isinstance(v, int) or abs(v) < 10**30 else f"{str(v)[:20]}..."
    return text if len(text) <= 40 else text[:37] + "..."


def to_number(v: Any, where: Any, key: str | None, what: str) -> float:
    """One config value as a finite float: ``true``, text that is no number,
    ``nan``/``inf`` (also as text) and integers beyond a double are errors."""
    x = math.nan
    if not isinstance(v, bool):
        try:
            x = float(v)
        except (TypeError, ValueError, OverflowError):
            raise error_at(f"{what} must be a number, got '{_shown(v)}'", where, key) from None
    if not math.isfinite(x):
        raise error_at(f"{what} must be a finite number, got '{_shown(v)}'", where, key)
    return x


def number(
    d: LineDict, key: str, what: str, *, positive: bool = True, maximum: float = MAX_MS
) -> float | None:
    """``d[key]``, a duration in ms, as a float (None if absent): finite, never
    negative, at most ``maximum``, and positive unless told otherwise."""
    v = d.get(key)
    if v is None:
        return None
    x = to_number(v, d, key, f"{what}.{key}")
    if positive and x <= 0:
        raise error_at(f"{what}.{key} must be positive", d, key)
    if x < 0:
        raise error_at(f"{what}.{key} must not be negative", d, key)
    if x > maximum:
        raise error_at(
            f"{what}.{key} must be at most {maximum:g}, got {_shown(v)}",
            d,
            key,
            "durations are in milliseconds" if key.endswith("_ms") else None,
        )
    return x


def whole_number(
    d: LineDict, key: str, what: str, *, default: int, minimum: int, maximum: int
) -> int:
    """``d[key]`` (``default`` if absent) as a whole number in [minimum, maximum]."""
    v = d.get(key, default)
    text = _shown(v).strip()
    if (
        isinstance(v, bool)
        or not re.fullmatch(r"\d{1,18}", text)
        or not minimum <= int(text) <= maximum
    ):
        raise error_at(
            f"{what}: {key} must be a whole number from {minimum} to {maximum}, got '{text}'",
            d,
            key,
        )
    return int(text)


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
    if vtype not in ("bool", "int64"):
        return to_number(v, where, key, f"variable '{name}': {key}")
    value = integral_value(_shown(v), vtype)
    if value is not None:
        return value
    raise error_at(f"variable '{name}': {key} '{_shown(v)}' is not a {vtype}", where, key)
