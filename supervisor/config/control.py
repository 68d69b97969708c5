"""The ``control:`` section: the operator's control socket and its reset rate limit.

Who may reset is decided by the socket file's permissions (owner and
``group``) and checked again on the caller's SO_PEERCRED; how often by
``max_resets`` per ``interval_ms``.  docs/reference/config.md, ``control:``.
"""

from __future__ import annotations

import re
from pathlib import Path

from supervisor.config.fields import as_mapping, check_keys, error_at, number, relative_to
from supervisor.config.model import ControlConfig
from supervisor.config.yamlload import LineDict

CONTROL_KEYS = {"socket", "group", "max_resets", "interval_ms"}
# sockaddr_un.sun_path is 108 bytes with the terminating NUL (unix(7)).
MAX_SOCKET_PATH = 107
GROUP_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_.-]*\$?$")


def load_control(doc: LineDict, config: Path) -> ControlConfig:
    raw = doc.get("control")
    out = ControlConfig(file=str(config))
    if raw is None:
        return out
    c = as_mapping(raw, doc, "control", "control")
    check_keys(c, CONTROL_KEYS, "control")
    out.line = c.line
    sock = c.get("socket")
    if sock is not None:
        if not isinstance(sock, str) or not sock.strip():
            raise error_at("control.socket must be a file path", c, "socket")
        path = str(relative_to(config, sock))
        if len(path.encode()) > MAX_SOCKET_PATH:
            raise error_at(
                f"control.socket '{path}' is {len(path.encode())} bytes long; "
                f"a Unix socket path has at most {MAX_SOCKET_PATH}",
                c,
                "socket",
                hint="use a shorter path, e.g. under /run or /tmp",
            )
        out.socket, out.socket_line = path, c.key_line("socket")
    group = c.get("group")
    if group is not None:
        if not isinstance(group, str) or not GROUP_NAME.match(group):
            raise error_at(f"control.group '{group}' is not a group name", c, "group")
        out.group, out.group_line = group, c.key_line("group")
    n = c.get("max_resets")
    if n is not None:
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise error_at(
                f"control.max_resets must be a whole number >= 1, got '{n}'", c, "max_resets"
            )
        out.max_resets = n
    interval = number(c, "interval_ms", "control")
    if interval is not None:
        out.interval_ms = interval
    return out
