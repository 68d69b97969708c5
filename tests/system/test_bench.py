"""``safety-supervisor bench`` end to end in a short configuration.

Only structure and sanity are asserted (every number present, received <= sent,
losses between 0 and 100 %, positive latencies, p50 <= p99), never speed: speed
goals are benchmarks, and this machine is shared with other test runs.
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

pytestmark = pytest.mark.ros
pytest.importorskip("rclpy")

ROOT = Path(__file__).resolve().parents[2]


def _number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _bench(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC")}
    # The recording, replay and UI parts have tests of their own (tests/supervisor/tools/bench/test_bench_replay.py,
    # tests/supervisor/tools/bench/test_bench_ui.py, tests/supervisor/tools/bench/test_bench_scale.py).
    skip = ["--skip-record", "--skip-replay", "--skip-ui", "--skip-scale", "--skip-soak"]
    return subprocess.run(
        [sys.executable, "-m", "supervisor", "bench", *skip, *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _percentiles_sane(st: dict[str, Any]) -> None:
    for k in ("p50", "p90", "p99", "max", "mean"):
        assert _number(st[k]) and st[k] > 0, (k, st)
    assert st["p50"] <= st["p90"] <= st["p99"] <= st["max"], st


def test_bench_short_run() -> None:
    p = _bench("--rates", "2000", "--seconds", "1", "--latency-trials", "20", "--json")
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    r = json.loads(p.stdout)
    assert r["topics"] and r["trigger"] == "turnoffUVC"
    assert 215 <= r["domain_id"] <= 232  # clear of the test suite's 1..200

    (row,) = r["throughput"]
    assert row["offered"] == 2000
    sent = row["sent"]
    assert sent > 0 and sent % len(r["topics"]) == 0  # whole rounds, trigger last
    assert sum(row["sent_per_topic"].values()) == sent
    assert _number(row["achieved"]) and row["achieved"] > 0
    assert set(row["receivers"]) == {"daemon", "rclpy wait-set"}
    for name, rc in row["receivers"].items():
        assert 0 <= rc["received"] <= sent, name
        assert set(rc["received_per_topic"]) == set(row["sent_per_topic"]), name
        assert 0.0 <= rc["loss_pct"] <= 100.0, name
        # every receiver got messages and spent CPU on them; the rates are the counts
        # over the publishing window
        assert rc["received"] > 0 and _number(rc["cpu_s"]) and rc["cpu_s"] > 0, (name, rc)
        assert rc["msg_per_s"] == pytest.approx(rc["received"] / row["seconds"]), (name, rc)
        assert rc["cpu_us_per_msg"] == pytest.approx(1e6 * rc["cpu_s"] / rc["received"]), rc
    assert _number(row["overhead_pct"])
    assert row["fastest_baseline"] == "rclpy wait-set"
    assert row["daemon_violations"] == 0  # the published state is nominal
    loss = row["daemon_loss"]
    assert loss["agree"], loss
    assert loss["missing"] == sent - row["receivers"]["daemon"]["received"]
    assert loss["gaps"] + loss["before_first"] + loss["after_last"] == loss["missing"]
    assert loss["gaps"] == row["daemon_counted_lost"]

    lat = r["latency"]
    # both logging.durability orders, side by side (docs/reference/log.md#durability)
    assert lat["daemon"]["durability"] == "after_publish"
    assert lat["daemon_before_action"]["durability"] == "before_action"
    for who in ("echo", "daemon", "daemon_before_action"):
        st = lat[who]
        assert st["n"] + st["missed"] == 20, (who, st)
        assert st["n"] > 0
        _percentiles_sane(st)
    d = lat["daemon"]
    assert d["violation_records"] >= lat["warmup"] + d["n"]  # every halt had its record first
    _percentiles_sane(d["detect_to_publish_ms"])
    _percentiles_sane(lat["daemon_before_action"]["detect_to_publish_ms"])
    _percentiles_sane(lat["fsync"])
    assert lat["thesis_mean_ms"] == 33.0 and lat["tessla_mean_ms"] == 15.0


def test_daemon_loss_splits_what_was_not_taken() -> None:
    """sent - received = gaps + before the first number heard + after the last one
    (the stop record's by_publisher); [DISAGREE] only when they do not add up."""
    from supervisor.tools.bench.report import _format_loss
    from supervisor.tools.bench.throughput import daemon_loss

    sent = {"a": 100, "b": 100, "c": 100}
    inputs = {
        # 10 lost before the first heard, 5 in gaps, 20 after the last taken
        "a": {
            "messages": 64,
            "rejected": 1,
            "lost": 5,
            "by_publisher": [{"first": 11, "last": 80, "received": 65, "lost": 5}],
        },
        "b": {
            "messages": 100,
            "rejected": 0,
            "lost": 0,
            "by_publisher": [{"first": 1, "last": 100, "received": 100, "lost": 0}],
        },
        "c": {"messages": 0, "rejected": 0, "lost": 0, "by_publisher": []},  # nothing heard
    }
    loss = daemon_loss(sent, inputs)
    assert loss["per_topic"]["a"] == {
        "missing": 35,
        "gaps": 5,
        "before_first": 10,
        "after_last": 20,
    }
    assert loss["per_topic"]["c"] == {
        "missing": 100,
        "gaps": 0,
        "before_first": 0,
        "after_last": 100,
    }
    assert (loss["missing"], loss["gaps"], loss["before_first"], loss["after_last"]) == (
        135,
        5,
        10,
        120,
    )
    assert loss["agree"]
    row = {"daemon_loss": loss, "drained": True}
    line = _format_loss(row)
    assert "sent - received 135 = counted lost 5 + before the first heard 10" in line
    assert "after the last taken 120" in line and "DISAGREE" not in line
    assert "not yet taken" in _format_loss({**row, "drained": False})

    # A second stream on a topic with one publisher, or a message taken twice:
    # the categories no longer add up.
    inputs["b"]["by_publisher"].append({"first": 1, "last": 3, "received": 3, "lost": 0})
    inputs["b"]["messages"] = 103
    loss = daemon_loss(sent, inputs)
    assert not loss["agree"]
    assert _format_loss({"daemon_loss": loss, "drained": True}).endswith("[DISAGREE]")


def test_bench_text_and_errors(tmp_path: Path) -> None:
    """Tables for people; a bad config or option is one line, never a traceback."""
    p = _bench("--skip-latency", "--rates", "1500", "--seconds", "0.5")
    assert p.returncode == 0, p.stderr
    out = p.stdout
    assert "overhead (eq. 1) vs rclpy wait-set" in out
    assert "load average" in out and "summary" in out

    missing = tmp_path / "nope.yaml"
    p = _bench("--config", str(missing), timeout=60)
    assert p.returncode == 1
    assert p.stderr.strip().count("\n") == 0 and str(missing) in p.stderr
    assert "Traceback" not in p.stderr

    no_latency = tmp_path / "small.yaml"
    no_latency.write_text(
        "component: R\n"
        "step: {policy: on_message}\n"
        "variables:\n"
        "  x: {type: int64, topic: /x, msg: std_msgs/msg/Int64}\n"
        "requirements:\n"
        "  - id: r1\n"
        "    text: R shall always satisfy x >= 0\n"
        "    on_violation: [record]\n"
        "mitigations:\n"
        "  record: {log: {message: violated}}\n"
        "logging: {violations: /tmp/unused.jsonl}\n"
    )
    p = _bench("--config", str(no_latency), "--skip-throughput", timeout=60)
    assert p.returncode == 1
    assert "--skip-latency" in p.stderr and "Traceback" not in p.stderr

    p = _bench("--rates", "fast", timeout=60)
    assert p.returncode == 2


@pytest.mark.slow  # two daemon runs (two monitor builds)
def test_bench_quick_scan(tmp_path: Path) -> None:
    """``bench --quick --scan``: the LaserScan beside the stream, in bench.json and
    bench.md: the daemon without and with the scan, and the reduction per scan."""
    out = tmp_path / "out"
    p = _bench("--quick", "--scan", "--skip-throughput", "--skip-latency", "--out", str(out))
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    assert "LaserScan beside the stream" in p.stdout
    r = json.loads((out / "bench.json").read_text())
    assert "throughput" not in r and "latency" not in r
    sc = r["scan"]
    assert (sc["offered"], sc["seconds"], sc["hz"], sc["readings"]) == (10000, 2.0, 40, 1440)
    for label in ("off", "on"):
        side = sc[label]
        assert 0 < side["received"] <= side["sent"], (label, side)
        assert side["lost"] == side["sent"] - side["received"], label
        assert 0.0 <= side["loss_pct"] <= 100.0, label
        assert isinstance(side["loss_agree"], bool), label
        for k in ("cpu_s", "cpu_us_per_msg", "cpu_us_per_msg_to_exit"):
            assert _number(side[k]) and side[k] > 0, (label, k, side)
        assert side["waitset"]["received"] <= side["sent"], label
    off, on = sc["off"], sc["on"]
    assert off["scans_sent"] == off["scans_received"] == 0
    assert off["violations"] == 0  # the published state is nominal
    # 40 Hz for about 2 s, every scan counted in sent; the baseline takes them too
    assert 0 < on["scans_received"] <= on["scans_sent"] and 40 <= on["scans_sent"] <= 200
    assert on["stream_received"] + on["scans_received"] == on["received"]
    for k in ("cpu_diff_pct", "loss_pct_diff", "cpu_us_per_scan_added"):
        assert _number(sc[k]), (k, sc[k])

    red = sc["reduction"]
    assert (red["scans"], red["readings"], red["obstacle"]) == (5000, 1440, 1.25)
    assert red["cdr_bytes"] > 4 * 1440
    for k in ("reduce_built_us", "reduce_deserialised_us", "deserialise_us", "age_reader_us"):
        assert red[k]["n"] == 5000, k
        _percentiles_sane(red[k])
    md = (out / "bench.md").read_text()
    assert "## LaserScan beside the stream" in md and "reduce: min, deserialised message" in md
