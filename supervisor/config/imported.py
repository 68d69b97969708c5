"""Reading the files a config names, within bounds, and the type of each field read.

FRET's exports and OGMA's databases come from other tools and other people: each
is read here once, capped in size (a regular file only), checked as UTF-8 and,
for JSON, capped in nesting (monitors/untrusted.py).  The importers then take
each field through :class:`Fields`, which checks its type, so that a wrong one
is one line naming the field and the requirement or variable, never an
exception from deep inside (docs/reference/config.md, "Limits").
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from monitors.untrusted import Untrusted, load_json, printable, read_regular

MB = 1 << 20
# What the files a config names may hold, checked before any parsing
# (docs/reference/config.md, "Limits").  PyYAML builds Python objects at about
# 1 MB/s and 100 bytes per byte read, so the config's cap keeps check within
# seconds; a FRET export of 1,000 requirements is about 7 MB.
MAX_CONFIG_BYTES = 4 * MB
MAX_IMPORT_BYTES = 32 * MB  # a FRET export or an OGMA database
MAX_IMPORT_DEPTH = 64  # JSON nesting; FRET's exports nest 5 levels
# One requirement's FRETISH text, an imported define or formula: a sentence is
# a few hundred characters, and the parser's time and memory grow with it.
MAX_TEXT_CHARS = 10_000
MAX_FORMULA_CHARS = 100_000  # FRET's exported ptLTL, only cross-checked
MAX_ID_CHARS = 128  # a requirement id, which names C functions and log records

_POSITION = re.compile(r"^not JSON \((.*): line (\d+) column (\d+) \(char \d+\)\)$")
C_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def read_bytes(path: Path | str, what: str, max_bytes: int = MAX_IMPORT_BYTES) -> bytes:
    """A regular file of at most ``max_bytes`` (never a FIFO or a device)."""
    try:
        return read_regular(path, max_bytes=max_bytes)
    except Untrusted as e:
        raise UserError(
            f"cannot read {what}: {str(e).removeprefix('cannot open: ')}",
            file=str(path),
            hint=None if "larger" not in str(e) else "docs/reference/config.md, Limits",
        ) from None


class Imports:
    """The files a config imports (``variables_from``, ``requirements_from``), each
    read once per load and kept: a FRET file that gives both variables and
    requirements is one version of it, and the analyses' child process is given
    these bytes, not the paths (docs/ARCHITECTURE.md, "The stages")."""

    def __init__(self, given: dict[str, bytes] | None = None) -> None:
        self._files: dict[str, bytes] = dict(given or {})

    def read(self, path: Path | str, what: str) -> bytes:
        """The file at ``path``: the bytes read before, else read now (bounded)."""
        key = str(path)
        if key not in self._files:
            self._files[key] = read_bytes(path, what)
        return self._files[key]

    def read_named(self, path: Path | str, what: str, where: Any, key: str, name: str) -> None:
        """Reads the file the config names as ``name`` under ``key`` of ``where`` (a
        LineDict): one it cannot read is an error at that key's line of the config,
        where the name was written."""
        try:
            self.read(path, what)
        except UserError as e:
            raise UserError(
                f"{key} '{name}': {e.message}",
                file=getattr(where, "file", "") or str(path),
                line=where.key_line(key),
                hint=e.hint,
            ) from None

    def files(self) -> dict[str, bytes]:
        """Every file read so far, by the path it was read at."""
        return dict(self._files)


def decode(data: bytes, file: str) -> str:
    """``data`` as UTF-8; an invalid byte is an error at its line and offset."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        raise UserError(f"not UTF-8 (byte {e.start})", file=file, line=line) from None


def read_json(
    path: Path | str, what: str, text: str | None = None, imports: Imports | None = None
) -> Any:
    """One JSON document from a file (or its ``text``, read already with
    :func:`read_bytes`), within the import bounds."""
    file = str(path)
    if text is None:
        data = (imports or Imports()).read(path, what)
        text = decode(data, file)
    try:
        return load_json(text, max_bytes=MAX_IMPORT_BYTES, max_depth=MAX_IMPORT_DEPTH)
    except Untrusted as e:
        found = _POSITION.match(str(e))
        if found:
            raise UserError(
                f"invalid JSON: {found[1]}", file=file, line=int(found[2]), col=int(found[3])
            ) from None
        raise UserError(str(e), file=file) from None


def control_at(text: str) -> str | None:
    """Where ``text`` holds a control or invisible format character (anything but
    tab and line breaks), said for an error; None if it holds none.  Such a
    character has no meaning in a sentence or formula, and would reach terminals
    through the parser's messages."""
    if text.isprintable():
        return None
    for i, c in enumerate(text):
        if not c.isprintable() and c not in "\t\n\r":
            return f"a control character ({printable(c)}) at character {i + 1}"
    return None


def kind(value: object) -> str:
    """How an error names what a field holds instead."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return "a number"
    if isinstance(value, str):
        return "text"
    if isinstance(value, list):
        return "a list"
    return "an object"


class Fields:
    """One JSON object of an imported file, read by key with each value's type
    checked.  ``where`` names it in errors (``requirement 'r1'``)."""

    def __init__(self, obj: object, where: str, file: str) -> None:
        if not isinstance(obj, dict):
            raise UserError(f"{where}: must be an object, not {kind(obj)}", file=file)
        self.obj: dict[str, Any] = obj
        self.where = where
        self.file = file

    def error(self, message: str) -> UserError:
        return UserError(f"{self.where}: {message}", file=self.file)

    def text(self, key: str, *, max_chars: int | None = None) -> str | None:
        """A text field; absent or null is None."""
        value = self.obj.get(key)
        if value is None:
            return None
        if not isinstance(value, str):
            raise self.error(f"'{key}' must be text, not {kind(value)}")
        if max_chars is not None and len(value) > max_chars:
            raise self.error(f"'{key}' is longer than {max_chars} characters")
        return value

    def sentence(self, key: str, *, max_chars: int) -> str | None:
        """A text field read by a parser: no control characters either."""
        value = self.text(key, max_chars=max_chars)
        where = control_at(value) if value is not None else None
        if where is not None:
            raise self.error(f"'{key}' holds {where}")
        return value

    def list(self, key: str) -> list[Any]:
        """A list field; absent or null is empty."""
        value = self.obj.get(key)
        if value is None:
            return []
        if not isinstance(value, list):
            raise self.error(f"'{key}' must be a list, not {kind(value)}")
        return value

    def object(self, key: str) -> Fields:
        """An object field; absent or null is an empty one."""
        value = self.obj.get(key)
        if value is not None and not isinstance(value, dict):
            raise self.error(f"'{key}' must be an object, not {kind(value)}")
        return Fields(value or {}, f"{self.where}: '{key}'", self.file)


def top_list(doc: object, key: str, file: str) -> list[Any]:
    """A list field of a file's top-level object."""
    if not isinstance(doc, dict):
        raise UserError(f"must be an object, not {kind(doc)}", file=file)
    value = doc.get(key)
    if value is None:
        return []
    if not isinstance(value, list):
        raise UserError(f"'{key}' must be a list, not {kind(value)}", file=file)
    return value


def named(name: str | None, index: int, what: str) -> str:
    """How errors name the ``index``-th (from 1) entry: by its name when it has one."""
    return f"{what} '{printable(name)}'" if name else f"{what} {index}"


def is_c_identifier(name: str) -> bool:
    return len(name) <= MAX_ID_CHARS and C_IDENTIFIER.fullmatch(name) is not None


def c_identifiers(
    names: list[str], taken: set[str] | frozenset[str] = frozenset()
) -> dict[str, str]:
    """A C identifier for each distinct name (docs/reference/config.md,
    "variables_from and requirements_from"): itself when it is one; else other
    characters as ``_`` (``r_`` before a leading digit), and ``_2``, ``_3`` ...
    after one already given out.  Names that are identifiers keep them whatever
    their order, so the mapping depends only on the names and ``taken``."""
    out = {n: n for n in names if is_c_identifier(n) and n not in taken}
    used = set(taken) | set(out)
    for name in names:
        if name in out:
            continue
        base = re.sub(r"[^A-Za-z0-9_]", "_", name)[: MAX_ID_CHARS - 8]
        if not base or base[0].isdigit():
            base = "r_" + base
        mapped, n = base, 2
        while mapped in used:
            mapped, n = f"{base}_{n}", n + 1
        out[name] = mapped
        used.add(mapped)
    return out
