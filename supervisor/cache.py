"""The start-up cache: the compiled monitor and the analyses' findings, kept in the
daemon's state directory so that ``check`` (ExecStartPre) and ``run`` do the
expensive work once between them and a restart does none (docs/reference/commands.md,
"The start-up cache").

The cache lives only in systemd's ``StateDirectory`` (``$STATE_DIRECTORY/cache``),
never at a path from the config; without ``STATE_DIRECTORY`` nothing is cached, except
that ``replay`` keeps its monitors in the user's ``$XDG_CACHE_HOME/safety-supervisor``
(``Cache.open_user``).
An item is ``<key>/<name>`` with a ``<name>.sha256`` beside it.  Both are written
to a temporary file, fsynced and renamed, the digest last, so a start killed
half-way leaves at most an item without its digest, which is never taken for
good.  An item is used only when the directory, the entry and the files are
ours (owned by this user, not writable by group or others, no symbolic links)
and the digest matches; anything else is a miss, and damaged items of ours are
removed so the next build replaces them.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import stat
import sys
from pathlib import Path

from supervisor.files import write_atomic

SUBDIR = "cache"
_KEY = re.compile(r"[0-9a-f]{64}")
_NAME = re.compile(r"[A-Za-z0-9_.-]{1,200}")


def _warn(text: str) -> None:
    print(f"safety-supervisor: WARNING: start-up cache: {text}", file=sys.stderr, flush=True)


def _ours(st: os.stat_result, kind: int) -> bool:
    """Owned by this user, of the expected kind, writable by nobody else."""
    return (
        stat.S_IFMT(st.st_mode) == kind
        and st.st_uid == os.geteuid()
        and not st.st_mode & (stat.S_IWGRP | stat.S_IWOTH)
    )


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class Cache:
    """Items by (key, name) under ``root``; see the module's description."""

    def __init__(self, root: Path) -> None:
        self.root = root

    @classmethod
    def open(cls) -> Cache | None:
        """The cache in ``$STATE_DIRECTORY/cache`` (created, mode 0700), or None when
        there is no state directory or the cache directory is not ours."""
        state = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
        if not state:
            return None
        return cls._made(Path(state), Path(state) / SUBDIR)

    @classmethod
    def open_user(cls) -> Cache | None:
        """``replay``'s cache: the daemon's (``open``) under systemd, else this user's
        ``$XDG_CACHE_HOME/safety-supervisor`` (``~/.cache/safety-supervisor``), with
        the same checks; a path from the environment, never from a config or a bag."""
        if os.environ.get("STATE_DIRECTORY", "").split(":")[0]:
            return cls.open()
        base = os.environ.get("XDG_CACHE_HOME", "")
        # the XDG base directory specification: a relative value is to be ignored
        home = Path(base) if os.path.isabs(base) else Path.home() / ".cache"
        return cls._made(home, home / "safety-supervisor", parents=True)

    @classmethod
    def _made(cls, home: Path, root: Path, parents: bool = False) -> Cache | None:
        """``root`` made (mode 0700) in ``home`` (made too with ``parents``), or None
        with one warning when that fails or ``root`` is not only this user's."""
        try:
            if parents:
                home.mkdir(mode=0o700, parents=True, exist_ok=True)
            with contextlib.suppress(FileExistsError):
                root.mkdir(mode=0o700)
            st = root.lstat()
        except (OSError, RuntimeError) as e:  # RuntimeError: no home directory
            _warn(f"{root}: {getattr(e, 'strerror', None) or e}; not used")
            return None
        if not _ours(st, stat.S_IFDIR):
            _warn(f"{root} is not a directory of this user's that only it can write; not used")
            return None
        return cls(root)

    def _entry(self, key: str, name: str) -> Path:
        if not _KEY.fullmatch(key) or not _NAME.fullmatch(name) or name.endswith(".sha256"):
            raise ValueError(f"bad cache item {key}/{name}")
        return self.root / key / name

    def get(self, key: str, name: str) -> Path | None:
        """The item's path when it is complete, intact and ours; else None (a
        damaged item of ours is removed)."""
        path = self._entry(key, name)
        sidecar = path.with_name(name + ".sha256")
        try:
            if not _ours(path.parent.lstat(), stat.S_IFDIR):
                _warn(f"{path.parent} is not this user's own; not used")
                return None
            st, st_sum = path.lstat(), sidecar.lstat()
        except FileNotFoundError:
            return None
        except OSError as e:
            _warn(f"{path}: {e.strerror}; not used")
            return None
        if not (_ours(st, stat.S_IFREG) and _ours(st_sum, stat.S_IFREG)):
            _warn(f"{path} is not this user's own; not used")
            return None
        try:
            good = sidecar.read_text(encoding="ascii").strip() == _digest(path)
        except (OSError, UnicodeDecodeError):
            good = False
        if good:
            return path
        _warn(f"{path} is damaged; rebuilt")
        for p in (sidecar, path):
            with contextlib.suppress(OSError):
                p.unlink()
        return None

    def read(self, key: str, name: str) -> bytes | None:
        path = self.get(key, name)
        if path is None:
            return None
        try:
            return path.read_bytes()
        except OSError:
            return None

    def put(self, key: str, name: str, data: bytes) -> Path | None:
        """Store ``data`` as the item; its path, or None when it could not be stored
        (said once on stderr: the caller goes on without the cache)."""
        path = self._entry(key, name)
        try:
            with contextlib.suppress(FileExistsError):
                path.parent.mkdir(mode=0o700)
            if not _ours(path.parent.lstat(), stat.S_IFDIR):
                _warn(f"{path.parent} is not this user's own; not stored")
                return None
            write_atomic(path, data)
            write_atomic(
                path.with_name(name + ".sha256"), hashlib.sha256(data).hexdigest().encode()
            )
        except OSError as e:
            _warn(f"{path}: {e.strerror}; not stored")
            return None
        return path
