"""A client of the daemon's control socket as the tests speak to it: one request
line, one answer line (docs/reference/commands.md, the control socket)."""

from __future__ import annotations

import json
import socket
from pathlib import Path
from typing import Any

RESET = b'{"command": "reset"}\n'


def connect(path: str | Path, timeout: float = 10) -> socket.socket:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(timeout)
    s.connect(str(path))
    return s


def answer_of(s: socket.socket) -> dict[str, Any]:
    """The one answer line (raises on a reset connection or a close without one)."""
    data = b""
    while not data.endswith(b"\n"):
        chunk = s.recv(65536)
        if not chunk:
            break
        data += chunk
    assert data.endswith(b"\n") and data.count(b"\n") == 1, data[:200]
    doc = json.loads(data)
    assert isinstance(doc, dict) and isinstance(doc.get("ok"), bool), doc
    assert isinstance(doc.get("message"), str), doc
    return doc


def ask(path: str | Path, line: bytes = RESET, timeout: float = 10) -> dict[str, Any]:
    with connect(path, timeout) as s:
        s.sendall(line)
        return answer_of(s)
