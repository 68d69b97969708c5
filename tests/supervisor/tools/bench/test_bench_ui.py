"""``safety-supervisor bench``'s UI load (supervisor/tools/bench/ui.py): the daemon
without a UI, with ``ui`` and open event streams, and with the UI killed and restarted.

Only structure and sanity are asserted (the daemon's counts add up, every client
received events and got the status back after the restart, the UI exited 0), never
speed: speed goals are printed by the bench, not tested.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[4]
CLIENTS = 3


def _positive(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) and x > 0


def test_quick_and_full_defaults() -> None:
    import argparse

    from supervisor.tools.bench.command import _add_arguments, resolve

    p = argparse.ArgumentParser()
    _add_arguments(p)
    full = resolve(p.parse_args([]))
    assert (full.ui_rates, full.ui_seconds, full.ui_clients) == ([20000], 10.0, 10)
    quick = resolve(p.parse_args(["--quick", "--ui-rates", "5000"]))
    assert (quick.ui_rates, quick.ui_seconds, quick.skip_ui) == ([5000], 8.0, False)


@pytest.mark.ros
@pytest.mark.slow
def test_bench_ui_load(tmp_path: Path) -> None:
    pytest.importorskip("rclpy")
    out = tmp_path / "out"
    env = {k: v for k, v in os.environ.items() if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC")}
    skip = ["--skip-throughput", "--skip-record", "--skip-latency", "--skip-replay"]
    skip += ["--skip-scale", "--skip-soak"]
    args = ["--ui-rates", "5000", "--ui-seconds", "6", "--ui-clients", str(CLIENTS)]
    p = subprocess.run(
        [sys.executable, "-m", "supervisor", "bench", *skip, *args, "--out", str(out)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=150,
    )
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    assert "UI load" in p.stdout
    r = json.loads((out / "bench.json").read_text())
    assert set(r) >= {"ui"} and "throughput" not in r
    (row,) = r["ui"]
    assert (row["offered"], row["seconds"], row["clients"]) == (5000, 6, CLIENTS)
    cases = {c["case"]: c for c in row["cases"]}
    assert list(cases) == ["no ui", "ui + clients", "ui killed and restarted"]
    for name, c in cases.items():
        assert 0 < c["received"] <= c["sent"], name
        assert c["lost"] == c["sent"] - c["received"], name
        assert c["loss_agree"], (name, c["loss"])
        assert _positive(c["cpu_us_per_msg"]), (name, c)
        assert isinstance(c["cpu_diff_pct"], float), name
    assert cases["no ui"]["ui"] is None

    for name in ("ui + clients", "ui killed and restarted"):
        ui = cases[name]["ui"]
        assert len(ui["per_client"]) == CLIENTS
        for client in ui["per_client"]:
            # the snapshot, status documents and /diagnostics, while the publisher ran too
            assert client["events"] > 0 and client["events_in_run"] > 0, (name, client)
            assert client["status_events"] > 0, (name, client)
        assert ui["exit_code"] == 0, name  # SIGTERM with the streams open
    served = cases["ui + clients"]["ui"]
    assert all(c["connects"] == 1 for c in served["per_client"]), served
    assert _positive(served["ui_cpu_ms_per_s"]), served
    restarted = cases["ui killed and restarted"]["ui"]
    assert all(c["connects"] == 2 for c in restarted["per_client"]), restarted
    rs = restarted["restart"]
    assert rs["clients_reconnected"] == CLIENTS and rs["clients_with_status_again"] == CLIENTS
    assert _positive(rs["status_again_s"]["min"]), rs
    assert rs["status_again_s"]["min"] >= rs["connected_again_s"]["min"] > 0, rs

    md = (out / "bench.md").read_text()
    assert "## UI load" in md
    for name, c in cases.items():
        shown = name.replace("clients", f"{CLIENTS} clients")
        assert f"| {shown} | {c['sent']} | {c['received']} | {c['lost']} |" in md, shown
    assert f"{CLIENTS}/{CLIENTS} clients connected again" in p.stdout
