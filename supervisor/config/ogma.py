"""OGMA's variable database (``variables_from:``): input variables with their topics."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from monitors.untrusted import printable
from supervisor.config.imported import Fields, Imports, decode, named, read_json, top_list
from supervisor.config.limits import MAX_TEXT_CHARS

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


def load_ogma_variables(path: Path, imports: Imports | None = None) -> list[dict[str, Any]]:
    """OGMA's variable database: JSON (OGMA 1.7+) or the older one-tuple-per-line format.
    Read within the import bounds, every field read type-checked
    (supervisor/config/imported.py)."""
    file = str(path)
    text = decode((imports or Imports()).read(path, "OGMA variable database"), file)
    if text.lstrip().startswith("{"):
        return _json_database(read_json(path, "OGMA variable database", text), file)
    out: list[dict[str, Any]] = []
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
                f"unknown topic type '{printable(ttype)}'",
                file=file,
                line=lineno,
                hint="known: " + ", ".join(f"{n}_t" for n in _INTS) + ", bool, float, double",
            )
        declared = ogma_type(ctype)
        if declared is not None and declared != vtype:
            raise UserError(
                f"variable '{printable(name)}' is {printable(ctype)} but its topic carries "
                f"{printable(ttype)}",
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


def _json_database(db: object, file: str) -> list[dict[str, Any]]:
    topics: dict[str, str] = {}
    for i, item in enumerate(top_list(db, "topics", file), 1):
        t = Fields(item, f"topic {i}", file)
        topic = t.text("topic", max_chars=MAX_TEXT_CHARS)
        t.where = named(topic, i, "topic")
        mtype = t.text("type", max_chars=MAX_TEXT_CHARS)
        if topic is not None:
            topics[topic] = mtype or ""
    out: list[dict[str, Any]] = []
    for i, item in enumerate(top_list(db, "inputs", file), 1):
        v = Fields(item, f"variable {i}", file)
        name = v.text("name", max_chars=MAX_TEXT_CHARS)
        v.where = named(name, i, "variable")
        ctype = v.text("type", max_chars=MAX_TEXT_CHARS) or ""
        conns = []
        for j, c in enumerate(v.list("connections"), 1):
            conn = Fields(c, f"{v.where}: connection {j}", file)
            scope = conn.text("scope", max_chars=MAX_TEXT_CHARS) or ""
            topic = conn.text("topic", max_chars=MAX_TEXT_CHARS)
            field = conn.text("field", max_chars=MAX_TEXT_CHARS)
            if scope.startswith("ros"):
                conns.append((topic, field))
        if not name or not conns:
            continue
        topic, field = conns[0]
        msg = topics.get(topic or "", "").replace("::", "/")
        vtype = ogma_type(ctype)
        if vtype is None:
            raise UserError(
                f"variable '{printable(name)}' has type '{printable(ctype)}', which is not a C "
                "or ROS number or bool",
                file=file,
                hint="known: " + ", ".join(OGMA_TYPES),
            )
        out.append(
            {
                "name": name,
                "type": vtype,
                "topic": topic,
                "msg": msg or None,
                "field": field or "data",
                "line": None,
            }
        )
    return out
