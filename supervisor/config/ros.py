"""The ``ros:`` section: the supervisor's own node name, publishing periods and
whether the unauthenticated ROS reset service exists (off by default)."""

from __future__ import annotations

import re

from supervisor.config.fields import as_mapping, check_keys, error_at, number
from supervisor.config.model import RosConfig
from supervisor.config.yamlload import LineDict
from supervisor.names import RESET_SERVICE

ROS_KEYS = {
    "node_name",
    "namespace",
    "heartbeat_ms",
    "diagnostics_ms",
    "status_ms",
    "reset_service",
}

# an absolute ROS namespace: also what replay's --namespace takes
NAMESPACE = re.compile(r"/([A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*)?")


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
    ns = r.get("namespace")
    if ns is not None:
        if not NAMESPACE.fullmatch(str(ns)):
            raise error_at(
                f"ros.namespace '{ns}' is not a ROS namespace",
                r,
                "namespace",
                "absolute, like /robot1 or /fleet/robot1",
            )
        out.namespace = str(ns)
    for key in ("heartbeat_ms", "diagnostics_ms", "status_ms"):
        # status_ms 0 turns the status topic off; the others must tick
        v = number(r, key, "ros", positive=key != "status_ms")
        if v is not None:
            setattr(out, key, v)
    reset = r.get("reset_service")
    if reset is not None:
        if not isinstance(reset, bool):
            raise error_at(
                f"ros.reset_service must be true or false, got '{reset}'", r, "reset_service"
            )
        out.reset_service, out.reset_service_line = reset, r.key_line("reset_service")
    return out


def reset_service_warning(ros: RosConfig, file: str) -> str | None:
    """``check``'s warning for the opt-in ROS reset service: std_srvs/Trigger
    carries no credentials, so only the graph's access control protects it."""
    if not ros.reset_service:
        return None
    return (
        f"{file}:{ros.reset_service_line}: ros.reset_service: any node on the ROS graph can "
        f"call {RESET_SERVICE} and lift a latched mitigation (std_srvs/Trigger carries no "
        "credentials); enable it only on an SROS2 graph with access control, else use "
        "the control socket (safety-supervisor reset)"
    )
