"""``python -m supervisor.tools.bench.monitor``: its margins rows run the sRobot monitor
with margins on beside the boolean one (numbers printed, never asserted)."""

from __future__ import annotations

import re

import pytest

from supervisor.tools.bench.monitor import main


def test_margins_rows_compare_the_margin_monitor_with_the_boolean_one(
    capsys: pytest.CaptureFixture[str],
) -> None:
    main(["--backend", "native", "--ticks", "300"])
    out = capsys.readouterr().out
    assert "native, margins on: " in out
    assert "104 bytes of margin state, 0 of 13 requirements with a window kept boolean" in out
    for row in ("tick", r"tick \+ margins\(\)"):
        assert len(re.findall(rf"\n +{row} +\d+ ns, \d+\.\d\dx the boolean tick", out)) == 2
    assert re.search(r"C step alone \(tick_batch of 10000 rows\): \d+ ns/tick boolean", out)
