"""OGMA's variable database (``variables_from:``): input variables with their topics."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from monitors.ir.spec import TYPE_ALIASES

_OGMA_LINE = re.compile(r'^\(\s*"([^"]+)"\s*,\s*"([^"]+)"\s*,\s*"([^"]*)"\s*,\s*"([^"]+)"\s*\)\s*$')
# OGMA's old topic datatypes (thesis Table 11) -> ROS 2 message types.
_OGMA_TOPIC_TYPES = {
    "int64_t": ("std_msgs/msg/Int64", "int64"),
    "int32_t": ("std_msgs/msg/Int32", "int64"),
    "bool": ("std_msgs/msg/Bool", "bool"),
    "double": ("std_msgs/msg/Float64", "double"),
    "float": ("std_msgs/msg/Float32", "double"),
    "uint8_t": ("std_msgs/msg/UInt8", "int64"),
}


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
            vtype = TYPE_ALIASES.get(str(ctype).replace("_t", "").lower()) or TYPE_ALIASES.get(
                str(ctype)
            )
            if vtype is None:
                raise UserError(f"variable '{name}' has unsupported type '{ctype}'", file=file)
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
        msg, vtype = _OGMA_TOPIC_TYPES.get(ttype.lower(), (None, None))
        if msg is None:
            raise UserError(
                f"unknown topic type '{ttype}'",
                file=file,
                line=lineno,
                hint="known: " + ", ".join(_OGMA_TOPIC_TYPES),
            )
        declared = TYPE_ALIASES.get(ctype.replace("_t", "").lower(), TYPE_ALIASES.get(ctype))
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
