"""A recording directory, as ``demo --record DIR`` leaves it: the config the run used
(one ``*.yaml``), its violation log (``*.jsonl``, rotated ones too) and the bags of
``run --record`` (one directory per bag).  ``logs DIR``, ``report DIR`` and ``replay
DIR`` find its parts here, and refuse an ambiguous or incomplete directory in one
line (docs/reference/commands.md, "Recording directories").
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from monitors.errors import UserError

_CONFIG = re.compile(r".+\.ya?ml")
# violations.jsonl, and logrotate's violations.jsonl.1, violations.jsonl.2.gz
_LOG = re.compile(r"(?P<base>.+\.jsonl)(?:\.\d+)?(?:\.gz)?")
_STORAGE = (".mcap", ".db3", ".mcap.zstd", ".db3.zstd")


@dataclass(frozen=True)
class RecordingDir:
    path: Path
    config: Path | None
    logs: list[Path]  # one log, its rotated files with it
    bags: list[Path]


def is_bag(path: Path) -> bool:
    """A rosbag2 bag directory (its metadata, or storage files directly in it)."""
    try:
        return (path / "metadata.yaml").is_file() or any(
            f.name.endswith(_STORAGE) for f in path.iterdir() if f.is_file()
        )
    except OSError:  # a directory this user cannot list holds nothing it can read
        return False


def is_recording_dir(path: str | Path) -> bool:
    """A directory that is not itself a bag (replay reads a bag directory as one)."""
    p = Path(path)
    return p.is_dir() and not is_bag(p)


def recording_dir(
    path: str | Path, *, log: bool = False, config: bool = False, bag: bool = False
) -> RecordingDir:
    """The parts of the recording directory ``path``; ``log``/``config``/``bag``: the caller
    needs that part (else a UserError at ``path``: incomplete).  Two configs, or two
    logs that are not one log's rotations, are ambiguous: a UserError too."""
    p = Path(path)
    try:
        entries = sorted(p.iterdir())
    except OSError as e:
        raise UserError(f"cannot read recording directory: {e.strerror or e}", file=str(p)) from e
    configs = [f for f in entries if f.is_file() and _CONFIG.fullmatch(f.name)]
    logs = [f for f in entries if f.is_file() and _LOG.fullmatch(f.name)]
    bags = [d for d in entries if d.is_dir() and is_bag(d)]
    if len(configs) > 1:
        names = ", ".join(f.name for f in configs)
        raise UserError(
            f"ambiguous recording directory: {len(configs)} configs ({names})",
            file=str(p),
            hint="keep the one the run used, or name the files instead of the directory",
        )
    bases = sorted({m.group("base") for f in logs if (m := _LOG.fullmatch(f.name))})
    if len(bases) > 1:
        raise UserError(
            f"ambiguous recording directory: {len(bases)} violation logs ({', '.join(bases)})",
            file=str(p),
            hint="keep one log (and its rotated files), or name the files instead",
        )
    missing = [
        what
        for what, need, have in (
            ("no config (*.yaml)", config, configs),
            ("no violation log (*.jsonl)", log, logs),
            ("no bag (run --record's directories)", bag, bags),
        )
        if need and not have
    ]
    if not bags and not logs and not configs:
        missing = ["no config, violation log or bag"]
    if missing:
        raise UserError(
            f"incomplete recording directory: {'; '.join(missing)}",
            file=str(p),
            hint="demo --record DIR keeps the config, the log and the bags in DIR",
        )
    return RecordingDir(p, configs[0] if configs else None, logs, bags)
