"""Files written whole or not at all: the start-up cache's entries and the files
``install-service`` writes (its unit, logrotate snippet, token); and directories
removed whole (the start-up cache's pruned entries).

A reader (another process, or this one after a crash or power loss) sees the old
file or the new one, never half of either: the bytes go to a temporary file in the
same directory, which is fsynced and renamed over the target, and the directory
is fsynced so the rename itself is on disk.

``write_whole`` is the same without the fsyncs, for files made durable in groups by
``sync_filesystem`` (the fleet dataset's, docs/BENCHMARKS.md, "Fleet"): after a
process kill a reader still sees the old file or the new one (the kernel's page
cache outlives the process); only a power loss before the group's sync can leave the
new name empty or with part of its bytes, which that file's reader must allow for.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import os
import shutil
import stat
import tempfile
from pathlib import Path
from typing import BinaryIO


def write_atomic(path: Path, data: bytes, mode: int = 0o600) -> None:
    """``data`` as ``path``, with permissions ``mode``: whole or absent, and durable."""
    _write(path, data, mode, sync=True)
    dfd = os.open(path.parent, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)


def write_whole(path: Path, data: bytes, mode: int = 0o600) -> None:
    """``data`` as ``path``: whole or absent to every reader while the machine runs,
    durable only once ``sync_filesystem`` has run after it (module docstring)."""
    _write(path, data, mode, sync=False)


def _write(path: Path, data: bytes, mode: int, *, sync: bool) -> None:
    # mkstemp opens O_EXCL with a fresh name: never a symlink planted there, never
    # another writer's temporary file.
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            if sync:
                f.flush()
                os.fsync(f.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


_libc: ctypes.CDLL | None = None


def sync_filesystem(path: Path) -> None:
    """Every file written on ``path``'s filesystem, and every rename there, on disk:
    one ``syncfs`` (Linux) for any number of files, where an fsync per file and its
    directory is a journal commit each; elsewhere ``sync``, every filesystem's."""
    global _libc
    if _libc is None:
        _libc = ctypes.CDLL(None, use_errno=True)
    syncfs = getattr(_libc, "syncfs", None)
    if syncfs is None:
        os.sync()
        return
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        if syncfs(fd) != 0:
            e = ctypes.get_errno()
            raise OSError(e, os.strerror(e), str(path))
    finally:
        os.close(fd)


def remove_whole(path: Path, aside: Path) -> None:
    """Remove the directory ``path`` so that a reader finds it whole or not at all:
    renamed to ``aside`` (a name in the same directory no reader looks for), then
    deleted (the start-up cache's pruning)."""
    os.rename(path, aside)
    shutil.rmtree(aside, ignore_errors=True)


class NotRegularFile(OSError):
    """What ``open_regular`` found at a path: a FIFO, a device, a directory (``mode``)."""

    def __init__(self, path: Path, mode: int) -> None:
        super().__init__(errno.EINVAL, "not a regular file", str(path))
        self.mode = mode


def open_regular(path: Path, *, follow: bool = True) -> BinaryIO:
    """``path`` opened for reading if it is a regular file: never waits on a FIFO for a
    writer or reads a device, whatever an input names (a file listed as a regular one
    can be swapped before it is opened).  ``NotRegularFile`` otherwise; ``follow``
    False: a link is ``OSError`` ELOOP, not its target."""
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | (0 if follow else os.O_NOFOLLOW)
    fd = os.open(path, flags)
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        raise NotRegularFile(path, mode)
    fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
    return os.fdopen(fd, "rb")
