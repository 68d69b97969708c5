"""The archive listed: every bag under the given directories and globs, with the robot
that recorded it and a fingerprint of its files that is read from their metadata alone.

A bag is what ``replay`` reads as one: a rosbag2 directory (``metadata.yaml``, or
``.mcap``/``.db3`` files without it, plain or ``.zstd``), or such a file given itself.  A
recording directory of ``run --record`` holds one bag directory per rotation, and each
is a bag here.  The robot is the first directory under the archive root, or what
``--robot-from`` matches.
"""

from __future__ import annotations

import glob
import hashlib
import os
import re
from dataclasses import dataclass
from pathlib import Path

from monitors.errors import UserError
from monitors.untrusted import printable

# a storage file, plain or compressed per file as rosbag2's zstd compressor writes it
BAG_FILES = (".mcap", ".db3", ".mcap.zstd", ".db3.zstd")
# The robot's name becomes a partition directory (robot=NAME): a path component of
# plain characters, never one that climbs or nests (docs/reference/commands.md).
ROBOT = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
MAX_DEPTH = 16  # directories below an archive root: a loop of mounts ends here
MAX_BAGS = 1_000_000


@dataclass(frozen=True)
class BagRef:
    """One bag of the archive: its path, the robot (None with the reason in
    ``robot_error``), its files' total size and their fingerprint."""

    path: str
    robot: str | None
    robot_error: str | None
    size: int
    fingerprint: str


def list_archive(archives: list[str], robot_from: str | None = None) -> list[BagRef]:
    """The bags of ``archives`` (directories, bag files or globs), each once, sorted by
    path.  An archive that names nothing is an error."""
    rule = robot_rule(robot_from) if robot_from is not None else None
    found: dict[str, BagRef] = {}
    for arg in archives:
        roots = _expanded(arg)
        if not roots:
            raise UserError("no such directory, bag or match", file=printable(arg))
        for root, path in roots:
            for bag in _bags(path):
                key = os.path.abspath(bag)
                if key in found:
                    continue
                if len(found) >= MAX_BAGS:
                    raise UserError(f"more than {MAX_BAGS:,} bags", file=printable(arg))
                robot, why = _robot(Path(key), Path(os.path.abspath(root)), rule)
                try:
                    size, fp = fingerprint(Path(key))
                except OSError as e:  # gone or unreadable since it was listed: its row says so
                    fp = hashlib.sha256(key.encode()).hexdigest()  # its row's own key
                    size, robot, why = 0, None, f"cannot read: {e.strerror or e}"
                found[key] = BagRef(key, robot, why, size, fp)
    return [found[k] for k in sorted(found)]


def _expanded(arg: str) -> list[tuple[str, str]]:
    """(archive root, path) for each path ``arg`` names: itself, or a glob's matches
    with the part before the first wildcard as their root."""
    if glob.has_magic(arg):
        head = []
        for part in Path(arg).parts:
            if glob.has_magic(part):
                break
            head.append(part)
        root = str(Path(*head)) if head else "."
        return [(root, m) for m in sorted(glob.glob(arg, recursive=True))]
    return [(arg, arg)] if os.path.exists(arg) else []


def _is_bag_dir(p: Path) -> bool:
    try:
        return (p / "metadata.yaml").is_file() or any(
            c.name.endswith(BAG_FILES) and c.is_file() for c in p.iterdir()
        )
    except OSError:
        return False


def _bags(path: str) -> list[Path]:
    p = Path(path)
    if p.is_file():
        return [p] if p.name.endswith(BAG_FILES) else []
    out: list[Path] = []
    todo = [(p, 0)]
    while todo:
        d, depth = todo.pop()
        if _is_bag_dir(d):
            out.append(d)
            continue
        if depth >= MAX_DEPTH:
            continue
        try:
            children = sorted(d.iterdir())
        except OSError:
            continue
        for c in children:
            if c.is_symlink():
                continue  # an archive is its own tree: a link could lead anywhere
            if c.is_dir():  # a storage file makes its directory a bag (_is_bag_dir)
                todo.append((c, depth + 1))
    return out


def robot_rule(rule: str) -> re.Pattern[str]:
    """``--robot-from``: a path pattern with ``{robot}`` once (one path component),
    ``*`` (within a component) and ``**`` (any depth), matched against the bag's
    absolute path, starting at a component."""
    if rule.count("{robot}") != 1:
        raise UserError(
            f"--robot-from {printable(rule)!r} must hold {{robot}} once",
            hint="for example '/data/{robot}/**' or 'robot-{robot}'",
        )
    out = []
    for piece in re.split(r"(\{robot\}|\*\*|\*)", rule):
        if piece == "{robot}":
            out.append(r"(?P<robot>[^/]+)")
        elif piece == "**":
            out.append(r".*")
        elif piece == "*":
            out.append(r"[^/]*")
        else:
            out.append(re.escape(piece))
    return re.compile(r"(?:^|/)" + "".join(out) + r"(?:/|$)")


def _robot(bag: Path, root: Path, rule: re.Pattern[str] | None) -> tuple[str | None, str | None]:
    if rule is not None:
        m = rule.search(bag.as_posix())
        name = m.group("robot") if m else None
        if name is None:
            return None, "--robot-from does not match its path"
    else:
        try:
            rel = bag.relative_to(root).parts
        except ValueError:
            rel = ()
        # a bag given directly, or at the archive root itself: the directory it is in
        name = rel[0] if len(rel) > 1 else (root.name if root != bag else bag.parent.name)
    if not ROBOT.fullmatch(name):
        return (
            None,
            f"robot name {printable(name)!r} is not a plain name ([A-Za-z0-9_.-], 64 at most)",
        )
    return name, None


def bag_files(bag: Path) -> list[Path]:
    """The files that make up ``bag``, sorted: what its content hash reads."""
    if bag.is_file():
        return [bag]
    return sorted(c for c in bag.iterdir() if c.is_file() and not c.is_symlink())


def fingerprint(bag: Path) -> tuple[int, str]:
    """The bag's total size and a hash of its path and its files' names, sizes and
    modification times: a finished bag is known again without reading it (as make
    and rsync do); its content hash is what its results are keyed by."""
    h = hashlib.sha256(str(bag).encode() + b"\0")
    total = 0
    for f in bag_files(bag):
        st = f.stat()
        total += st.st_size
        h.update(f"{f.name}\0{st.st_size}\0{st.st_mtime_ns}\0".encode())
    return total, h.hexdigest()


def content_hash(bag: Path) -> str:
    """SHA-256 over the bag's files' names and bytes, in name order."""
    h = hashlib.sha256()
    for f in bag_files(bag):
        h.update(f.name.encode() + b"\0")
        with f.open("rb") as fh:
            while chunk := fh.read(1 << 20):
                h.update(chunk)
        h.update(b"\0")
    return h.hexdigest()
