"""JSON-lines traces (the schema is in supervisor/tools/replay/sources.py)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore

from monitors.errors import UserError
from monitors.untrusted import Untrusted, load_json, printable
from supervisor.config.model import Config, Variable
from supervisor.tools.replay.storage import (
    CHUNK_BYTES,
    LINE_BYTES,
    NS_MAX,
    RECORDS_TOPIC,
    STRING,
    Damage,
    Raw,
    Source,
    normalise_type,
    open_regular,
)

# --- JSON-lines traces ----------------------------------------------------------------


class Trace(Source):
    def __init__(self, path: Path, cfg: Config) -> None:
        self.path = path
        self.label = str(path)
        self.counts = None
        self.warnings: list[str] = []
        self.store = get_typestore(Stores.EMPTY)
        self.vars = {v.name: v for v in cfg.inputs if v.topic}
        self.topics = {v.topic: normalise_type(v.msg or "") for v in self.vars.values() if v.topic}
        self.topics[RECORDS_TOPIC] = STRING

    def _value(self, v: Variable, value: Any) -> Any:
        ok = {
            "bool": isinstance(value, bool),
            "int64": isinstance(value, int)
            and not isinstance(value, bool)
            and -(2**63) <= value < 2**63,
            "double": isinstance(value, int | float) and not isinstance(value, bool),
        }[v.type]
        if not ok:
            raise ValueError(f"'{v.name}' is {v.type}; {printable(json.dumps(value)[:80])} is not")
        return float(value) if v.type == "double" else value

    def chunks(self, ids: dict[str, int], chunk: int) -> Iterator[Raw]:
        ts: list[int] = []
        tops: list[int] = []
        items: list[Any] = []

        def out() -> Raw:
            return Raw(np.asarray(ts, np.int64), np.asarray(tops, np.int32), items=items)

        last = -1
        size = 0  # bytes of the lines in the chunk: a chunk stops at CHUNK_BYTES too
        try:
            f = open_regular(self.path)
        except Damage as e:
            raise UserError(f"cannot read the trace ({e})", file=self.label) from None
        with f:
            lineno = 0
            while line := f.readline(LINE_BYTES + 1):
                lineno += 1
                try:
                    if len(line) > LINE_BYTES:
                        raise ValueError(f"larger than {LINE_BYTES} bytes")
                    if not line.strip():
                        continue
                    t, topic, item = self._line(line)
                    if t < last:
                        raise ValueError(f"t_ns {t} is before the previous line's {last}")
                except ValueError as e:
                    if ts:
                        yield out()
                    raise Damage(f"line {lineno}: {e}") from None
                last = t
                if topic in ids:
                    ts.append(t)
                    tops.append(ids[topic])
                    items.append(item)
                    size += len(line)
                if len(ts) >= chunk or size >= CHUNK_BYTES:
                    yield out()
                    ts, tops, items, size = [], [], [], 0
        if ts:
            yield out()

    def _line(self, line: bytes) -> tuple[int, str, Any]:
        try:
            obj = load_json(line, max_bytes=LINE_BYTES)
        except Untrusted as e:
            raise ValueError(str(e)) from None
        schema = '{"t_ns": N, "name": VARIABLE, "value": V} or {"t_ns": N, "record": {...}}'
        if not isinstance(obj, dict) or set(obj) not in (
            {"t_ns", "name", "value"},
            {"t_ns", "record"},
        ):
            shown = printable(line.strip()[:80].decode("utf-8", "replace"))
            raise ValueError(f"expected {schema}, got {shown}")
        t = obj["t_ns"]
        if not isinstance(t, int) or isinstance(t, bool) or not 0 <= t <= NS_MAX:
            raise ValueError(
                f"t_ns must be a whole number of nanoseconds, 0 to 2^63-1, got {json.dumps(t)[:40]}"
            )
        if "record" in obj:
            if not isinstance(obj["record"], dict):
                raise ValueError("record must be a JSON object")
            return t, RECORDS_TOPIC, obj["record"]
        name = obj["name"]
        v = self.vars.get(name) if isinstance(name, str) else None
        if v is None or v.topic is None:
            known = ", ".join(self.vars) or "none"
            raise ValueError(
                f"{printable(json.dumps(name)[:80])} is not a topic variable of the config (known: {known})"
            )
        return t, v.topic, (name, self._value(v, obj["value"]))
