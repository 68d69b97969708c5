"""The ``step:`` section's ``margins`` key (supervisor/config/step.py): off by default,
``true`` or a boolean atom's margin, one located line for anything else, and the
monitor spec the pipeline builds from it (docs/reference/margins.md)."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import pytest

from monitors.errors import UserError
from supervisor.config import load_config
from supervisor.pipeline import build_project

CONFIG = """\
component: sw
step: {{policy: periodic, period_ms: 100{margins}}}
variables:
  d: {{type: double, topic: /d, msg: std_msgs/msg/Float64}}
requirements:
  - id: r1
    text: sw shall always satisfy d > 0.5
"""


def spec_of(tmp_path: Path, margins: str) -> object:
    path = tmp_path / "c.yaml"
    path.write_text(textwrap.dedent(CONFIG.format(margins=margins)))
    return build_project(load_config(path), ros=False).spec()


@pytest.mark.parametrize(
    ("margins", "on", "bool_margin"),
    [("", False, math.inf), (", margins: false", False, math.inf),
     (", margins: true", True, math.inf), (", margins: 2", True, 2.0)],
)  # fmt: skip
def test_margins_key_turns_the_monitors_margins_on(tmp_path, margins, on, bool_margin) -> None:
    spec = spec_of(tmp_path, margins)
    assert (spec.margins, spec.bool_margin) == (on, bool_margin)


@pytest.mark.parametrize("value", ["0", "-1", "yes please", "[1]"])
def test_a_bad_margins_value_is_one_line_at_its_line(tmp_path, value) -> None:
    with pytest.raises(UserError) as e:
        spec_of(tmp_path, f", margins: {value}")
    assert e.value.line == 2
    assert "step.margins must be" in str(e.value) and "\n" not in str(e.value)
