"""The daemon holds its config's start-up cache entry while that config is in force
(supervisor/daemon/process.py, supervisor/cache.py): ``check`` of other configs
prunes old entries around it, never it, however long ago it was read.

ROS tier: a real ``safety-supervisor run`` with a STATE_DIRECTORY and a NOTIFY_SOCKET
bound by the test; the real ``check`` beside it with the same state directory, as
ExecStartPre and a reload share it under systemd.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from supervisor import cache

pytestmark = pytest.mark.ros
pytest.importorskip("rclpy")

from rosutil import SROBOT, Daemon  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]


def _check(config: Path, state: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "SAFETY_SUPERVISOR_DEBUG"}
    env["STATE_DIRECTORY"] = str(state)
    r = subprocess.run(
        [sys.executable, "-m", "supervisor", "check", str(config)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
        cwd=ROOT,
    )
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stdout + r.stderr


def _age(path: Path, seconds: float) -> None:
    t = time.time() - seconds
    os.utime(path, (t, t))


def test_the_entry_in_force_is_not_pruned_while_the_daemon_runs(tmp_path: Path) -> None:
    state = tmp_path / "state"
    state.mkdir()
    config = tmp_path / "supervisor.yaml"
    shutil.copyfile(SROBOT, config)
    d = Daemon(tmp_path, config, env={"STATE_DIRECTORY": str(state)})
    try:
        d.wait_notify("READY=1", timeout=120)
        (entry,) = (p for p in (state / "cache").iterdir() if p.is_dir())
        # Started weeks ago; more than KEEP configs were checked since, long ago.
        for i in range(cache.KEEP + 2):
            copy = entry.with_name(hashlib.sha256(f"older {i}".encode()).hexdigest())
            shutil.copytree(entry, copy)
            _age(copy, 2 * cache.GRACE_S + 60 * i)
        _age(entry, 30 * 86400)
        other = tmp_path / "next.yaml"
        other.write_text(config.read_text() + "# the next config, checked beside the daemon\n")
        _check(other, state)
        kept = {p.name for p in (state / "cache").iterdir() if p.is_dir()}
        assert entry.name in kept, "the daemon's entry was pruned while it ran"
        assert len(kept) == cache.KEEP + 1, sorted(kept)
        d.terminate()
    finally:
        d.close()
    # The daemon stopped: its entry is the oldest, and held by nobody.
    _age(entry, 30 * 86400)
    other.write_text(other.read_text() + "# and one more\n")
    _check(other, state)
    assert not entry.exists()
