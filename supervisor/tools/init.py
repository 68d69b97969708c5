"""``safety-supervisor init [DIR]``: start a configuration from the shipped examples.

Writes ``srobot.yaml`` (the thesis's robot, complete; it imports no other file)
and ``template.yaml`` (every section and key, one comment each) into DIR, both
passing ``check`` as written.  An existing file is never overwritten unless
``--force`` is given: nothing is written then, and the error names the file.
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from supervisor import data

# (file name, what it is) in the order they are written and listed.
FILES = (
    ("srobot.yaml", "the sRobot example (the thesis's robot), complete"),
    ("template.yaml", "every section and key with a comment, to edit for your robot"),
)


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "init", help="write the sRobot example config and a commented template into DIR"
    )
    p.add_argument("dir", nargs="?", default=".", metavar="DIR", help="default: this directory")
    p.add_argument("--force", action="store_true", help="overwrite files that exist")


def init(target: Path, *, force: bool = False) -> list[Path]:
    """Copy the files into ``target`` (created if missing); the paths written."""
    if target.exists() and not target.is_dir():
        raise UserError("not a directory", file=str(target))
    dests = [target / name for name, _ in FILES]
    if not force:
        for dest in dests:
            if dest.exists():
                raise UserError(
                    "exists, not overwritten", file=str(dest), hint="--force overwrites it"
                )
    try:
        target.mkdir(parents=True, exist_ok=True)
        for (name, _), dest in zip(FILES, dests, strict=True):
            dest.write_bytes(data.example(name).read_bytes())
    except OSError as e:
        raise UserError(f"cannot write: {e.strerror or e}", file=str(e.filename or target)) from e
    return dests


def cmd_init(args: argparse.Namespace) -> int:
    written = init(Path(args.dir), force=args.force)
    for (_, what), path in zip(FILES, written, strict=True):
        print(f"wrote {path}: {what}", flush=True)
    template = shlex.quote(str(written[-1]))
    print(
        f"next: edit {template} for your robot, then: safety-supervisor check {template}",
        flush=True,
    )
    return 0
