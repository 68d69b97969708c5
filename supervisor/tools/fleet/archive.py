"""The archive listed: every bag under the given directories and globs, with the robot
that recorded it and a fingerprint of its files that is read from their metadata alone.

A bag is what ``replay`` reads as one: a rosbag2 directory (``metadata.yaml``, or
``.mcap``/``.db3`` files without it, plain or ``.zstd``), or such a file given itself.  A
recording directory of ``run --record`` holds one bag directory per rotation, and each
is a bag here.  The robot is the first directory under the archive root, or what
``--robot-from`` matches.

The archive is untrusted: its names may be any bytes, its links may loop or lead out,
its trees may be deep.  Links to directories are never followed below a root (nor by
a glob's ``**``), a tree deeper than ``MAX_DEPTH`` or a directory that cannot be
listed is an error, and an ARCHIVE that holds no bag is one too: nothing is left out
without a word (docs/reference/commands.md, "fleet replay").
"""

from __future__ import annotations

import fnmatch
import glob
import hashlib
import os
import re
from dataclasses import dataclass
from pathlib import Path

from monitors.errors import UserError
from monitors.untrusted import printable
from supervisor.files import open_regular

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
    ``robot_error``), its files' total size and their fingerprint; ``shape``: a hash
    of its files' names and sizes alone, the same for every copy of it (``copies``)."""

    path: str
    robot: str | None
    robot_error: str | None
    size: int
    fingerprint: str
    shape: str = ""


def list_archive(archives: list[str], robot_from: str | None = None) -> list[BagRef]:
    """The bags of ``archives`` (directories, bag files or globs), each once, sorted by
    path.  An archive that names nothing is an error."""
    rule = robot_rule(robot_from) if robot_from is not None else None
    found: dict[str, BagRef] = {}
    # each bag once by what it is, not how it is reached: an archive and a link to it
    # (or a bind mount) replayed every bag twice, each violation two rows
    seen: dict[tuple[int, int], str] = {}
    for arg in archives:
        roots = _expanded(arg)
        if not roots:
            raise UserError("no such directory, bag or match", file=printable(arg))
        named = 0
        for root, path in roots:
            bags = _bags(path)
            named += len(bags)
            for bag in bags:
                key = os.path.abspath(bag)
                ident = _identity(key)
                if key in found or (ident is not None and ident in seen):
                    continue
                if ident is not None:
                    seen[ident] = key
                if len(found) >= MAX_BAGS:
                    raise UserError(f"more than {MAX_BAGS:,} bags", file=printable(arg))
                found[key] = _ref(key, root, rule)
        if not named:  # a typo, a FIFO, a file of another kind: said, not a run of nothing
            raise UserError(
                "no bag here (a rosbag2 directory, or a .mcap or .db3 file, plain or .zstd)",
                file=printable(arg),
            )
    # a storage file of a bag directory also listed (a glob's ``**`` matches both) is
    # that bag, not a second one
    for key in [k for k in found if os.path.isfile(k)]:
        if _identity(os.path.dirname(key)) in seen:
            del found[key]
    return sorted(found.values(), key=lambda b: b.path)


def _ref(key: str, root: str, rule: RobotRule | None) -> BagRef:
    text = _utf8(key)
    if text is None:  # the dataset's columns are text: the bag's row says why, escaped
        shown = os.fsencode(key).decode("utf-8", "backslashreplace")
        fp = hashlib.sha256(os.fsencode(key)).hexdigest()
        return BagRef(shown, None, "its path is not UTF-8: rename it", 0, fp)
    robot, why = _robot(Path(key), Path(os.path.abspath(root)), rule)
    try:
        size, fp, shape = _stats(Path(key))
    except OSError as e:  # gone or unreadable since it was listed: its row says so
        fp = hashlib.sha256(key.encode()).hexdigest()  # its row's own key
        size, robot, why, shape = 0, None, f"cannot read: {e.strerror or e}", ""
    return BagRef(key, robot, why, size, fp, shape)


def _identity(path: str) -> tuple[int, int] | None:
    try:
        st = os.stat(path)
    except OSError:
        return None  # its row says why it cannot be read
    return st.st_dev, st.st_ino


def _utf8(path: str) -> str | None:
    """``path`` when it is UTF-8 (Python keeps other bytes as lone surrogates)."""
    try:
        path.encode()
    except UnicodeEncodeError:
        return None
    return path


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
        return [(root, m) for m in sorted(_glob(root, Path(arg).parts[len(head) :]))]
    try:
        os.stat(arg)
    except (FileNotFoundError, NotADirectoryError):
        return []
    except OSError as e:  # there, but not for this user (os.path.exists says "no")
        raise UserError(f"cannot read it: {e.strerror}", file=printable(arg)) from None
    return [(arg, arg)]


def _glob(root: str, parts: tuple[str, ...]) -> list[str]:
    """glob.glob's matches of ``root/parts...``, iteratively: a component that is no
    wildcard is a path (a link is followed, as the user wrote it), ``*`` and ``[..]``
    match names in one directory, and ``**`` any depth down to ``MAX_DEPTH`` without
    entering a link (glob.glob walked each path two link loops spell, without end)."""
    out: list[str] = []
    todo: list[tuple[str, int, int]] = [(root, 0, 0)]  # path, next part, depth under **
    while todo:
        path, i, depth = todo.pop()
        if i == len(parts):
            out.append(path)
            if len(out) > MAX_BAGS:
                raise UserError(f"more than {MAX_BAGS:,} matches", file=printable(root))
            continue
        part = parts[i]
        if not glob.has_magic(part):
            child = os.path.join(path, part)
            if os.path.lexists(child):
                todo.append((child, i + 1, depth))
            continue
        if part == "**":
            todo.append((path, i + 1, depth))  # no directory at all
        for name, is_dir, is_link in _names(path):
            if name.startswith(".") and not part.startswith("."):
                continue  # as glob.glob: a wildcard matches no hidden name
            child = os.path.join(path, name)
            if part == "**":
                if is_link:
                    continue  # neither entered nor matched: a link could lead anywhere
                if is_dir:
                    if depth >= MAX_DEPTH:
                        raise _too_deep(child)
                    todo.append((child, i, depth + 1))
                elif i + 1 == len(parts):
                    todo.append((child, i + 1, depth))
            elif fnmatch.fnmatchcase(name, part):
                todo.append((child, i + 1, depth))
    return out


def _names(path: str) -> list[tuple[str, bool, bool]]:
    """The names in the directory ``path``, whether each is a directory itself and
    whether it is a link; nothing when ``path`` is no directory."""
    try:
        with os.scandir(path) as it:
            return [(e.name, e.is_dir(follow_symlinks=False), e.is_symlink()) for e in it]
    except NotADirectoryError:
        return []
    except OSError as e:
        raise UserError(f"cannot list: {e.strerror or e}", file=printable(path)) from None


def _too_deep(path: str | Path) -> UserError:
    return UserError(
        f"directories nested deeper than {MAX_DEPTH} below the archive",
        file=printable(str(path)),
        hint="give a directory nearer the bags as ARCHIVE",
    )


def _is_bag_dir(p: Path) -> bool:
    """A storage file of any kind but a directory makes a bag: a FIFO or a device in a
    bag's place is that bag's row (its task says what it is), not a bag left out."""
    try:
        return (p / "metadata.yaml").is_file() or any(
            c.name.endswith(BAG_FILES) and not c.is_dir() for c in p.iterdir()
        )
    except OSError:
        return False


def _bags(path: str) -> list[Path]:
    p = Path(path)
    if p.is_file():
        return [p] if p.name.endswith(BAG_FILES) else []
    if not p.is_dir():  # a FIFO, a device: no bag (list_archive says so)
        return []
    out: list[Path] = []
    # each directory with the bag above it, if any: a bag's directory is still walked,
    # as a storage file dropped beside a robot's bag directories made that robot's
    # directory one bag, and its bags were left out without a word
    todo: list[tuple[Path, int, Path | None]] = [(p, 0, None)]
    while todo:
        d, depth, above = todo.pop()
        if _is_bag_dir(d):
            if above is not None:
                raise UserError(
                    f"a bag inside the bag {printable(str(above))}: its storage files make "
                    "that directory one bag, and the bags below it would be left out",
                    file=printable(str(d)),
                    hint="move the .mcap/.db3 files (or metadata.yaml) beside the bags' "
                    "directories into a directory of their own",
                )
            out.append(d)
            above = d
        try:
            children = sorted(d.iterdir())
        except OSError as e:  # its bags would be missing without a word
            raise UserError(f"cannot list: {e.strerror or e}", file=printable(str(d))) from None
        for c in children:
            if c.is_symlink():
                continue  # an archive is its own tree: a link could lead anywhere
            if c.is_dir():  # a storage file makes its directory a bag (_is_bag_dir)
                if depth >= MAX_DEPTH:
                    raise _too_deep(c)
                todo.append((c, depth + 1, above))
    return out


MAX_RULE = 256  # characters of a --robot-from rule


@dataclass(frozen=True)
class RobotRule:
    """``--robot-from`` compiled: one pattern per directory of the rule, ``None`` for
    ``**``.  Matched directory by directory (``matches``), never as one regular
    expression over the whole path: that one backtracked through every way its
    ``**`` could split a long path, minutes per bag for ``**x**`` and hostile names."""

    parts: tuple[re.Pattern[str] | None, ...]

    def robot(self, path: str) -> str | None:
        """The robot's name in ``path`` (absolute): the leftmost place where the rule
        matches whole directories, each ``**`` taking as many as it can."""
        names = path.split("/")
        k, n = len(self.parts), len(names)
        # ok[i][j]: the rule's parts from i match the path's names from j on
        ok = [[False] * (n + 1) for _ in range(k)] + [[True] * (n + 1)]
        for i in range(k - 1, -1, -1):
            part, after = self.parts[i], ok[i + 1]
            if part is None:
                later = False
                for j in range(n, -1, -1):
                    later = later or after[j]
                    ok[i][j] = later
            else:
                for j in range(n):
                    ok[i][j] = after[j + 1] and part.fullmatch(names[j]) is not None
        j = next((j for j in range(n + 1) if ok[0][j]), None)
        if j is None:
            return None
        robot = None
        for i, part in enumerate(self.parts):
            if part is None:
                j = max(x for x in range(j, n + 1) if ok[i + 1][x])
                continue
            m = part.fullmatch(names[j])
            assert m is not None  # ok[i][j]
            robot = m.groupdict().get("robot") or robot
            j += 1
        return robot


def robot_rule(rule: str) -> RobotRule:
    """``--robot-from``: a path pattern with ``{robot}`` once (in one directory), ``*``
    (within a directory, one per directory) and ``**`` (a whole directory: any
    depth), matched against the bag's absolute path from a directory on."""
    hint = "for example '/data/{robot}/**' or 'robot-{robot}'"
    if rule.count("{robot}") != 1:
        raise UserError(f"--robot-from {printable(rule)!r} must hold {{robot}} once", hint=hint)
    if len(rule) > MAX_RULE:
        raise UserError(f"--robot-from is longer than {MAX_RULE} characters", hint=hint)
    parts: list[re.Pattern[str] | None] = []
    names = rule.rstrip("/").split("/")
    for n, name in enumerate(names):
        if name == "**":
            parts.append(None)
            continue
        if "**" in name or name.count("*") > 1:
            raise UserError(
                f"--robot-from {printable(rule)!r}: ** is a directory of its own and a "
                "directory holds one * at most",
                hint=hint,
            )
        if not name and n > 0:
            continue  # a doubled slash
        out = []
        for piece in re.split(r"(\{robot\}|\*)", name):
            if piece == "{robot}":
                out.append(r"(?P<robot>.+)")
            elif piece == "*":
                out.append(r".*")
            else:
                out.append(re.escape(piece))
        parts.append(re.compile("".join(out), re.DOTALL))
    return RobotRule(tuple(parts))


def _robot(bag: Path, root: Path, rule: RobotRule | None) -> tuple[str | None, str | None]:
    if rule is not None:
        name = rule.robot(bag.as_posix())
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
    """The files that make up ``bag``, sorted: what its content hash reads.  A link to
    a file is its target's bytes, as replay reads it: two bags of links (git-annex's
    layout) hashed as no files at all were one content, and the second was skipped."""
    if bag.is_file():
        return [bag]
    return sorted(c for c in bag.iterdir() if c.is_file())


def fingerprint(bag: Path) -> tuple[int, str]:
    """The bag's total size and a hash of its path and its files' names, sizes and
    modification times: a finished bag is known again without reading it (as make
    and rsync do); its content hash is what its results are keyed by."""
    total, fp, _ = _stats(bag)
    return total, fp


def _stats(bag: Path) -> tuple[int, str, str]:
    """``fingerprint``, and the bag's shape (``BagRef``), from one stat of each file."""
    h = hashlib.sha256(str(bag).encode() + b"\0")
    shape = hashlib.sha256()
    total = 0
    for f in bag_files(bag):
        st = f.stat()
        total += st.st_size
        # a name's bytes as they are: a file may be named in any encoding
        name = os.fsencode(f.name) + f"\0{st.st_size}\0".encode()
        h.update(name + f"{st.st_mtime_ns}\0".encode())
        shape.update(name)
    return total, h.hexdigest(), shape.hexdigest()


def copies(bags: list[BagRef]) -> dict[str, tuple[str, str]]:
    """Each bag of ``bags`` whose content is that of an earlier one (by path, bags
    whose robot is known): its path -> (that bag's path, the content hash).  Two
    copies of a bag in one run were both replayed, each violation two rows; only
    bags of the same shape are read to compare them (a copy is rare, and a bag's
    files of the same names and sizes as another's rarer still when it is none)."""
    by_shape: dict[str, list[BagRef]] = {}
    for bag in bags:
        if bag.robot is not None and bag.shape:
            by_shape.setdefault(bag.shape, []).append(bag)
    out: dict[str, tuple[str, str]] = {}
    for group in by_shape.values():
        if len(group) < 2:
            continue
        first: dict[str, str] = {}  # content hash -> the first bag's path
        for bag in sorted(group, key=lambda b: b.path):
            try:
                digest = content_hash(Path(bag.path))
            except OSError:
                continue  # its task says why, as for any bag
            if digest in first:
                out[bag.path] = (first[digest], digest)
            else:
                first[digest] = bag.path
    return out


def content_hash(bag: Path) -> str:
    """SHA-256 over the bag's files' names and bytes, in name order."""
    h = hashlib.sha256()
    for f in bag_files(bag):
        h.update(os.fsencode(f.name) + b"\0")
        with open_regular(f) as fh:  # a FIFO put in its place since the listing
            while chunk := fh.read(1 << 20):
                h.update(chunk)
        h.update(b"\0")
    return h.hexdigest()
