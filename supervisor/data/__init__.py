"""Files the commands ship and read: example configs, the systemd unit, the logrotate snippet.

They are package data, found with importlib.resources, so ``demo``, ``init``,
``check`` on the examples and ``install-service`` work from a wheel as from a
checkout (where ``config/`` and ``packaging/`` link here).  The package must be
installed unzipped (pip always does): callers get real paths.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

UNIT_NAME = "safety-supervisor.service"
LOGROTATE_NAME = "safety-supervisor"


def _path(*parts: str) -> Path:
    return Path(str(files(__name__).joinpath(*parts)))


def example(name: str = "srobot.yaml") -> Path:
    """A shipped example: ``srobot.yaml`` (the thesis's robot), ``srobot-from-fret.yaml``
    (the same from FRET/OGMA files) and the files they import."""
    return _path("examples", name)


def systemd_unit() -> Path:
    return _path("systemd", UNIT_NAME)


def logrotate_snippet() -> Path:
    return _path("logrotate", LOGROTATE_NAME)
