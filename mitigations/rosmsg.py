"""ROS 2 message types by name, and dotted field paths into them: the one type
lookup of the actions, the inputs (``supervisor/inputs/``, whose ``rostypes.py``
resolves a recording's types with the names written as here) and the tools.

Used by ``check`` (an unknown type or field is a config error, not a run-time
crash) and by the node (to read a field and to build a message from a mapping).
Only rosidl's generated Python classes are needed, so this imports no rclpy.  It
lives in ``mitigations`` because the publish action needs it and a package may use
only those below it (docs/ARCHITECTURE.md).
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


def normalise_type(name: str) -> str:
    """'std_msgs/Int64', 'std_msgs::msg::Int64' -> 'std_msgs/msg/Int64'."""
    parts = [p for p in name.replace("::", "/").split("/") if p]
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    return "/".join(parts)


def debian_package(pkg: str) -> str:
    """The Jazzy package that installs ROS package ``pkg`` ('std_msgs' -> ros-jazzy-std-msgs)."""
    return f"ros-jazzy-{pkg.replace('_', '-')}"


def package_hint(name: str) -> str:
    """Which package would provide type ``name`` ('test_msgs/srv/X' -> ros-jazzy-test-msgs)."""
    pkg = name.split("/", 1)[0]
    return f"install {debian_package(pkg)} (the package {pkg})"


def message_class(name: str) -> type:
    """'std_msgs/msg/Int64' (also 'std_msgs/Int64', 'std_msgs::msg::Int64') -> class."""
    parts = normalise_type(name).split("/")
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
            hint=f"install {debian_package(pkg)}",
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
