"""Mitigations end to end: the daemon as a subprocess over real DDS, a real
sshd on 127.0.0.1, real subscribers in this process.

- latched halt: a subscriber that joins after the violation still gets it;
  the latch repeats; an operator reset (``safety-supervisor reset``) is refused
  while the requirement is violated and accepted once it holds;
- ssh: a violation runs the configured command on the sshd (the test sees the
  file it touches and the logged exit status); a wrong host key is refused and
  the escalation still runs; with sshd down the action is retried with backoff
  while the monitor keeps stepping.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.ros
pytest.importorskip("rclpy")

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rosutil import (  # noqa: E402
    ROOT,
    ROS_ENV,
    S0,
    S3,
    VIOLATING,
    Daemon,
    Robot,
    spin_until,
    variant,
    wait_until,
)
from sshd import free_port, keygen, known_hosts_line  # noqa: E402
from std_msgs.msg import Bool  # noqa: E402

REQ103_BLOCK = (
    "on_violation: [record]\n"
    "    policy: {debounce_steps: 1, cooldown_ms: 1000, reset: after_mitigation}\n"
    "  - id: state_req201"
)
# A trained worker in the red zone, robot stopped with UV off: state_req103 holds.
HOLDING = dict(S3)


def req103(policy: str, on_violation: str = "[stop_robot]") -> tuple[str, str]:
    return (
        REQ103_BLOCK,
        f"on_violation: {on_violation}\n    policy: {policy}\n  - id: state_req201",
    )


def start(tmp_path: Path, config: Path) -> Daemon:
    d = Daemon(tmp_path, config)
    d.wait_notify("READY=1", timeout=30)
    return d


def mitigation(d: Daemon, action: str, **match: Any) -> dict[str, Any]:
    return d.wait_record(
        lambda r: (
            r["event"] == "mitigation"
            and r["action"] == action
            and all(r.get(k) == v for k, v in match.items())
        ),
        f"a {action} mitigation record {match}",
        timeout=20,
    )


def reset_cli() -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "supervisor", "reset", "--timeout", "15"],
        cwd=ROOT,
        env={**os.environ, **ROS_ENV},
        capture_output=True,
        text=True,
        timeout=60,
    )


LATCHED = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)


def test_latched_halt_and_operator_reset(tmp_path: Path, robot_node: Any) -> None:
    config = variant(tmp_path, req103("{latch: true, repeat_ms: 300}"))
    d = start(tmp_path, config)
    try:
        robot = Robot(robot_node)
        robot.matched()  # discovery first: t_burst is just before the first burst
        t_burst = time.monotonic()
        v = robot.violate(
            d,
            lambda r: r["event"] == "violation" and r["requirement"] == "state_req103",
            "violation",
        )
        first = mitigation(d, "stop_robot", requirement="state_req103", stage="violation")
        assert first["ok"] is True and first["kind"] == "publish"
        # The violation record is on disk before the action (and before its record).
        lines = [json.loads(x) for x in d.log.read_text().splitlines()]
        assert lines.index(v) < lines.index(first)
        # from the violation's detection to the action's end: within the time this
        # test took from the violating burst to reading the record
        assert 0 < first["latency_ms"] <= 1000 * (time.monotonic() - t_burst), first

        # A controller that starts after the violation still sees the halt.
        halts: list[bool] = []
        robot_node.create_subscription(Bool, "/sRobotHalt", lambda m: halts.append(m.data), LATCHED)
        spin_until(robot_node, "the latched halt", lambda: True in halts, 10)
        mitigation(d, "stop_robot", requirement="state_req103", stage="repeat")

        # Still violated: the operator reset is refused and says why.
        robot.publish(VIOLATING, gap_before_trigger=0.01)
        refused = reset_cli()
        assert refused.returncode == 1, refused
        assert "state_req103" in refused.stdout and "still violated" in refused.stdout

        # The robot stops: the requirement holds again; now the reset is accepted.
        def accepted() -> bool:
            robot.publish(HOLDING)
            return reset_cli().returncode == 0

        wait_until("an accepted operator reset", accepted, 30, d.explain)
        d.wait_record(
            lambda r: (
                r["event"] == "reset"
                and r["requirement"] == "state_req103"
                and r["reason"] == "operator reset: latch released"
            ),
            "latch released",
        )
        d.terminate()
    finally:
        d.close()


# ------------------------------------------------------------------ ssh


def ssh_mitigation(params: dict[str, Any]) -> str:
    inner = ", ".join(f"{k}: {json.dumps(v)}" for k, v in params.items())
    return f"  power_off:\n    ssh: {{{inner}}}\n"


def with_ssh(config: Path, params: dict[str, Any]) -> Path:
    text = config.read_text()
    start_ = text.index("  power_off:\n")
    end = text.index("\nlogging:")
    config.write_text(text[:start_] + ssh_mitigation(params) + text[end:])
    return config


@pytest.mark.sshd
def test_ssh_shutdown_runs_on_the_robot(tmp_path: Path, robot_node: Any, sshd: Any) -> None:
    marker = tmp_path / "powered-off"
    config = variant(tmp_path, req103("{reset: after_mitigation}", "[power_off]"))
    with_ssh(config, sshd.params(f"touch {marker}"))
    d = start(tmp_path, config)
    try:
        robot = Robot(robot_node)
        rec = robot.violate(
            d,
            lambda r: r["event"] == "mitigation" and r["action"] == "power_off",
            "the power_off record",
        )
        assert rec["ok"] is True, rec
        assert rec["kind"] == "ssh" and rec["detail"]["exit_status"] == 0
        assert marker.exists()
        d.terminate()
    finally:
        d.close()


@pytest.mark.sshd
def test_wrong_host_key_refused_and_escalation_continues(
    tmp_path: Path, robot_node: Any, sshd: Any
) -> None:
    marker = tmp_path / "must-not-exist"
    other = keygen(tmp_path / "other_host_key")
    wrong = tmp_path / "known_hosts_wrong"
    wrong.write_text(known_hosts_line(sshd.host, sshd.port, other))
    config = variant(
        tmp_path,
        req103(
            "{reset: after_mitigation, escalate: {after_ms: 300, actions: [stop_robot]}}",
            "[power_off]",
        ),
    )
    with_ssh(config, sshd.params(f"touch {marker}", known_hosts=str(wrong)))
    d = start(tmp_path, config)
    try:
        robot = Robot(robot_node)
        robot.matched()
        robot.publish(S0)
        t_end = time.monotonic() + 20
        esc = None
        while esc is None and time.monotonic() < t_end:
            robot.publish(VIOLATING)  # the violation persists
            esc = next(
                (
                    r
                    for r in d.records()
                    if r["event"] == "mitigation" and r.get("stage") == "escalation"
                ),
                None,
            )
            time.sleep(0.05)  # the robot's publishing period
        assert esc is not None, d.explain()
        assert esc["action"] == "stop_robot" and esc["ok"] is True
        refused = mitigation(d, "power_off", requirement="state_req103")
        assert refused["ok"] is False and "host key" in refused["error"]
        assert refused["attempt"] == 1
        assert not marker.exists()
        d.terminate()
    finally:
        d.close()


@pytest.mark.sshd
def test_sshd_down_retries_while_monitoring_goes_on(
    tmp_path: Path, robot_node: Any, sshd: Any
) -> None:
    params = sshd.params("true", port=free_port(), retries=4, backoff_s=0.3, connect_timeout_s=1)
    config = variant(tmp_path, req103("{reset: after_mitigation}", "[power_off]"))
    with_ssh(config, params)
    d = start(tmp_path, config)
    try:
        robot = Robot(robot_node)
        first = robot.violate(
            d,
            lambda r: r["event"] == "mitigation" and r["action"] == "power_off",
            "the first power_off attempt",
        )
        assert first["attempt"] == 1
        assert first["ok"] is False and "refused" in first["error"].lower(), first
        # While the action backs off and retries, the monitor keeps stepping:
        # a different violation is detected meanwhile.
        other = robot.until(  # state_req000: classifier 0 needs OpState 0
            dict(S0, OpState=1),
            d,
            lambda r: r["event"] == "violation" and r["requirement"] == "state_req000",
            "a violation during the retries",
        )
        last = mitigation(d, "power_off", attempt=4)
        assert last["ok"] is False
        t_other = other["ts"]
        assert t_other < last["ts"], "the monitor waited for the ssh retries"
        attempts = [
            r for r in d.records() if r["event"] == "mitigation" and r["action"] == "power_off"
        ]
        assert [r["attempt"] for r in attempts[:4]] == [1, 2, 3, 4]
        d.terminate()
    finally:
        d.close()
