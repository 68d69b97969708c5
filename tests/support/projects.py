"""A config's project (parsed, analysed, ready to compile) from its text, written to a
directory of its own: what the core's tests build their sessions from."""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Any

from supervisor.pipeline import project_for


def project_of(d: Path, config: str) -> tuple[Any, Path]:
    """The project of ``config`` (dedented) written to ``d``/c.yaml, and ``d``: the
    monitors the tests compile go below it.  A config that does not check fails here."""
    (d / "c.yaml").write_text(textwrap.dedent(config))
    p = project_for(d / "c.yaml", ros=False)
    assert p.ok, p.first_error()
    return p, d
