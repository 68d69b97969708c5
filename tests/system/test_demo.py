"""``safety-supervisor demo`` end to end: real processes, real DDS, no mocks.

The demo runs as ``python -m supervisor demo`` with ``--log`` in the test's
directory, so the summary it prints can be checked against the violation log
it leaves.
"""

from __future__ import annotations

import json
import os
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.ros
pytest.importorskip("rclpy")

ROOT = Path(__file__).resolve().parents[2]
DEMO = [sys.executable, "-m", "supervisor", "demo"]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env.pop("ROS_DOMAIN_ID", None)  # the demo picks its own private domain
    env.pop("NOTIFY_SOCKET", None)
    return env


def run_demo(tmp_path: Path, *args: str, timeout: float = 90) -> tuple[Any, list[dict]]:
    log = tmp_path / "violations.jsonl"
    proc = subprocess.run(
        [*DEMO, "--no-live", "--log", str(log), *args],
        cwd=ROOT,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    records = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
    return proc, records


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


def leftovers(*markers: str) -> list[str]:
    """Command lines of live processes that hold every marker as whole arguments
    (a marker of several words as consecutive arguments), so ``--seed 1`` is not
    found in another run's ``--seed 11``."""
    wanted = [m.split() for m in markers]
    found = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            argv = (proc / "cmdline").read_bytes().decode(errors="replace").split("\0")
            state = (proc / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        words = [w for a in argv for w in a.split()]
        if state != "Z" and all(_holds(words, m) for m in wanted):
            found.append(" ".join(argv))
    return found


def _holds(words: list[str], run: list[str]) -> bool:
    return any(words[i : i + len(run)] == run for i in range(len(words) - len(run) + 1))


def no_leftovers(log: Path, seed: int) -> None:
    assert leftovers("supervisor", "run", str(log)) == []
    assert leftovers("supervisor.tools.demo.robot", f"--seed {seed}") == []


def test_clean_run_has_no_violations(tmp_path: Path) -> None:
    seed = random.randrange(10**6, 10**7)
    proc, records = run_demo(tmp_path, "--duration", "8", "--fault-rate", "0", "--seed", str(seed))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr
    out = proc.stdout
    assert "demo finished after 8.0 s" in out
    assert section(out, "violations") == (0, {})
    assert section(out, "mitigations") == (0, {})
    assert f"violation log     {tmp_path / 'violations.jsonl'}" in out
    # The walk ran and the supervisor stepped on it.
    assert int(re.search(r"supervisor ticks  (\d+)", out).group(1)) >= 50
    assert int(re.search(r"walks +(\d+)", out).group(1)) >= 1
    assert "fault rate 0 %" in out
    assert [r for r in records if r["event"] == "violation"] == []
    assert [r for r in records if r["event"] == "mitigation"] == []
    whats = [r.get("what") for r in records if r["event"] == "supervisor"]
    assert {"start", "ready", "stop"} <= set(whats)
    assert whats.index("start") < whats.index("ready") < whats.index("stop")
    assert "input_stale" not in whats  # the supervisor stops before the robot goes quiet
    stop = next(r for r in records if r.get("what") == "stop")
    assert stop["violations"] == 0 and stop["ticks"] >= 50
    no_leftovers(tmp_path / "violations.jsonl", seed)


def test_uv_fault_is_caught_and_mitigated(tmp_path: Path) -> None:
    # Seed 1: the first walk reaches the red zone at ~3 s; every state-3 entry is faulty.
    proc, records = run_demo(
        tmp_path, "--duration", "10", "--fault-rate", "1", "--seed", "1", timeout=90
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    out = proc.stdout
    n_v, violations = section(out, "violations")
    assert n_v >= 1 and set(violations) == {"operationalstate_3"}, out
    _, mitigations = section(out, "mitigations")
    m = re.match(
        r"(\d+) ok, (\d+) failed, latency p50 [\d.]+ ms, max [\d.]+ ms", mitigations["uv_off"]
    )
    assert m is not None, mitigations
    uv_ok, uv_failed = int(m.group(1)), int(m.group(2))
    assert uv_ok >= 1 and uv_failed == 0
    # The log says the same: nothing but the injected fault was reported.
    logged = [r for r in records if r["event"] == "violation"]
    assert {r["requirement"] for r in logged} == {"operationalstate_3"}
    assert len(logged) == int(violations["operationalstate_3"]) == n_v
    for r in logged:
        assert r["inputs"]["OpState"] == 3 and r["inputs"]["turnoffUVC"] is False
        assert r["inputs"]["halt"] is True
    uv = [r for r in records if r["event"] == "mitigation" and r["action"] == "uv_off"]
    assert len(uv) == uv_ok and all(
        r["ok"] and r["requirement"] == "operationalstate_3" for r in uv
    )
    # Every fault was caught, and the robot acted on the supervisor's uv_off.
    faults = re.search(r"faults injected   (\d+) .*, (\d+) cut by the supervisor", out)
    assert faults is not None and int(faults.group(1)) == n_v == int(faults.group(2)), out
    # The events read as words.
    assert re.search(
        r"\* violation operationalstate_3: UV on in state 3 -> (uv_off, stop_robot|stop_robot, uv_off) \(\d+ ms\)",
        out,
    ), out
    # The escalation never fired (the mitigation fixed the fault at once) and no SSH was tried.
    assert not [r for r in records if r["event"] == "mitigation" and r["action"] == "power_off"]
    no_leftovers(tmp_path / "violations.jsonl", 1)


def test_ctrl_c_stops_everything(tmp_path: Path) -> None:
    seed = random.randrange(10**6, 10**7)
    log = tmp_path / "violations.jsonl"
    proc = subprocess.Popen(
        [*DEMO, "--no-live", "--log", str(log), "--duration", "60", "--seed", str(seed)],
        cwd=ROOT,
        env=_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        deadline = time.monotonic() + 60
        for line in proc.stdout:
            if "the walk starts" in line or time.monotonic() > deadline:
                break
        time.sleep(1.5)  # a few cycles of the walk
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert "demo interrupted after" in out and "Traceback" not in err
    whats = [json.loads(x).get("what") for x in log.read_text().splitlines()]
    assert "stop" in whats
    no_leftovers(log, seed)


def test_bad_domain_is_one_line(tmp_path: Path) -> None:
    proc = subprocess.run(
        [*DEMO, "--duration", "1", "--log", str(tmp_path / "v.jsonl")],
        cwd=ROOT,
        env={**_env(), "ROS_DOMAIN_ID": "robot"},
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert proc.returncode == 1
    assert proc.stderr.startswith("safety-supervisor demo: ROS_DOMAIN_ID='robot' is not a number")
    assert len(proc.stderr.strip().splitlines()) == 1


def test_demo_config_differs_from_the_shipped_one_only_in_log_and_power_off(
    tmp_path: Path,
) -> None:
    import yaml

    from supervisor.config import load_config
    from supervisor.tools.demo.config import SHIPPED_CONFIG, demo_config

    log = tmp_path / "v.jsonl"
    path = demo_config(SHIPPED_CONFIG, tmp_path, log)
    shipped, demo = yaml.safe_load(SHIPPED_CONFIG.read_text()), yaml.safe_load(path.read_text())
    assert demo["logging"]["violations"] == str(log)
    assert demo["mitigations"]["power_off"]["command"]["argv"][-2:] == [
        "poweroff-marker",
        str(tmp_path),
    ]
    for key in ("logging", "mitigations"):
        shipped.pop(key), demo.pop(key)
    assert demo == shipped
    cfg = load_config(path)
    assert cfg.mitigations["power_off"].kind == "command"
    assert len(cfg.requirements) == 13
    # The stand-in really runs, without a shell and with the command action's bare environment.
    settings = cfg.mitigations["power_off"].settings
    argv = list(settings.argv)
    env = {"PATH": "/usr/bin:/bin", **settings.env}
    subprocess.run(argv, env=env, cwd="/", check=True, capture_output=True, timeout=30)
    assert len(list(tmp_path.glob("poweroff-*.marker"))) == 1


def test_explain_in_words() -> None:
    from supervisor.tools.demo.state import explain

    uv_on = dict(classifier=1, distance_to_target=2, OpState=3, alert=False, halt=True, slowdown=False, turnoffUVC=False)  # fmt: skip
    assert explain("operationalstate_3", uv_on) == "UV on in state 3"
    wrong_state = dict(uv_on, OpState=2, alert=True, slowdown=True, turnoffUVC=False, halt=False)
    assert (
        explain("state_req103", wrong_state)
        == "trained worker at 2 m (red) but OpState 2, expected 3"
    )
