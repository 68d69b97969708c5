"""``safety-supervisor demo --example mobile-base``: the shipped mobile-base.yaml, the
simulated base's script, and the real demo over DDS breaking every requirement.

The script's check needs no DDS: :class:`supervisor.tools.demo.base.BaseModel` is the
base without ROS.  The end-to-end test runs ``python -m supervisor demo`` with its own
ROS domain, localhost-only discovery and ``--log`` in the test's directory, and reads
the log with the project's reader.
"""

from __future__ import annotations

import os
import random
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import pytest
import yaml

from mitigations.violationlog.reader import iter_records, read_bytes, verify_bytes
from supervisor import data
from supervisor.tools.demo.base import (
    REQUIREMENTS,
    SCENARIO,
    SCENARIO_S,
    BaseModel,
    phase_at,
    scenario_breaks,
)

ROOT = Path(__file__).resolve().parents[3]
CONFIG = data.example("mobile-base.yaml")
DEMO = [sys.executable, "-m", "supervisor", "demo", "--example", "mobile-base"]


def config_ids() -> list[str]:
    return [r["id"] for r in yaml.safe_load(CONFIG.read_text())["requirements"]]


# ------------------------------------------------------------ the script, no DDS


def test_every_requirement_of_the_config_is_in_the_script() -> None:
    assert config_ids() == list(REQUIREMENTS)
    assert {p.breaks for p in SCENARIO if p.breaks} == set(REQUIREMENTS)


def test_each_phase_breaks_what_it_says_and_nothing_else() -> None:
    # Without a supervisor to halt the base, each fault runs its course.
    found = scenario_breaks()
    assert found == {p.name: ({p.breaks} if p.breaks else set()) for p in SCENARIO}


def test_the_script_repeats_the_same_way() -> None:
    once = scenario_breaks()
    twice = scenario_breaks(2 * SCENARIO_S)
    assert twice == once
    assert phase_at(0.0)[1] is phase_at(SCENARIO_S)[1] is SCENARIO[0]


def test_the_base_obeys_the_supervisor_at_once_and_resumes_at_the_next_phase() -> None:
    model = BaseModel()
    wall = next(i for i, p in enumerate(SCENARIO) if p.name == "wall")
    while model.index != wall:
        model.step()
    assert model.step().vx > 0
    model.supervisor_halt = True
    o = model.step()
    assert o.halted and o.vx == o.vy == o.cmd == 0.0 and model.halted_by == "supervisor"
    while model.index == wall:
        o = model.step()
    assert not o.halted and o.cmd > 0  # the next phase: the operator resumed


def test_the_scan_is_frozen_slow_and_fast_where_the_script_says() -> None:
    model = BaseModel()
    stamps: dict[str, list[tuple[float, float]]] = {}
    while model.t < SCENARIO_S:
        o = model.step()
        if o.scan_stamp is not None:
            stamps.setdefault(o.phase.name, []).append((o.t, o.scan_stamp))
    frozen = stamps["stale_scan"]
    assert len({s for _, s in frozen}) == 1 and len(frozen) >= 25  # still 15 Hz, one stamp
    assert all(t == s for t, s in stamps["cruise"])
    slow = [t for t, _ in stamps["slow_scan"]]
    assert 11 <= len(slow) <= 13  # 5 Hz for 2.5 s
    for name, got in stamps.items():
        hz = next(p.scan_hz for p in SCENARIO if p.name == name)
        assert 10 <= hz <= 40 or name == "slow_scan"
        assert len(got) >= 1


def test_the_scan_hides_its_wall_among_readings_that_are_not_readings() -> None:
    import math

    from supervisor.tools.demo.base import READINGS, scan_ranges

    rng = random.Random(1)
    room = [rng.uniform(2.5, 8.0) for _ in range(READINGS)]
    ranges = scan_ranges(rng, room, 0.45)
    assert len(ranges) == READINGS == 1440
    valid = [r for r in ranges if math.isfinite(r) and 0.05 <= r <= 30.0]
    assert min(valid) == pytest.approx(0.45)
    assert len(valid) < READINGS  # NaN, inf or out of range readings are in
    assert any(not math.isfinite(r) or r < 0.05 or r > 30.0 for r in ranges)


# ------------------------------------------------------------ the config


@pytest.mark.slow  # the z3 analyses: about 20 s here
def test_the_config_passes_check() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "supervisor", "check", str(CONFIG)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr
    for rid in REQUIREMENTS:
        assert re.search(rf"^ok +{rid} ", proc.stdout, re.M), proc.stdout


# ------------------------------------------------------------ the real demo over DDS


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(100, 200))
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("NOTIFY_SOCKET", None)
    return env


def section(out: str, title: str) -> tuple[int, dict[str, str]]:
    """``  violations        3`` and the indented rows under it."""
    lines = out.splitlines()
    start = next(i for i, ln in enumerate(lines) if re.match(rf"  {title} +\d+$", ln))
    total = int(lines[start].split()[-1])
    rows = {}
    for ln in lines[start + 1 :]:
        if not ln.startswith("    "):
            break
        name, rest = ln.split(maxsplit=1)
        rows[name] = rest
    return total, rows


@pytest.mark.ros
def test_the_demo_breaks_every_requirement_over_dds(tmp_path: Path) -> None:
    pytest.importorskip("rclpy")
    log = tmp_path / "violations.jsonl"
    seconds = SCENARIO_S + 1
    proc = subprocess.run(
        [*DEMO, "--no-live", "--log", str(log), "--duration", f"{seconds:g}", "--seed", "7"],
        cwd=ROOT,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=seconds + 120,
    )
    out = proc.stdout
    assert proc.returncode == 0, out + proc.stderr
    assert "Traceback" not in proc.stderr
    assert verify_bytes(str(log), read_bytes(str(log))).errors == []
    records: list[dict[str, Any]] = list(iter_records(str(log)))
    violated = {r["requirement"] for r in records if r["event"] == "violation"}
    assert violated == set(REQUIREMENTS), out
    # Each fault is caught in the phase that makes it, with the inputs that break it.
    first = {
        rid: next(r for r in records if r["event"] == "violation" and r["requirement"] == rid)
        for rid in REQUIREMENTS
    }
    assert first["slow_near_obstacle"]["inputs"]["obstacle"] < 0.5
    assert first["fresh_scan"]["inputs"]["scan_age_ms"] >= 300
    assert first["scan_rate_ok"]["inputs"]["scan_rate"] < 8
    assert first["no_nav_on_low_battery"]["inputs"]["nav_active"] is True
    assert first["no_nav_on_low_battery"]["inputs"]["battery"] < 0.15
    assert first["cmd_vel_limit"]["inputs"]["cmd_vel"] > 1.0
    order = [first[rid]["seq"] for rid in REQUIREMENTS]
    assert order == sorted(order)  # in the script's order
    # The supervisor's mitigations ran, and the base obeyed them.
    mitigations = [r for r in records if r["event"] == "mitigation"]
    assert {r["action"] for r in mitigations} >= {"stop_base", "zero_cmd_vel"}
    assert all(r["ok"] for r in mitigations)
    assert re.search(r"base halted +.*\d+ by supervisor", out), out
    # The summary names every requirement and says it was broken.
    n_req, rows = section(out, "requirements")
    assert n_req == len(REQUIREMENTS) and list(rows) == list(REQUIREMENTS)
    assert all(row.startswith("broken: ") for row in rows.values()), rows
    assert f"broken            {len(REQUIREMENTS)} of {len(REQUIREMENTS)} requirements" in out
    n_v, per = section(out, "violations")
    assert n_v == sum(1 for r in records if r["event"] == "violation")
    assert set(per) == set(REQUIREMENTS)
    whats = [r.get("what") for r in records if r["event"] == "supervisor"]
    assert "input_stale" not in whats  # the supervisor stops before the base goes quiet
    assert leftovers("supervisor.tools.demo.base", "--seed 7") == []
    assert leftovers("supervisor", "run", str(log)) == []


def leftovers(*markers: str) -> list[str]:
    """Command lines of live processes that contain every marker."""
    found = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            cmd = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            state = (proc / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z" and all(m in cmd for m in markers):
            found.append(cmd)
    return found


@pytest.mark.ros
@pytest.mark.parametrize("how", ["stdin", "sigterm", "sigint"])
def test_the_base_exits_when_the_demo_goes_away_or_stops_it(how: str, robot_node: Any) -> None:
    pytest.importorskip("rclpy")
    import rosutil

    seed = str(random.randrange(10**6, 10**7))
    env = _env()
    env["ROS_DOMAIN_ID"] = str(rosutil.DOMAIN_ID)  # where this process's node watches
    proc = subprocess.Popen(
        [sys.executable, "-m", "supervisor.tools.demo.base", "--seed", seed],
        cwd=ROOT,
        env=env,
        stdin=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        # rclpy imported and the base's node made: it is in the graph, waiting for the supervisor
        rosutil.wait_until(
            "the base's node in the graph",
            lambda: proc.poll() is not None or "mobile_base" in robot_node.get_node_names(),
            60,
        )
        assert proc.poll() is None
        assert proc.stdin is not None
        if how == "stdin":
            proc.stdin.close()
        else:
            proc.send_signal(signal.SIGTERM if how == "sigterm" else signal.SIGINT)
        proc.wait(timeout=15)
        assert proc.stderr is not None
        err = proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    assert leftovers("supervisor.tools.demo.base", f"--seed {seed}") == []


def test_the_view_names_every_requirement_and_its_violations_in_words() -> None:
    from supervisor.tools.demo.config import EXAMPLES, demo_config, requirement_ids
    from supervisor.tools.demo.state import DemoState

    example = EXAMPLES["mobile-base"]
    st = DemoState(30.0, 0.0, 1, 42, Path("/tmp/v.jsonl"), "mobile-base")
    st.requirements = requirement_ids(CONFIG)
    st.walk_wall, st.walk_mono = time.time(), time.monotonic()
    st.on_robot({"ev": "phase", "n": 1, "name": "wall", "says": "at a wall", "breaks": "slow_near_obstacle"})  # fmt: skip
    st.on_robot({"ev": "base", "obstacle": 0.49, "speed": 0.79, "cmd": 0.75, "scan_hz": 15.0, "frozen": False, "battery": 0.8, "nav": "", "halted": False})  # fmt: skip
    st.on_record({"event": "violation", "requirement": "slow_near_obstacle", "inputs": {"obstacle": 0.49, "vx": 0.75, "vy": 0.25}})  # fmt: skip
    st.on_record({"event": "mitigation", "requirement": "slow_near_obstacle", "action": "stop_base", "ok": True, "latency_ms": 2.0})  # fmt: skip
    st.on_robot({"ev": "halted", "by": "supervisor"})
    screen = example.screen(st, False)
    assert "phase        wall: at a wall   (breaks slow_near_obstacle)" in screen
    assert "requirements 1 of 6 broken, 1 violations" in screen
    assert re.search(
        r"slow_near_obstacle +broken: 1 violation +\(last at [\d.]+ s: 0.79 m/s with an obstacle at 0.49 m\)",
        screen,
    ), screen
    assert "0.79 m/s with an obstacle at 0.49 m -> stop_base (2 ms)" in screen
    assert re.search(r"fresh_scan +not broken", screen)
    assert "obstacle 0.49 m" in example.status_line(st)
    out = example.summary(st, 30.0, False)
    n, rows = section(out, "requirements")
    assert n == 6 and list(rows) == list(REQUIREMENTS)
    assert rows["slow_near_obstacle"] == "broken: 1 violation"
    assert rows["cmd_vel_limit"] == "not broken"
    assert "broken            1 of 6 requirements" in out
    assert "base halted       1 by supervisor" in out
    # The demo's copy of the config differs only in its log.
    tmp = Path(tempfile.mkdtemp())
    copy = yaml.safe_load(demo_config(CONFIG, tmp, tmp / "v.jsonl").read_text())
    shipped = yaml.safe_load(CONFIG.read_text())
    assert copy.pop("logging")["violations"] == str(tmp / "v.jsonl")
    shipped.pop("logging")
    assert copy == shipped


def test_robot_options_of_the_srobot_are_refused_for_the_base() -> None:
    proc = subprocess.run(
        [*DEMO, "--fault-rate", "0.5", "--duration", "1"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert proc.stderr == (
        "safety-supervisor demo: --fault-rate is not an option of --example mobile-base\n"
    )
