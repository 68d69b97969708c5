"""The monitors of the shipped configs are as hard real-time as any other: the config
is read by the application (supervisor.pipeline), the C judged as the compiler's own
tests judge it (tests/monitors/backends/test_c99.py)."""

from __future__ import annotations

from pathlib import Path

from supervisor.pipeline import project_for
from tests.monitors.backends.test_c99 import assert_hard_real_time_c

ROOT = Path(__file__).resolve().parents[2]


def test_mobile_base_c_is_loop_free_strict_c99(tmp_path: Path) -> None:
    # mobile-base: reductions, ages, rates, events and goal states are read before
    # the monitor; its C (hypot included) stays as hard real-time as any other
    project = project_for(ROOT / "config" / "mobile-base.yaml")
    assert project.ok, project.first_error()
    assert_hard_real_time_c(project.spec(), tmp_path)
