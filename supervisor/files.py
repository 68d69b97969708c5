"""Files written whole or not at all: the start-up cache's entries and the files
``install-service`` writes (its unit, logrotate snippet, token).

A reader (another process, or this one after a crash or power loss) sees the old
file or the new one, never half of either: the bytes go to a temporary file in the
same directory, which is fsynced and renamed over the target, and the directory
is fsynced so the rename itself is on disk.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path


def write_atomic(path: Path, data: bytes, mode: int = 0o600) -> None:
    """``data`` as ``path``, with permissions ``mode``: whole or absent."""
    # mkstemp opens O_EXCL with a fresh name: never a symlink planted there, never
    # another writer's temporary file.
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    dfd = os.open(path.parent, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)
