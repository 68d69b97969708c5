"""supervisor.children.run: a short-lived child started the one way (environment,
process group, parent-death signal), with subprocess.run's answer."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from supervisor import children


def test_run_answers_like_subprocess_run(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NOTIFY_SOCKET", "/run/systemd/notify")  # meant for this process
    code = "import os, sys; print(os.environ.get('NOTIFY_SOCKET')); print('err', file=sys.stderr); sys.exit(3)"
    r = children.run([sys.executable, "-c", code], env=children.child_env(), timeout=60)
    assert (r.returncode, r.stdout, r.stderr) == (3, "None\n", "err\n")


def test_run_in_its_own_process_group() -> None:
    code = "import os; print(os.getpgid(0) == os.getpid())"
    r = children.run([sys.executable, "-c", code], env=children.child_env(), timeout=60)
    assert r.stdout == "True\n", r


def test_a_timeout_kills_what_the_child_started(tmp_path: Path) -> None:
    pidfile = tmp_path / "grandchild.pid"
    code = (
        "import subprocess, sys, time\n"
        # Not on the pipes: run() must not merely wait for them to close.
        "p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(120)'],\n"
        "                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)\n"
        f"open({str(pidfile)!r}, 'w').write(str(p.pid))\n"
        "time.sleep(120)\n"
    )
    with pytest.raises(subprocess.TimeoutExpired):
        children.run([sys.executable, "-c", code], env=children.child_env(), timeout=3)
    grandchild = int(pidfile.read_text())
    deadline = time.monotonic() + 10
    while _alive(grandchild) and time.monotonic() < deadline:
        time.sleep(0.05)  # polling the kernel's process table: no event to await
    assert not _alive(grandchild), "the child's own child outlived the timeout"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = Path(f"/proc/{pid}/stat").read_text()
    return stat.split(")")[-1].split()[0] != "Z"  # a zombie waits for its parent only
