"""SAFETY_SUPERVISOR_REQUIRE_<KIND>=1 turns a skip of that kind into a failure
(tests/conftest.py), wherever the skip happens: a skipif marker, pytest.skip in a
fixture or a test, a module skipped while it is collected.  Run here by a real pytest
on a test file written for it, with this suite's conftest.py."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent

SKIPPING = """
import os
import pytest

@pytest.mark.skipif(True, reason="giving a file to another user needs root")
def test_root_marker():
    pass

@pytest.fixture
def traced():
    pytest.skip("strace cannot trace here: ptrace: Operation not permitted")

def test_strace_fixture(traced):
    pass

def test_unrelated():
    pytest.skip("this libc exports no 'step'")

def test_tool():
    pytest.skip("logrotate missing (install Debian's logrotate)")

def test_ray():
    pytest.skip("ray is not installed (pip install 'safety-supervisor[fleet]')")
"""

MODULE_SKIP = """
import pytest

pytest.importorskip("rclpy_that_is_not_there", reason="rclpy is not installed")

def test_never():
    pass
"""


def run(tmp_path: Path, **require: str) -> str:
    shutil.copy(TESTS / "conftest.py", tmp_path / "conftest.py")
    (tmp_path / "test_skipping.py").write_text(SKIPPING)
    (tmp_path / "test_module_skip.py").write_text(MODULE_SKIP)
    env = {k: v for k, v in os.environ.items() if not k.startswith("SAFETY_SUPERVISOR_REQUIRE_")}
    env.update({f"SAFETY_SUPERVISOR_REQUIRE_{k}": v for k, v in require.items()})
    env["PYTHONPATH"] = str(TESTS / "support")
    r = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-rA", "-p", "no:cacheprovider"]
        + ["--continue-on-collection-errors", str(tmp_path)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    return r.stdout + r.stderr


def test_without_the_variables_every_skip_stays_a_skip(tmp_path: Path) -> None:
    out = run(tmp_path)
    assert "6 skipped" in out and "failed" not in out and "error" not in out, out


@pytest.mark.parametrize(
    ("kind", "test", "said"),
    [
        ("ROOT", "test_skipping.py::test_root_marker", "needs root"),
        ("STRACE", "test_skipping.py::test_strace_fixture", "strace cannot trace here"),
        ("ROS", "test_module_skip.py", "rclpy is not installed"),
        ("TOOLS", "test_skipping.py::test_tool", "logrotate missing"),
        ("RAY", "test_skipping.py::test_ray", "ray is not installed"),
    ],
)
def test_a_required_kind_fails_and_says_why(
    tmp_path: Path, kind: str, test: str, said: str
) -> None:
    out = run(tmp_path, **{kind: "1"})
    failures = [line for line in out.splitlines() if line.startswith(("ERROR ", "FAILED "))]
    # only the skip of that kind fails: the other kinds and the unrelated skip stay skips
    assert len(failures) == 1 and test in failures[0], out
    assert f"SAFETY_SUPERVISOR_REQUIRE_{kind}=1 but the test skipped: " in out, out
    assert said in out, out
    assert "5 skipped" in out, out
