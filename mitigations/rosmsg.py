"""ROS 2 message types by name, and dotted field paths into them.

Used by ``check`` (an unknown type or field is a config error, not a run-time
crash) and by the node (to read a field and to build a message from a mapping).
Only rosidl's generated Python classes are needed, so this imports no rclpy.
"""

from __future__ import annotations

import importlib
from typing import Any

from monitors.errors import UserError

INT_TYPES = {
    "int8",
    "int16",
    "int32",
    "int64",
    "uint8",
    "uint16",
    "uint32",
    "uint64",
    "byte",
    "octet",
    "char",
}
REAL_TYPES = {"float", "double", "float32", "float64"}
# Which ROS leaf field types may feed which monitor variable type.
COMPATIBLE = {
    "bool": {"boolean"},
    "int64": INT_TYPES,
    "double": REAL_TYPES | INT_TYPES,
}


def message_class(name: str) -> type:
    """'std_msgs/msg/Int64' (also 'std_msgs/Int64', 'std_msgs::msg::Int64') -> class."""
    parts = [p for p in name.replace("::", "/").split("/") if p]
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or parts[1] not in ("msg", "srv", "action"):
        raise UserError(
            f"'{name}' is not a ROS 2 message type", hint="write it as package/msg/Name"
        )
    pkg, kind, cls = parts
    try:
        module = importlib.import_module(f"{pkg}.{kind}")
    except ImportError:
        raise UserError(
            f"ROS 2 package '{pkg}' is not installed (message type '{name}')",
            hint=f"install ros-jazzy-{pkg.replace('_', '-')}",
        ) from None
    klass = getattr(module, cls, None)
    if klass is None or not hasattr(klass, "get_fields_and_field_types"):
        raise UserError(f"package '{pkg}' has no message '{cls}'")
    return klass


def field_type(msg_class: type, path: str) -> str:
    """The ROS type name of a dotted field path ('linear.x' -> 'double')."""
    klass: Any = msg_class
    parts = path.split(".")
    for i, part in enumerate(parts):
        fields = klass.get_fields_and_field_types()
        if part not in fields:
            known = ", ".join(fields) or "none"
            raise UserError(f"message {klass.__name__} has no field '{part}' (fields: {known})")
        t = fields[part]
        if i == len(parts) - 1:
            return t
        if "/" not in t or t.startswith("sequence") or "[" in t:
            raise UserError(f"field '{'.'.join(parts[: i + 1])}' is {t}, not a message with fields")
        klass = message_class(t)
    raise AssertionError("unreachable")


# What a variable may make of an array field (config ``reduce:``; docs/reference/config.md).
REDUCTIONS = ("min", "max", "mean", "sum", "count", "len", "any", "all")


def element_type(t: str) -> str | None:
    """The element type of an array or sequence type ('sequence<float>', 'float[360]',
    'sequence<float, 10>'), or None for any other type."""
    if t.startswith("sequence<") and t.endswith(">"):
        return t[len("sequence<") : -1].split(",")[0].strip()
    if t.endswith("]") and "[" in t:
        return t[: t.index("[")]
    return None


def check_reduction(msg_name: str, path: str, reduce: str, var_type: str) -> str:
    """Validate ``reduce`` over the array field msg_name.path for a var_type variable;
    returns the element type."""
    leaf = field_type(message_class(msg_name), path)
    element = element_type(leaf)
    if element is None:
        raise UserError(f"field '{path}' of {msg_name} is {leaf}, not an array: reduce needs one")
    if reduce in ("len", "count"):
        wants, why = {"int64", "double"}, "a count"
    elif reduce in ("any", "all"):
        if element != "boolean":
            raise UserError(
                f"reduce: {reduce} needs an array of booleans; '{path}' holds {element}"
            )
        wants, why = {"bool"}, "true or false"
    else:
        if element not in REAL_TYPES | INT_TYPES:
            raise UserError(f"reduce: {reduce} needs an array of numbers; '{path}' holds {element}")
        ints = element in INT_TYPES and reduce != "mean"
        wants, why = ({"int64", "double"} if ints else {"double"}), f"{reduce} of {element}"
    if var_type not in wants:
        raise UserError(
            f"reduce: {reduce} over '{path}' gives {why}, which cannot feed a {var_type} variable"
        )
    return element


def reduce_values(values: Any, how: str, bounds: tuple[float, float] | None = None) -> Any:
    """``how`` over an array's elements.  Readings that are NaN are not readings and
    are left out; with ``bounds`` (a LaserScan's range_min..range_max, REP 117) so are
    infinite ones and those outside the bounds.  With no reading left: min is +inf,
    max -inf, mean NaN, sum 0, count 0 (len counts every element)."""
    import numpy as np

    if how == "len":
        return len(values)
    if how in ("any", "all"):
        flags = [bool(x) for x in values]
        return any(flags) if how == "any" else all(flags)
    arr = np.asarray(values)
    integral = arr.dtype.kind in "iu" or (arr.size == 0 and how not in ("mean",))
    if arr.dtype.kind == "f":
        keep = ~np.isnan(arr)
        if bounds is not None:
            keep &= np.isfinite(arr) & (arr >= bounds[0]) & (arr <= bounds[1])
        arr = arr[keep]
        integral = False
    if how == "count":
        return int(arr.size)
    if arr.size == 0:
        return {"min": float("inf"), "max": float("-inf"), "mean": float("nan"), "sum": 0.0}[how]
    with np.errstate(all="ignore"):  # inf - inf is NaN, as in C: said by the value
        result = {"min": arr.min, "max": arr.max, "mean": arr.mean, "sum": arr.sum}[how]()
    return int(result) if integral and how != "mean" else float(result)


def read_value(msg: Any, path: str, reduce: str | None = None) -> Any:
    """The value a variable reads: the field at ``path``, reduced when ``reduce`` says
    so.  A LaserScan's ``ranges`` honour its own range_min and range_max (REP 117)."""
    value = get_field(msg, path)
    if reduce is None:
        return value
    bounds = None
    head, _, last = path.rpartition(".")
    parent = get_field(msg, head) if head else msg
    if last == "ranges" and hasattr(parent, "range_min") and hasattr(parent, "range_max"):
        bounds = (float(parent.range_min), float(parent.range_max))
    return reduce_values(value, reduce, bounds)


def check_field(msg_name: str, path: str, var_type: str) -> str:
    """Validate that msg_name.path exists and can feed a variable of var_type."""
    leaf = field_type(message_class(msg_name), path)
    if leaf not in COMPATIBLE[var_type]:
        raise UserError(
            f"field '{path}' of {msg_name} is {leaf}, which cannot feed a {var_type} variable"
        )
    return leaf


def get_field(msg: Any, path: str) -> Any:
    for part in path.split("."):
        msg = getattr(msg, part)
    return msg


def build_message(msg_class: type, value: Any, where: str = "value") -> Any:
    """A message instance from a nested mapping ({linear: {x: 0.0}})."""
    msg = msg_class()
    if value is None:
        return msg
    if not isinstance(value, dict):
        raise UserError(f"{where} must be a mapping of field names, e.g. {{data: true}}")
    fields = msg_class.get_fields_and_field_types()
    for key, v in value.items():
        if key not in fields:
            raise UserError(
                f"{where}: message {msg_class.__name__} has no field '{key}' (fields: {', '.join(fields)})"
            )
        t = fields[key]
        if isinstance(v, dict):
            v = build_message(message_class(t), v, f"{where}.{key}")
        try:
            setattr(msg, key, v)
        except (AssertionError, TypeError, ValueError) as e:
            raise UserError(f"{where}.{key}: {v!r} is not a valid {t} ({e})") from None
    return msg
