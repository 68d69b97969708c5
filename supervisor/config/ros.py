"""The ``ros:`` section: the supervisor's own node name and publishing periods."""

from __future__ import annotations

import re

from supervisor.config.fields import as_mapping, check_keys, error_at, number
from supervisor.config.model import RosConfig
from supervisor.config.yamlload import LineDict

ROS_KEYS = {"node_name", "heartbeat_ms", "diagnostics_ms"}


def load_ros(doc: LineDict) -> RosConfig:
    raw = doc.get("ros")
    if raw is None:
        return RosConfig()
    r = as_mapping(raw, doc, "ros", "ros")
    check_keys(r, ROS_KEYS, "ros")
    out = RosConfig()
    name = r.get("node_name")
    if name is not None:
        if not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", str(name)):
            raise error_at(f"ros.node_name '{name}' is not a valid ROS node name", r, "node_name")
        out.node_name = str(name)
    for key in ("heartbeat_ms", "diagnostics_ms"):
        v = number(r, key, "ros")
        if v is not None:
            setattr(out, key, v)
    return out
