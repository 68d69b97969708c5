"""``run``'s stderr: every warning once.

The log echoes each record on stderr (or sends it to the journal,
docs/reference/log.md), so a warning that is a record is not printed a second
time.  A real ``safety-supervisor run`` of the sRobot example, whose shipped
config has ``check`` warnings and whose inputs have no publisher yet.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest


@pytest.mark.ros
def test_run_prints_each_warning_once(tmp_path: Path) -> None:
    from rosutil import Daemon

    d = Daemon(tmp_path)
    try:
        d.wait_notify("READY=1", timeout=60)
        d.terminate()
    finally:
        d.close()
    records = d.records()
    warnings = [r["detail"] for r in records if r.get("what") == "check_warning"]
    silent = [r["topic"] for r in records if r.get("what") == "input_no_publisher"]
    assert warnings and silent, d.explain()  # the example has both kinds
    lines = d.stderr.read_text().splitlines()
    for text in warnings:
        assert sum(text in line for line in lines) == 1, (text, lines)
    for topic in silent:
        said = [line for line in lines if "publisher" in line and topic in line]
        assert len(said) == 1, (topic, said)
    repeated = [line for line, n in Counter(lines).items() if n > 1]
    assert not repeated, repeated
