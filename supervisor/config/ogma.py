"""OGMA's variable database (``variables_from:``): input variables with their topics."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from monitors.errors import UserError

_OGMA_LINE = re.compile(r'^\(\s*"([^"]+)"\s*,\s*"([^"]+)"\s*,\s*"([^"]*)"\s*,\s*"([^"]+)"\s*\)\s*$')
# The C and ROS type names OGMA's databases use, as monitor types: the integers
# widen to int64 and the floats to double (docs/reference/config.md).
_INTS = ("int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64")
OGMA_TYPES = {
    **{n: "bool" for n in ("bool", "_bool", "boolean")},
    **{n: "int64" for n in _INTS},
    **{n + "_t": "int64" for n in _INTS},
    **{n: "int64" for n in ("int", "short", "long", "char", "byte", "unsigned", "integer")},
    **{n: "double" for n in ("float", "double", "float32", "float64", "real")},
}
# OGMA's old topic datatypes (thesis Table 11): std_msgs' type of each C type.
_STD_MSGS = {
    **{n: n.capitalize() for n in _INTS},
    "bool": "Bool",
    "float": "Float32",
    "double": "Float64",
}


def ogma_type(name: str) -> str | None:
    """A C or ROS type name (``uint8_t``, ``std::int32_t``, ``float64``) as a monitor type."""
    t = str(name).strip().lower().removeprefix("std::")
    return OGMA_TYPES.get(t) or OGMA_TYPES.get(" ".join(t.split()[-1:]))


def _topic_type(name: str) -> tuple[str | None, str | None]:
    t = str(name).strip().lower().removesuffix("_t")
    msg = _STD_MSGS.get(t)
    if msg is None:
        return None, None
    return f"std_msgs/msg/{msg.replace('Uint', 'UInt')}", ogma_type(t)


def load_ogma_variables(path: Path) -> list[dict[str, Any]]:
    """OGMA's variable database: JSON (OGMA 1.7+) or the older one-tuple-per-line format."""
    file = str(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise UserError(f"cannot read OGMA variable database: {e.strerror}", file=file) from None
    out: list[dict[str, Any]] = []
    if text.lstrip().startswith("{"):
        try:
            db = json.loads(text)
        except json.JSONDecodeError as e:
            raise UserError(
                f"invalid JSON: {e.msg}", file=file, line=e.lineno, col=e.colno
            ) from None
        topics = {t.get("topic"): t for t in db.get("topics", []) if isinstance(t, dict)}
        for item in db.get("inputs", []):
            name, ctype = item.get("name"), item.get("type", "")
            conns = [
                c for c in item.get("connections", []) if str(c.get("scope", "")).startswith("ros")
            ]
            if not name or not conns:
                continue
            topic = conns[0].get("topic")
            msg = str(topics.get(topic, {}).get("type", "")).replace("::", "/")
            vtype = ogma_type(ctype)
            if vtype is None:
                raise UserError(
                    f"variable '{name}' has type '{ctype}', which is not a C or ROS number or bool",
                    file=file,
                    hint="known: " + ", ".join(OGMA_TYPES),
                )
            out.append(
                {
                    "name": name,
                    "type": vtype,
                    "topic": topic,
                    "msg": msg or None,
                    "field": conns[0].get("field") or "data",
                    "line": None,
                }
            )
        return out
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith(("#", "--")):
            continue
        m = _OGMA_LINE.match(line)
        if not m:
            raise UserError('expected ("name","type","/topic","TopicType")', file=file, line=lineno)
        name, ctype, topic, ttype = m.groups()
        msg, vtype = _topic_type(ttype)
        if msg is None:
            raise UserError(
                f"unknown topic type '{ttype}'",
                file=file,
                line=lineno,
                hint="known: " + ", ".join(f"{n}_t" for n in _INTS) + ", bool, float, double",
            )
        declared = ogma_type(ctype)
        if declared is not None and declared != vtype:
            raise UserError(
                f"variable '{name}' is {ctype} but its topic carries {ttype}",
                file=file,
                line=lineno,
            )
        out.append(
            {
                "name": name,
                "type": vtype,
                "topic": topic,
                "msg": msg,
                "field": "data",
                "line": lineno,
            }
        )
    return out
