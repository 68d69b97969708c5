"""What a start pays for: importing the CLI, the daemon core or running ``check``
from the start-up cache loads no action kind, paramiko, z3 or numpy until a
mitigation, an analysis or a reduction uses them (docs/BENCHMARKS.md, "Start-up").

Each case runs in a fresh interpreter, so nothing an earlier test imported counts.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

HEAVY = (
    "paramiko",
    "z3",
    "numpy",
    "mitigations.actions.ssh",
    "mitigations.actions.command",
    "mitigations.actions.log",
)
# A config whose check needs none of them: std_msgs types, a publish action.
CONFIG = """\
component: sw
step: {policy: periodic, period_ms: 100}
variables:
  p: {type: bool, topic: /p, msg: std_msgs/msg/Bool}
  x: {type: int64, topic: /x, msg: std_msgs/msg/Int64}
requirements:
  - id: r1
    text: upon x > 3 sw shall within 1 second satisfy p
    on_violation: [halt]
mitigations:
  halt: {publish: {topic: /halt, msg: std_msgs/msg/Bool, value: {data: true}}}
"""


def loaded(
    code: str, env: dict[str, str] | None = None, names: tuple[str, ...] = HEAVY
) -> list[str]:
    """The modules of ``names`` that ``code`` leaves loaded in a fresh interpreter."""
    found = f"sorted(m for m in sys.modules if m in {names!r})"
    probe = f"import json, sys\n{code}\nprint(json.dumps({found}))"
    base = {k: v for k, v in os.environ.items() if k != "STATE_DIRECTORY"}
    r = subprocess.run(
        [sys.executable, "-c", probe],
        capture_output=True,
        text=True,
        env={**base, **(env or {})},
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_the_cli_and_its_help_load_none_of_them() -> None:
    code = "import supervisor.cli\nsupervisor.cli.build_parser().format_help()"
    # --help needs neither ROS, the analyses' module nor the config parser either, nor
    # the compiler, a demo's session or the installer's package metadata.
    also = (
        "rclpy",
        "supervisor.analysis_report",
        "lark",
        "supervisor.pipeline",
        "monitors.backends.build",
        "supervisor.tools.demo.session",
        "importlib.metadata",
    )
    assert loaded(code, names=(*HEAVY, *also)) == []


def test_importing_the_cli_takes_well_under_a_second() -> None:
    # A sanity bound, not the goal: bench --startup prints the figure against its
    # 150 ms goal (docs/BENCHMARKS.md, "Start-up"); a shared CI machine may be slow.
    r = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", "import supervisor.cli"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    rows = [line.split("|") for line in r.stderr.splitlines() if line.count("|") == 2]
    cumulative_us = {row[2].strip(): int(row[1]) for row in rows if row[1].strip().isdigit()}
    assert cumulative_us["supervisor.cli"] < 1_000_000, cumulative_us["supervisor.cli"]


def test_the_daemon_core_loads_none_of_them() -> None:
    assert loaded("import supervisor.daemon.core") == []
    assert loaded("import supervisor.daemon.process") == []


def test_check_from_the_cache_loads_none_of_them(tmp_path: Path) -> None:
    config = tmp_path / "supervisor.yaml"
    config.write_text(CONFIG)
    state = tmp_path / "state"
    state.mkdir()
    env = {"STATE_DIRECTORY": str(state)}
    code = (
        "import supervisor.cli\n"
        f"rc = supervisor.cli.main(['check', {str(config)!r}])\n"
        "assert rc == 0, rc\n"
    )
    first = loaded(code, env)
    assert "z3" in first  # the cold check analyses: the probe sees z3 when it is there
    assert loaded(code, env) == []


def test_a_fleet_worker_loads_no_action_backend(tmp_path: Path) -> None:
    """A ``fleet replay`` worker's whole path: the fork server's imports, the config
    compiled as the worker starts, one bag replayed.  A replay runs no action, so an
    SSH mitigation in the config costs no paramiko (0.08 s of every worker's start),
    and a replay writes no log, so no structlog either (0.07 s of the fork server's
    imports: docs/BENCHMARKS.md, "Fleet")."""
    from tests.supervisor.tools.replay.test_replay import config, messages, write_bag

    cfg = config(tmp_path)
    text = cfg.read_text().replace("on_violation: [note]", "on_violation: [note, power_off]", 1)
    cfg.write_text(
        text
        + "  power_off: {ssh: {host: robot-pc.local, user: robot, key: /nonexistent/key,\n"
        + "        known_hosts: /nonexistent/known_hosts, command: poweroff}}\n"
    )
    bag = write_bag(tmp_path / "b1", messages(1, 2000))
    state = tmp_path / "state"
    state.mkdir()
    code = (
        "import importlib\n"
        "from supervisor.tools.fleet import server\n"
        "for m in server.PRELOAD: importlib.import_module(m)\n"
        "from supervisor.tools.fleet.task import BagTask, compile_config, run_task\n"
        f"identity = compile_config({str(cfg)!r})\n"
        "assert isinstance(identity, str)\n"
        f"r = run_task(BagTask({str(bag)!r}, 'r', {str(cfg)!r}, identity))\n"
        "assert r.status == 'read' and r.violations.num_rows > 0, (r.status, r.reason)\n"
    )
    # numpy is pyarrow's own import, which the dataset needs
    names = (
        *(n for n in HEAVY if n != "numpy"),
        "rclpy",
        "cryptography",
        "nacl",
        "invoke",
        "structlog",
    )
    assert loaded(code, {"STATE_DIRECTORY": str(state)}, names=names) == []
