"""JSON-lines traces (the schema is in supervisor/tools/replay/sources.py)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore

from monitors.errors import UserError
from supervisor.config.model import Config, Variable
from supervisor.tools.replay.storage import (
    RECORDS_TOPIC,
    STRING,
    Damage,
    Raw,
    Source,
    normalise_type,
)

# --- JSON-lines traces ----------------------------------------------------------------


class Trace(Source):
    def __init__(self, path: Path, cfg: Config) -> None:
        self.path = path
        self.label = str(path)
        self.counts = None
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
            raise ValueError(f"'{v.name}' is {v.type}; {json.dumps(value)} is not")
        return float(value) if v.type == "double" else value

    def chunks(self, ids: dict[str, int], chunk: int) -> Iterator[Raw]:
        ts: list[int] = []
        tops: list[int] = []
        items: list[Any] = []

        def out() -> Raw:
            return Raw(np.asarray(ts, np.int64), np.asarray(tops, np.int32), items=items)

        last = -1
        try:
            f = self.path.open(encoding="utf-8")
        except OSError as e:
            raise UserError(f"cannot read the trace ({e.strerror})", file=self.label) from None
        with f:
            for lineno, line in enumerate(f, 1):
                if not line.strip():
                    continue
                try:
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
                if len(ts) >= chunk:
                    yield out()
                    ts, tops, items = [], [], []
        if ts:
            yield out()

    def _line(self, line: str) -> tuple[int, str, Any]:
        try:
            obj = json.loads(line)
        except json.JSONDecodeError as e:
            raise ValueError(f"not JSON ({e.msg}, column {e.colno})") from None
        schema = '{"t_ns": N, "name": VARIABLE, "value": V} or {"t_ns": N, "record": {...}}'
        if not isinstance(obj, dict) or set(obj) not in (
            {"t_ns", "name", "value"},
            {"t_ns", "record"},
        ):
            raise ValueError(f"expected {schema}, got {line.strip()[:80]}")
        t = obj["t_ns"]
        if not isinstance(t, int) or isinstance(t, bool) or t < 0:
            raise ValueError(
                f"t_ns must be a whole number of nanoseconds >= 0, got {json.dumps(t)}"
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
                f"{json.dumps(name)} is not a topic variable of the config (known: {known})"
            )
        return t, v.topic, (name, self._value(v, obj["value"]))
