"""A violation's record reaches ``published`` (the daemon's violations topic) after
the step's actions are submitted, so the halt does not wait for the record's dict
(supervisor/daemon/core.py); it is the record written to the log, field for field.
Real compiled monitor, real violation log."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path
from typing import Any

from mitigations.violationlog.writer import ViolationLog
from monitors.backends.load import compile_spec
from supervisor.daemon.core import Core
from supervisor.daemon.session import build_session
from supervisor.pipeline import project_for

MS = 1_000_000
CONFIG = """\
component: rover
step: {policy: on_message}
variables:
  speed: {type: double, topic: /speed, msg: std_msgs/msg/Float64}
  halted: {type: bool, topic: /halted, msg: std_msgs/msg/Bool}
requirements:
  - id: limit
    text: rover shall always satisfy speed <= 2.0
    on_violation: [stop]
    policy: {reset: after_mitigation}
  - id: held
    text: rover shall always satisfy speed < 2.5 | halted
    on_violation: [stop]
    policy: {reset: after_mitigation}
mitigations:
  stop: {log: {message: stop}}
"""
HEADER = {"ts", "event", "component", "config_sha256", "prev_sha256", "seq", "line_sha256"}


def test_the_published_record_follows_the_actions_and_is_the_logged_one(tmp_path: Path) -> None:
    (tmp_path / "c.yaml").write_text(textwrap.dedent(CONFIG))
    project = project_for(tmp_path / "c.yaml", ros=False)
    assert project.ok, project.first_error()
    session = build_session(project, compile_spec(project.spec(), tmp_path / "build"))
    order: list[tuple[str, Any]] = []
    log = ViolationLog(tmp_path / "v.jsonl", "rover", "00", echo=False)
    core = Core(
        session,
        log,
        lambda request: order.append(("submit", request.requirement)),
        published=lambda record: order.append(("published", record)),
        warn=lambda _text: None,
    )
    core.start(0)
    core.fields([("speed", 1.0), ("halted", False)], 1 * MS)
    core.fields([("speed", 3.0)], 2 * MS)  # both requirements violated at one step
    log.close()
    assert [(k, r if k == "submit" else r["requirement"]) for k, r in order] == [
        ("submit", "limit"),
        ("submit", "held"),
        ("published", "limit"),
        ("published", "held"),
    ]
    written = [json.loads(x) for x in (tmp_path / "v.jsonl").read_bytes().splitlines()]
    violations = [r for r in written if r["event"] == "violation"]
    published = [r for k, r in order if k == "published"]
    assert len(violations) == 2
    for logged, record in zip(violations, published, strict=True):
        assert {k: v for k, v in logged.items() if k not in HEADER} == record
