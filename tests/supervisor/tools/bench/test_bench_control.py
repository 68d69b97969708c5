"""The control socket and UI soak (supervisor/tools/bench/control.py and httpsoak.py):
a few seconds of it against the real daemon and the real ``ui``, its JSON summary
checked; and that its verdict fails on each thing it watches.

Only structure and sanity are asserted, never speed beyond the 1 s answer limit
that is the soak's own verdict (docs/BENCHMARKS.md, "Control socket and UI soak").
"""

from __future__ import annotations

import copy
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[4]


def _good() -> dict[str, Any]:
    """A summary of a soak that passed, as the soak writes it."""
    return {
        "missed": 0, "log_verifies": True, "control_failed": 0, "daemon_alive_at_end": True,
        "daemon_tracebacks": 0,
        "http": {"missed": 0, "answered": 20, "got_through": 0, "server_errors": 0,
                 "alive_at_end": True, "exit_status": 0, "tracebacks": 0,
                 "resets_expected": 12, "resets_recorded": 12},
    }  # fmt: skip


@pytest.mark.parametrize(
    ("where", "key", "value"),
    [
        (None, "missed", 1),
        (None, "log_verifies", False),
        (None, "control_failed", 1),
        (None, "daemon_alive_at_end", False),
        (None, "daemon_tracebacks", 1),
        ("http", "missed", 1),
        ("http", "answered", 0),
        ("http", "got_through", 1),
        ("http", "server_errors", 2),
        ("http", "alive_at_end", False),
        ("http", "exit_status", 1),
        ("http", "tracebacks", 1),
        ("http", "resets_recorded", 13),  # a reset the probe did not send got through
        ("http", "resets_recorded", 11),  # an answered reset that the daemon did not take
    ],
)
def test_the_verdict_fails_on_each_thing_watched(where: str | None, key: str, value: Any) -> None:
    from supervisor.tools.bench.control import passed

    assert passed(_good())
    bad = copy.deepcopy(_good())
    (bad if where is None else bad[where])[key] = value
    assert not passed(bad)


@pytest.mark.ros
@pytest.mark.slow
def test_a_short_combined_soak_against_the_real_daemon_and_ui(tmp_path: Path) -> None:
    pytest.importorskip("rclpy")
    env = {k: v for k, v in os.environ.items() if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC")}
    # max_resets high: every operator reset is taken, so each one must leave a record
    args = ["--minutes", "0.1", "--clients", "4", "--http-clients", "6", "--max-resets", "1000"]
    p = subprocess.run(
        [sys.executable, "-m", "supervisor.tools.bench.control", *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert "Traceback" not in p.stderr, p.stderr
    r = json.loads(p.stdout)
    assert p.returncode == 0, (p.stderr, json.dumps(r, indent=1))
    assert set(r["channels"]) == {"control", "http"}
    for name, c in r["channels"].items():
        assert c["sent"] > 0 and c["answered"] == c["sent"] and c["misses"] == 0, (name, c)
        assert 0 < c["p50_ms"] <= c["p99_ms"] <= c["max_ms"] <= 1000, (name, c)
    h = r["http"]
    # the UI relayed the daemon's answers, and each reset it took left a via=ui record
    assert h["answers"].get("accepted", 0) > 0, h["answers"]
    assert h["resets_recorded"] == h["resets_expected"] > 0
    assert r["answers"].get("accepted", 0) > 0, r["answers"]
    # the HTTP attackers ran several kinds and the UI refused their requests in 4xx
    kinds = {k.split(":")[0] for k in h["attack_outcomes"]}
    assert len(kinds) >= 5, h["attack_outcomes"]
    codes = {k.split(":")[1] for k in h["attack_outcomes"]}
    assert codes & {"400", "401", "403", "413", "415"}, h["attack_outcomes"]
    assert h["got_through"] == 0 and h["server_errors"] == 0
    assert h["alive_at_end"] and h["exit_status"] == 0 and h["tracebacks"] == 0
    assert r["daemon_alive_at_end"] and r["daemon_tracebacks"] == 0
    assert r["log_verifies"] and r["control_failed"] == 0
    assert r["attack_connections"] > 0 and h["attack_connections"] > 0
    for part in (r, h):
        assert part["rss_kb"]["start"] > 0 and part["rss_kb"]["end"] > 0
        assert part["fds"]["start"] > 0 and part["fds"]["end"] > 0
