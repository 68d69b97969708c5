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
good.  A writer holds the item's lock file (``<name>.lock``) exclusively over both
writes and a reader shares it while it checks the digest, so two processes building
one item at once (their bytes may differ: gcc in two build directories) never make a
reader take the pair for damaged.  An item is used only when the directory, the entry and the files are
ours (owned by this user, not writable by group or others, no symbolic links)
and the digest matches; anything else is a miss, and damaged items of ours are
removed so the next build replaces them.

Entries are pruned so a config edited daily does not fill the disk (reference
commands.md, "The start-up cache"): when a process adds an entry it removes the
others beyond the ``KEEP`` most recently used, except those used in the last
``GRACE_S`` seconds and those another process holds.  "Used" is the entry
directory's mtime, touched on every read and write (atime is not kept on
``noatime``/``relatime`` mounts).  A process holds each entry it reads or writes
with a shared ``flock`` on the entry's directory until it closes the cache (the
daemon: until its session ends); the pruner takes the exclusive lock without
waiting, looks at the mtime again under it, and renames the entry out of the way
before deleting it, so a reader sees the whole entry or none (a miss: rebuilt).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import os
import re
import shutil
import stat
import sys
import time
import weakref
from collections.abc import Iterator
from pathlib import Path

from supervisor.files import remove_whole, write_atomic

SUBDIR = "cache"
_KEY = re.compile(r"[0-9a-f]{64}")
_NAME = re.compile(r"[A-Za-z0-9_.-]{1,200}")
# Pruning (see the module's description): the entries kept however old, and the
# age under which an entry is never removed (a process may be about to read it).
KEEP = 8
GRACE_S = 600.0
# An entry being deleted: renamed to this prefix first (a name no key matches).
_PRUNED = ".pruned-"
# beside an item: its digest, and the lock its writers and checkers take
_SIDES = (".sha256", ".lock")


_said: set[str] = set()  # each warning once per process
_quiet = False


def quiet() -> None:
    """No warning from this process: a fleet replay's workers, whose command says
    the cache's warnings once for all of them (fleet/command.py)."""
    global _quiet
    _quiet = True


def _warn(text: str) -> None:
    if _quiet or text in _said:
        return
    _said.add(text)
    # stderr on a full disk: the warning is lost, the command goes on
    with contextlib.suppress(OSError):
        print(f"safety-supervisor: WARNING: start-up cache: {text}", file=sys.stderr, flush=True)


def _ours(st: os.stat_result, kind: int) -> bool:
    """Owned by this user, of the expected kind, writable by nobody else."""
    return (
        stat.S_IFMT(st.st_mode) == kind
        and st.st_uid == os.geteuid()
        and not st.st_mode & (stat.S_IWGRP | stat.S_IWOTH)
    )


def _open_dir(path: Path) -> int:
    """A descriptor of the directory ``path`` itself (never a symbolic link's target)."""
    return os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)


def _close_all(held: dict[str, int]) -> None:
    for fd in held.values():
        with contextlib.suppress(OSError):
            os.close(fd)  # releases its shared lock
    held.clear()


@contextlib.contextmanager
def _locked(item: Path, how: int) -> Iterator[None]:
    """The item's lock file (made on first use, never a symbolic link) held ``how``;
    a checker that cannot make or lock it (read-only media, a full disk, a quota, a
    filesystem without locks) reads without it: the digest still guards the item."""
    fd: int | None = None
    try:
        fd = os.open(
            item.with_name(item.name + ".lock"), os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o600
        )
        fcntl.flock(fd, how)
    except OSError:
        if how != fcntl.LOCK_SH:
            if fd is not None:
                os.close(fd)
            raise
    try:
        yield
    finally:
        if fd is not None:
            os.close(fd)


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
        # The entries this cache read or wrote, each a directory descriptor with a
        # shared lock: no other process prunes them while this one may use them.
        self._held: dict[str, int] = {}
        self._close = weakref.finalize(self, _close_all, self._held)

    def close(self) -> None:
        """Release the entries this cache holds (also when it is garbage)."""
        self._close()

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
        if not _KEY.fullmatch(key) or not _NAME.fullmatch(name) or name.endswith(_SIDES):
            raise ValueError(f"bad cache item {key}/{name}")
        return self.root / key / name

    def get(self, key: str, name: str) -> Path | None:
        """The item's path when it is complete, intact and ours; else None (a
        damaged item of ours is removed)."""
        path = self._entry(key, name)
        try:
            if not self._hold(key):
                _warn(f"{path.parent} is not this user's own; not used")
                return None
            with _locked(path, fcntl.LOCK_SH):
                return self._checked(path)
        except FileNotFoundError:
            return None
        except OSError as e:
            _warn(f"{path}: {e.strerror}; not used")
            return None

    def _checked(self, path: Path) -> Path | None:
        """``get`` under the item's lock: no ``put`` is between its item and digest."""
        sidecar = path.with_name(path.name + ".sha256")
        st, st_sum = path.lstat(), sidecar.lstat()
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
        created = False
        try:
            with contextlib.suppress(FileExistsError):
                path.parent.mkdir(mode=0o700)
                created = True
            if not self._hold(key):
                _warn(f"{path.parent} is not this user's own; not stored")
                return None
            # two builders of one item may differ in bytes (gcc in two build
            # directories): each writes its item and digest as one, under the lock
            with _locked(path, fcntl.LOCK_EX):
                write_atomic(path, data)
                write_atomic(
                    path.with_name(name + ".sha256"), hashlib.sha256(data).hexdigest().encode()
                )
        except OSError as e:
            _warn(f"{path}: {e.strerror}; not stored")
            return None
        if created:  # the cache grew: only then can it need pruning
            self.prune()
        return path

    def _hold(self, key: str) -> bool:
        """Hold the entry ``key`` (a shared lock until :meth:`close`) and stamp it
        used; False when it is not a directory only this user can write, and
        FileNotFoundError when there is none (or it was pruned meanwhile)."""
        fd = self._held.get(key)
        if fd is None:
            entry = self.root / key
            try:
                fd = _open_dir(entry)
            except FileNotFoundError:
                raise
            except OSError:  # ELOOP (a symbolic link), ENOTDIR, EACCES (another user's)
                return False
            try:
                # Waits only while a pruner holds it: its check and rename.
                fcntl.flock(fd, fcntl.LOCK_SH)
                st = os.fstat(fd)
                try:
                    now = entry.lstat()
                except FileNotFoundError:
                    now = None
                if now is None or (now.st_dev, now.st_ino) != (st.st_dev, st.st_ino):
                    # pruned while we waited
                    raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), str(entry))
                if not _ours(st, stat.S_IFDIR):
                    os.close(fd)
                    return False
            except BaseException:
                with contextlib.suppress(OSError):
                    os.close(fd)
                raise
            self._held[key] = fd
        # Last used: now.  Best effort: on a read-only cache nothing prunes either.
        with contextlib.suppress(OSError):
            os.utime(fd)
        return True

    def prune(self) -> list[str]:
        """Remove the entries beyond the ``KEEP`` most recently used that were last
        used over ``GRACE_S`` ago and that no process holds (this one's never);
        the keys removed."""
        now = time.time()
        entries: list[tuple[float, str]] = []
        try:
            with os.scandir(self.root) as it:
                for d in it:
                    with contextlib.suppress(OSError):
                        st = d.stat(follow_symlinks=False)
                        if not _ours(st, stat.S_IFDIR):
                            continue
                        if _KEY.fullmatch(d.name):
                            entries.append((st.st_mtime, d.name))
                        elif d.name.startswith(_PRUNED):  # a pruner that died half-way
                            shutil.rmtree(d.path, ignore_errors=True)
        except OSError as e:
            _warn(f"{self.root}: {e.strerror}; not pruned")
            return []
        entries.sort(reverse=True)
        removed = []
        for used, key in entries[KEEP:]:
            if key not in self._held and now - used >= GRACE_S and self._remove(key):
                removed.append(key)
        return removed

    def _remove(self, key: str) -> bool:
        """Remove the entry ``key`` when no process holds it and it is still unused
        for ``GRACE_S``; True when removed."""
        entry = self.root / key
        try:
            fd = _open_dir(entry)
        except OSError:
            return False
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            st, now = os.fstat(fd), entry.lstat()
            if (now.st_dev, now.st_ino) != (st.st_dev, st.st_ino):
                return False  # another pruner's, already gone
            if not _ours(st, stat.S_IFDIR) or time.time() - st.st_mtime < GRACE_S:
                return False  # used since it was listed
            # Under the lock: a reader waiting for it finds no entry (a miss)
            # instead of half of one.
            remove_whole(entry, self.root / f"{_PRUNED}{key}.{os.getpid()}")
        except OSError:  # BlockingIOError: held by another process
            return False
        finally:
            os.close(fd)
        return True
