"""The shipped sRobot config's ``check`` warnings each carry the config's reason
for them (a mitigation's ``expected``, docs/reference/config.md "mitigations"),
so a user starting from it knows they are deliberate; without a reason a warning
is printed as before, and a bad reason is one error line."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SROBOT = ROOT / "supervisor" / "data" / "examples" / "srobot.yaml"


def check(config: Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("SAFETY_SUPERVISOR_DEBUG",)}
    return subprocess.run(
        [sys.executable, "-m", "supervisor", "check", str(config)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )


def warnings(r: subprocess.CompletedProcess[str]) -> list[str]:
    return [line for line in r.stdout.splitlines() if line.startswith("warning: ")]


def test_every_warning_of_the_shipped_srobot_config_says_why_it_is_there() -> None:
    r = check(SROBOT)
    assert r.returncode == 0, r.stdout + r.stderr
    found = warnings(r)
    assert len(found) == 6, found
    own_topic = [w for w in found if "reads its own command" in w]
    ssh = [w for w in found if "mitigation 'power_off': ssh" in w]
    assert len(own_topic) == 4 and len(ssh) == 2, found
    for w in own_topic:
        assert w.endswith(
            "(expected here: the sRobot takes its commands on its state topics "
            "(thesis Tables 5 and 7))"
        ), w
    for w in ssh:
        assert w.endswith(
            "installed on the supervisor's host only " + '(docs/reference/config.md, "ssh"))'
        ), w


def _without_reasons(tmp_path: Path, replace: str = "") -> Path:
    lines = SROBOT.read_text(encoding="utf-8").splitlines(keepends=True)
    kept = [
        (("    expected: " + replace + "\n") if replace else "")
        if line.startswith("    expected: ")
        else line
        for line in lines
    ]
    path = tmp_path / "srobot.yaml"
    path.write_text("".join(kept), encoding="utf-8")
    return path


def test_a_warning_without_a_reason_is_printed_as_it_was(tmp_path: Path) -> None:
    r = check(_without_reasons(tmp_path))
    assert r.returncode == 0, r.stdout + r.stderr
    found = warnings(r)
    assert len(found) == 6 and not [w for w in found if "expected here" in w], found


def test_a_reason_that_is_not_one_line_of_text_is_one_error_line(tmp_path: Path) -> None:
    config = _without_reasons(tmp_path, "{because: [a, b]}")
    r = check(config)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    errors = [line for line in r.stderr.splitlines() if "expected must be one line" in line]
    assert len(errors) == 1 and errors[0].startswith(f"{config}:"), r.stderr
