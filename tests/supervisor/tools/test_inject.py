"""``inject``: computed violation injection.

The traces are judged here again with the reference interpreter, independently
of the command's own re-check, and injected into a real supervisor over DDS.
"""

from __future__ import annotations

import contextlib
import io
import os
import random
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from rosutil import ROOT, ROS_ENV, SROBOT, Daemon, variant

from monitors.verify.interpret import verdicts
from supervisor.cli import main as cli_main
from supervisor.pipeline import project_for
from supervisor.tools.bench.session import DOMAIN_IDS
from supervisor.tools.inject.plan import Planner
from supervisor.tools.inject.target import WARMUP
from supervisor.validation import project_requirements

SROBOT_IDS = [
    "classifier_assumption",
    "dtt_assumption",
    "operationalstate_0",
    "operationalstate_1",
    "operationalstate_2",
    "operationalstate_3",
    "state_req000",
    "state_req101",
    "state_req102",
    "state_req103",
    "state_req201",
    "state_req202",
    "state_req203",
]
ASSUMPTIONS = {"classifier_assumption": "classifier", "dtt_assumption": "distance_to_target"}

SMALL = """\
component: sRobot
step: {policy: POLICY, trigger: halt, period_ms: 10, max_skew_ms: 5}
variables:
  obstacle: {type: bool, topic: /obstacle, msg: std_msgs/msg/Bool, role: input}
  halt:     {type: bool, topic: /halt, msg: std_msgs/msg/Bool, role: output}
  speed:    {type: double, topic: /odom, msg: nav_msgs/msg/Odometry, field: twist.twist.linear.x, role: output, range: [0, 2]}
  level:    {type: int64, topic: /level, msg: std_msgs/msg/UInt8, role: output}
requirements:
  - id: react
    text: upon obstacle sRobot shall within 3 ticks satisfy halt
  - id: stopped
    text: whenever halt sRobot shall immediately satisfy speed <= 0.5
  - id: level_low
    text: sRobot shall always satisfy level <= 200
  - id: level_lower
    text: sRobot shall always satisfy level <= 100
EXTRA
"""


def command() -> list[str]:
    return [sys.executable, "-m", "supervisor", "inject"]


def run(*args: str, env: dict[str, str] | None = None, timeout: float = 120) -> Any:
    return subprocess.run(
        [*command(), *args],
        cwd=ROOT,
        env={**os.environ, **(env or {})},
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def small_config(tmp: Path, policy: str = "on_trigger", extra: str = "") -> Path:
    path = tmp / f"small-{policy}.yaml"
    path.write_text(SMALL.replace("POLICY", policy).replace("EXTRA", extra))
    return path


# ------------------------------------------------------------------ parsing the output


def _value(cell: str) -> bool | int | float:
    cell = cell.rstrip("*")  # '*' marks a changed value
    if cell in ("true", "false"):
        return cell == "true"
    return int(cell) if re.fullmatch(r"-?\d+", cell) else float(cell)


def parse_blocks(stdout: str, names: list[str]) -> dict[str, dict[str, Any]]:
    """Each injection's printed trace (typed), notes and 'logged:' line, by id."""
    blocks: dict[str, dict[str, Any]] = {}
    lines = stdout.splitlines()
    i = 0
    while i < len(lines):
        m = re.match(r"^(\w+): ", lines[i])
        if m and i + 2 < len(lines) and lines[i + 2].startswith("tick"):
            rid = m.group(1)
            head = re.split(r"\s{2,}", lines[i + 2].strip())
            trace, notes, logged = [], [], None
            j = i + 3
            while j < len(lines) and re.match(r"^\d", lines[j]):
                cells = dict(zip(head, re.split(r"\s{2,}", lines[j].strip()), strict=True))
                trace.append({n: _value(cells[n]) for n in names})
                j += 1
            while j < len(lines) and lines[j].startswith(("note: ", "logged: ")):
                if lines[j].startswith("note: "):
                    notes.append(lines[j][6:])
                else:
                    logged = lines[j][8:]
                j += 1
            blocks[rid] = {"trace": trace, "notes": notes, "logged": logged, "line": lines[i + 1]}
            i = j
        else:
            i += 1
    return blocks


@pytest.fixture(scope="module")
def srobot() -> Any:
    project = project_for(SROBOT)
    reqs, infos = project_requirements(project)
    names = [v.name for v in project.config.inputs]
    return {r.id: r for r in reqs}, {v.name: v for v in infos}, names


@pytest.fixture(scope="module")
def dry_all(srobot: Any) -> tuple[dict[str, dict[str, Any]], str, float]:
    """`inject config/srobot.yaml --all --dry-run`, in process (one z3 run for all 13)."""
    out = io.StringIO()
    t = time.perf_counter()
    with contextlib.redirect_stdout(out):
        rc = cli_main(["inject", str(SROBOT), "--all", "--dry-run"])
    seconds = time.perf_counter() - t
    assert rc == 0, out.getvalue()
    return parse_blocks(out.getvalue(), srobot[2]), out.getvalue(), seconds


# ------------------------------------------------------------------ dry runs


@pytest.mark.slow
@pytest.mark.parametrize("rid", SROBOT_IDS)
def test_dry_run_violates_only_the_requirement(rid: str, srobot: Any, dry_all: Any) -> None:
    reqs, infos, _ = srobot
    blocks, text, _ = dry_all
    assert set(blocks) == set(SROBOT_IDS), text
    trace = blocks[rid]["trace"]
    assert len(trace) >= 2
    for other, req in reqs.items():
        v = verdicts(req.formula, trace)
        if other == rid:
            assert not v[-1], f"{rid} holds at the last tick: {trace}"
            assert all(v[:-1]), f"{rid} is violated before the last tick: {trace}"
        else:
            assert all(v), f"injecting {rid} also violates {other}: {trace}"
    # the first tick is the same nominal state for every injection
    assert trace[0] == blocks["state_req103"]["trace"][0]
    out_of_range = {
        n
        for row in trace
        for n, x in row.items()
        if infos[n].range is not None and not infos[n].range[0] <= x <= infos[n].range[1]
    }
    if rid in ASSUMPTIONS:
        # an assumption here can only fail outside a declared range: the range is
        # broken too (not monitored), no other requirement is, and inject says so
        var = ASSUMPTIONS[rid]
        assert out_of_range == {var}
        assert any(f"needs {var} outside its range" in n for n in blocks[rid]["notes"])
        assert f"the supervisor should log {rid}" in blocks[rid]["line"]
    else:
        assert out_of_range == set()
        assert blocks[rid]["notes"] == []
        assert f"violates {rid} and nothing else" in blocks[rid]["line"]


@pytest.mark.slow
def test_dry_run_all_is_quick(dry_all: Any) -> None:
    _, text, seconds = dry_all
    assert "dry run: nothing published (13 trace(s)" in text
    assert seconds < 60, f"{seconds:.1f} s for 13 traces"


def test_dry_run_one_requirement_via_the_command() -> None:
    p = run(str(SROBOT), "state_req103", "--dry-run")
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert lines[0].startswith("state_req103: While classifier = 1")
    assert lines[1].startswith("2 ticks; tick 1 violates state_req103 and nothing else")
    table = lines[2:5]
    assert table[0].split() == [
        "tick",
        "classifier",
        "distance_to_target",
        "OpState",
        "alert",
        "halt",
        "slowdown",
        "turnoffUVC",
        "violated",
    ]
    assert table[2].split()[-1] == "state_req103"
    assert "dry run: nothing published" in lines[-1]
    assert p.stderr == ""


def test_unknown_requirement_one_line_with_the_list() -> None:
    p = run(str(SROBOT), "state_req999", "--dry-run")
    assert p.returncode == 1
    assert p.stdout == ""
    err = p.stderr.strip().splitlines()
    assert len(err) == 1, p.stderr
    assert "no requirement 'state_req999'" in err[0] and "state_req103" in err[0]


def test_req_and_all_together_is_a_usage_error() -> None:
    assert run(str(SROBOT), "--dry-run").returncode == 2
    assert run(str(SROBOT), "state_req103", "--all", "--dry-run").returncode == 2


@pytest.mark.ros
def test_no_supervisor_listening(tmp_path: Path) -> None:
    # a domain of no test (rosutil: 1..200) and of no bench (DOMAIN_IDS): 201..230 took
    # the bench's, and a bench of the other worker had a supervisor listening there
    domain = random.randint(201, DOMAIN_IDS[0] - 1)
    env = {"ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    p = run(str(SROBOT), "state_req103", "--wait-s", "1", env=env)
    assert p.returncode == 1
    err = p.stderr.strip().splitlines()
    assert len(err) == 1, p.stderr
    assert "no supervisor is listening" in err[0] and "/sRobotClassifier" in err[0]


@pytest.mark.slow  # a full check in a subprocess: full suite only (README, quick tier)
def test_unviolable_requirement_one_line(tmp_path: Path) -> None:
    # level is a uint8 field: no message can carry a value above 255
    extra = "  - id: fits_byte\n    text: sRobot shall always satisfy level <= 255\n"
    cfg = small_config(tmp_path, extra=extra)
    p = run(str(cfg), "fits_byte", "--dry-run")
    assert p.returncode == 1
    err = p.stderr.strip().splitlines()
    assert len(err) == 1 and "fits_byte cannot be violated" in err[0], p.stderr
    # --all skips it and says why, and still injects the others
    p = run(str(cfg), "--all", "--dry-run")
    assert p.returncode == 0, p.stderr
    assert "skipped fits_byte cannot be violated" in p.stdout
    assert "4 trace(s)" in p.stdout


def test_must_also_break_is_named(tmp_path: Path) -> None:
    """level <= 200 cannot fail while level <= 100 holds: inject says so, and the
    trace breaks exactly those two."""
    cfg = small_config(tmp_path)
    p = run(str(cfg), "level_low", "--dry-run")
    assert p.returncode == 0, p.stderr
    assert "note: violating level_low also violates level_lower (they share level)" in p.stdout
    assert "the supervisor should log level_low and level_lower" in p.stdout
    trace = parse_blocks(p.stdout, ["obstacle", "halt", "speed", "level"])["level_low"]["trace"]
    assert trace[-1]["level"] == 201  # the threshold, not an arbitrary value


@pytest.mark.parametrize("policy", ["on_trigger", "synchronized", "periodic", "on_message"])
def test_policies_judged_on_what_the_supervisor_steps_on(tmp_path: Path, policy: str) -> None:
    """The timed requirement over the states each step policy makes of the trace
    (warm-up, half-updated states for on_message, held ticks for periodic)."""
    project = project_for(small_config(tmp_path, policy))
    planner = Planner(project)
    reqs = planner.reqs
    for rid in reqs:
        inj = planner.plan(rid)
        for warm in (1, WARMUP):
            states, labels = planner.observed(inj.trace, warm, planner.saturation)
            last = len(labels) - 1 - labels[::-1].index(inj.k - 1)
            for other, req in reqs.items():
                v = verdicts(req.formula, states)
                if other == rid:
                    assert not v[last], (policy, rid, states)
                elif other not in inj.expected:
                    assert all(v), (policy, rid, other, states)
    react = planner.plan("react")
    assert react.k == 5  # within 3 ticks: the bound plus 2


# ------------------------------------------------------------------ real DDS


@pytest.mark.ros
def test_inject_all_into_a_running_supervisor(tmp_path: Path, srobot: Any) -> None:
    """Each of the 13 requirements, injected over DDS into the daemon (record-only
    mitigations, so its actions do not feed back), is logged exactly once, at the
    injected state, and nothing else is logged."""
    names = srobot[2]
    cfg = variant(tmp_path)
    daemon = Daemon(tmp_path, cfg)
    t0 = time.monotonic()
    try:
        daemon.wait_notify("READY=1", timeout=60)
        ready = time.monotonic() - t0
        proc = subprocess.Popen(
            [*command(), str(cfg), "--all", "--log", str(daemon.log), "--hold-s", "0.4"],
            cwd=ROOT,
            env={**os.environ, **ROS_ENV},
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        deadline = time.monotonic() + 90
        while proc.poll() is None:  # the daemon blocks if its notify socket fills up
            daemon.recv(0.2)
            if time.monotonic() > deadline:
                proc.kill()
                raise AssertionError(f"inject --all took over 90 s\n{daemon.explain()}")
        stdout, stderr = proc.communicate()
        took = time.monotonic() - t0 - ready
        assert proc.returncode == 0, f"{stdout}\n{stderr}\n{daemon.explain()}"
        blocks = parse_blocks(stdout, names)
        assert set(blocks) == set(SROBOT_IDS)
        assert all(b["logged"] == f"{rid} -> ok" for rid, b in blocks.items()), stdout
        assert "13 injected" in stdout and "13 as expected" in stdout
        # the log itself: one violation per injection, in injection order, each at
        # exactly the injected state
        violations = [r for r in daemon.records() if r["event"] == "violation"]
        assert [r["requirement"] for r in violations] == list(blocks), stdout
        for r in violations:
            assert r["inputs"] == blocks[r["requirement"]]["trace"][-1]
        print(f"daemon ready in {ready:.1f} s; inject --all took {took:.1f} s")
    finally:
        daemon.close()


def test_a_variable_made_of_a_whole_message_is_refused_with_its_line(tmp_path: Path) -> None:
    # a reduction has no one field inject could set: refused, never half-driven
    cfg = tmp_path / "scan.yaml"
    cfg.write_text(
        "component: base\n"
        "step: {policy: periodic, period_ms: 20}\n"
        "variables:\n"
        "  speed: {type: double, topic: /odom, msg: nav_msgs/msg/Odometry, field: twist.twist.linear.x}\n"
        "  obstacle: {type: double, topic: /scan, msg: sensor_msgs/msg/LaserScan, field: ranges, reduce: min}\n"
        "requirements:\n"
        "  - id: slow\n"
        "    text: base shall always satisfy (obstacle < 0.5 => speed <= 0.3)\n"
    )
    p = run(str(cfg), "slow", "--dry-run")
    assert p.returncode == 1
    err = p.stderr.strip().splitlines()
    assert len(err) == 1, p.stderr
    assert f"{cfg}:5: variable 'obstacle'" in err[0] and "reduce: min" in err[0]
