"""The daemon's ROS names, control socket and defaults, defined once.

The daemon serves and publishes under these names; the tools (``reset``, ``bench``,
``inject``, ``demo``) and the tests reach the daemon through them.  The reference
is docs/reference/ros-interfaces.md (the daemon's topics, services and control
socket).
"""

from __future__ import annotations

import os
import stat
from collections.abc import Mapping
from pathlib import Path

NODE_NAME = "safety_supervisor"
VIOLATIONS_TOPIC = "/safety_supervisor/violations"  # std_msgs/String, one JSON record each
# std_msgs/String, every log record with markers: in the recorder's bags (run --record)
RECORDS_TOPIC = "/safety_supervisor/records"
HEARTBEAT_TOPIC = "/safety_supervisor/heartbeat"  # std_msgs/UInt64, from the loop
RESET_SERVICE = "/safety_supervisor/reset"  # std_srvs/Trigger: opt-in (ros.reset_service)
# std_msgs/String, JSON: each requirement's state, inputs, health (docs/reference/
# ros-interfaces.md, "Status"); reliable + transient local, so a page that starts late
# gets the latest at once
STATUS_TOPIC = "/safety_supervisor/status"
DIAGNOSTICS_TOPIC = "/diagnostics"  # diagnostic_msgs/DiagnosticArray (REP 107)

# The operator's control socket (docs/reference/ros-interfaces.md, "Control socket").
CONTROL_SOCKET = "control.sock"  # in the unit's RuntimeDirectory=
SYSTEMD_CONTROL_SOCKET = "/run/safety-supervisor/control.sock"
OPERATORS_GROUP = "safety-operators"  # install-service creates it; the unit joins it


def _user_control_socket(env: Mapping[str, str]) -> str:
    """Outside systemd: per user and per ROS domain, so supervisors of different
    domains (and their test runs) never share one."""
    domain = env.get("ROS_DOMAIN_ID", "").strip() or "0"
    base = env.get("XDG_RUNTIME_DIR")
    root = (
        Path(base) / "safety-supervisor" if base else Path(f"/tmp/safety-supervisor-{os.getuid()}")
    )
    return str(root / f"control-{domain}.sock")


def daemon_control_socket(env: Mapping[str, str] = os.environ) -> str:
    """Where ``run`` listens without ``control.socket``: the unit's runtime
    directory under systemd, else a per-user, per-domain path."""
    runtime = env.get("RUNTIME_DIRECTORY", "").split(":")[0]
    if runtime:
        return str(Path(runtime) / CONTROL_SOCKET)
    return _user_control_socket(env)


def client_control_socket(env: Mapping[str, str] = os.environ) -> str:
    """Where ``reset`` connects without ``--socket``: the installed service's
    socket if there is one, else the path a ``run`` of this user would use."""
    try:
        if stat.S_ISSOCK(os.stat(SYSTEMD_CONTROL_SOCKET).st_mode):
            return SYSTEMD_CONTROL_SOCKET
    except OSError:
        pass
    return _user_control_socket(env)
