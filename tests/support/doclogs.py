"""The violation logs docs/reference/log.md's examples read, made with the product:

- ``violations.jsonl.1`` and ``violations.jsonl``: the demo's daemon, its log rotated
  the way the shipped logrotate snippet does it (rename, then SIGUSR1 to the running
  daemon; docs/reference/log.md, "Rotation");
- ``disk-full/violations.jsonl``: the writer the daemon uses, its file unable to grow
  for a while (RLIMIT_FSIZE: the kernel fails the writes as a full disk does), then
  able again, so the records dropped meanwhile are named by a ``records_lost`` record;
- ``rewritten/violations.jsonl``: the rotated file with its line 3 removed and the
  hashes after it recomputed (the chain has no key: anyone can do this).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

from logcraft import chain
from rosutil import wait_until

# Run in a child: RLIMIT_FSIZE is per process, and the test's own files must grow.
_DISK_FULL = """
import os, resource, sys
from mitigations.violationlog.writer import ViolationLog

path = sys.argv[1]
log = ViolationLog(path, "sRobot", "ab" * 32, echo=False, retry_buffer=20, retry_interval_s=3600)
log.supervisor("start", pid=os.getpid())

def violation(tick):
    log.violation(
        "state_req103",
        text="While classifier = 1 sRobot shall always satisfy OpState = 3",
        formula="H (classifier = 1 -> OpState = 3)",
        tick=tick,
        inputs={"classifier": 1, "OpState": 2},
    )

for tick in range(1, 11):
    violation(tick)
_, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
resource.setrlimit(resource.RLIMIT_FSIZE, (os.path.getsize(path), hard))  # the disk is full
for tick in range(11, 111):
    violation(tick)
resource.setrlimit(resource.RLIMIT_FSIZE, (hard, hard))  # room again
if log.retry() != 0:
    sys.exit("records still waiting after the disk had room again")
for tick in range(111, 121):
    violation(tick)
log.close()
"""


def _records(path: Path) -> list[dict[str, Any]]:
    try:
        lines = path.read_bytes().splitlines()
    except FileNotFoundError:
        return []
    out = []
    for line in lines:
        try:
            out.append(json.loads(line))
        except ValueError:
            continue  # a line still being written
    return out


def _supervisor(path: Path, what: str) -> dict[str, Any] | None:
    return next((r for r in _records(path) if r.get("what") == what), None)


def make(out: Path, env: dict[str, str]) -> None:
    """Write the files above into ``out``."""
    log = out / "violations.jsonl"
    rotated = out / "violations.jsonl.1"
    with open(out / "demo.txt", "w") as shown:
        demo = subprocess.Popen(
            [sys.executable, "-m", "supervisor", "demo", "--duration", "6", "--no-live"]
            + ["--seed", "7", "--fault-rate", "0.5", "--log", str(log)],
            cwd=out,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=shown,
            stderr=subprocess.STDOUT,
        )
    try:
        wait_until(
            "the demo's daemon ready",
            lambda: _supervisor(log, "ready"),
            120,
            lambda: (out / "demo.txt").read_text(),
        )
        start = _supervisor(log, "start")
        assert start is not None
        os.rename(log, rotated)  # logrotate: rename, then the snippet's SIGUSR1
        os.kill(start["pid"], signal.SIGUSR1)
        assert demo.wait(timeout=120) == 0, (out / "demo.txt").read_text()
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.wait()
    link = _records(log)[0]
    assert link.get("what") == "log_reopened" and link.get("rotated") is True, link

    full = out / "disk-full"
    full.mkdir()
    # Its stderr is the writer's journal lines (each record not written): not shown.
    done = subprocess.run(
        [sys.executable, "-c", _DISK_FULL, str(full / "violations.jsonl")],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr[-3000:]

    rewritten = out / "rewritten"
    rewritten.mkdir()
    kept = _records(rotated)
    del kept[2]  # line 3
    (rewritten / "violations.jsonl").write_bytes(chain(kept))
