"""Files written whole or not at all: the start-up cache's entries and the files
``install-service`` writes (its unit, logrotate snippet, token); and directories
removed whole (the start-up cache's pruned entries).

A reader (another process, or this one after a crash or power loss) sees the old
file or the new one, never half of either: the bytes go to a temporary file in the
same directory, which is fsynced and renamed over the target, and the directory
is fsynced so the rename itself is on disk.
"""

from __future__ import annotations

import contextlib
import os
import shutil
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


def remove_whole(path: Path, aside: Path) -> None:
    """Remove the directory ``path`` so that a reader finds it whole or not at all:
    renamed to ``aside`` (a name in the same directory no reader looks for), then
    deleted (the start-up cache's pruning)."""
    os.rename(path, aside)
    shutil.rmtree(aside, ignore_errors=True)
