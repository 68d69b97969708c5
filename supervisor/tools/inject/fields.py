"""The values a message field can carry: an injected value must be publishable."""

from __future__ import annotations

import struct
from typing import Any

from mitigations.rosmsg import field_type, message_class
from monitors.errors import UserError
from monitors.verify.interpret import Value

# ROS integer field types -> the values a message can carry (uint64 above
# int64's maximum is rejected by the supervisor, so it is left out)
INT_FIELD_RANGE = {
    "int8": (-(1 << 7), (1 << 7) - 1),
    "int16": (-(1 << 15), (1 << 15) - 1),
    "int32": (-(1 << 31), (1 << 31) - 1),
    "int64": (-(1 << 63), (1 << 63) - 1),
    "uint8": (0, (1 << 8) - 1),
    "uint16": (0, (1 << 16) - 1),
    "uint32": (0, (1 << 32) - 1),
    "uint64": (0, (1 << 63) - 1),
    "byte": (0, 255),
    "octet": (0, 255),
    "char": (0, 255),
}


def field_domains(cfg: Any) -> dict[str, str]:
    """Variable -> the ROS leaf type of its field (empty when ROS is not importable)."""
    out = {}
    for v in cfg.inputs:
        try:
            out[v.name] = field_type(message_class(v.msg), v.field)
        except (UserError, ImportError):
            pass  # check reports it; the value is then not narrowed
    return out


def fits(leaf: str | None, value: Value) -> bool:
    """The value can be carried by a field of ROS type ``leaf`` (None: unknown)."""
    if leaf in INT_FIELD_RANGE:
        lo, hi = INT_FIELD_RANGE[leaf]
        return float(value).is_integer() and lo <= value <= hi
    if leaf in ("float", "float32") and isinstance(value, float):
        return struct.unpack("<f", struct.pack("<f", value))[0] == value
    return True
