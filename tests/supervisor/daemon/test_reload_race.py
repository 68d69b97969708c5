"""A reload reads the config once: the monitor, the analyses (in their child
process) and the hash the reload record names are of the same bytes, however the
file is edited while the reload runs (docs/ARCHITECTURE.md, "The stages").

The edit is made at the one moment it could split them: after the daemon has read
the file, before the analyses' child starts (a hook around
``supervisor.children.start``, the one way a child starts).  The rest is real: the
daemon's ``prepare_session`` (what SIGHUP and ``safety-supervisor reload`` run),
gcc, the child and z3.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pytest

from monitors.errors import UserError
from supervisor import children
from supervisor.daemon.process import prepare_session

# Long traces (k) put the analyses of even this small set in the child process.
CLEAN = """\
component: sw
step: {policy: periodic, period_ms: 100}
variables:
  p: {type: bool, topic: /p, msg: std_msgs/msg/Bool}
  x: {type: int64, topic: /x, msg: std_msgs/msg/Int64}
requirements:
  - id: r1
    text: upon x > 3 sw shall within 1 second satisfy p
"""
CONFLICT = """\
  - id: r2
    text: sw shall always satisfy !p
  - id: r3
    text: sw shall always satisfy p
"""
ANALYSIS = "analysis: {k: 1000}\n"
GOOD = CLEAN + ANALYSIS
BAD = CLEAN + CONFLICT + ANALYSIS  # the analyses find r2 and r3 in conflict


def sha256(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def edit_when_the_child_starts(
    monkeypatch: pytest.MonkeyPatch, config: Path, text: str
) -> list[Sequence[str]]:
    """Write ``text`` into ``config`` just before the analyses' child starts; the
    argv of each child started so."""
    real: Callable[..., Any] = children.start
    started: list[Sequence[str]] = []

    def start(argv: Sequence[str], **kw: Any) -> Any:
        if any("analysis" in a for a in argv):
            config.write_text(text)
            started.append(argv)
        return real(argv, **kw)

    monkeypatch.setattr(children, "start", start)
    return started


@pytest.mark.slow  # gcc and a z3 child process
def test_a_good_config_edited_into_a_bad_one_mid_reload_reloads_the_good_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = tmp_path / "c.yaml"
    config.write_text(GOOD)
    started = edit_when_the_child_starts(monkeypatch, config, BAD)
    session = prepare_session(str(config), tmp_path / "build")
    try:
        assert started, "the analyses ran in the daemon: the race needs the child"
        assert config.read_text() == BAD  # the edit happened, mid-reload
        # What the reload record's config_sha256 is (SupervisorNode._reload_step):
        assert session.config.sha256 == sha256(GOOD)
        assert [r.id for r in session.requirements] == ["r1"]
    finally:
        if session.cleanup is not None:
            session.cleanup()


@pytest.mark.slow
def test_a_bad_config_edited_into_a_good_one_mid_reload_is_refused_for_its_findings(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = tmp_path / "c.yaml"
    config.write_text(BAD)
    started = edit_when_the_child_starts(monkeypatch, config, GOOD)
    with pytest.raises(UserError) as e:
        prepare_session(str(config), tmp_path / "build")
    assert started and config.read_text() == GOOD
    # The findings of what was read and compiled, not of the file as it is now.
    assert "analysis: conflict (r2, r3)" in str(e.value), e.value


@pytest.mark.slow
def test_findings_for_another_config_are_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A child given other bytes (and their hash) than the daemon read: it judges
    # them and says so, and the daemon takes none of its findings.
    from supervisor.analysis_child import Aside, _payload
    from supervisor.config import ConfigSource, read_config

    config = tmp_path / "c.yaml"
    config.write_text(GOOD)
    other = tmp_path / "other"
    real: Callable[..., Any] = children.start

    def start(argv: Sequence[str], **kw: Any) -> Any:
        argv = [sha256(BAD) if a == sha256(GOOD) else a for a in argv]
        other.write_bytes(_payload(ConfigSource.of(config, BAD.encode())))
        with other.open("rb") as stdin:
            return real(argv, **{**kw, "stdin": stdin})

    monkeypatch.setattr(children, "start", start)
    checked = Aside(read_config(config)).result()
    assert checked.skipped == f"the analyses' process judged another config (sha256 {sha256(BAD)})"
    assert checked.errors == [] and checked.project.config.sha256 == sha256(GOOD)


IMPORTING = """\
component: sw
step: {policy: periodic, period_ms: 100}
variables:
  p: {type: bool, topic: /p, msg: std_msgs/msg/Bool}
  x: {type: int64, topic: /x, msg: std_msgs/msg/Int64}
requirements_from: reqs.json
analysis: {k: 1000}
"""


def _fret(*texts: str) -> str:
    return json.dumps([{"reqid": f"r{i}", "fulltext": t} for i, t in enumerate(texts, 1)])


@pytest.mark.slow
def test_an_imported_file_edited_mid_reload_is_judged_as_it_was_read(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The child is given the imported FRET file's bytes as the daemon read them:
    # the findings are of the requirements compiled, not of the file as it is now.
    config = tmp_path / "c.yaml"
    config.write_text(IMPORTING)
    fret = tmp_path / "reqs.json"
    fret.write_text(_fret("upon x > 3 sw shall within 1 second satisfy p"))
    conflict = _fret(
        "upon x > 3 sw shall within 1 second satisfy p",
        "sw shall always satisfy !p",
        "sw shall always satisfy p",
    )
    started = edit_when_the_child_starts(monkeypatch, fret, conflict)
    session = prepare_session(str(config), tmp_path / "build")
    try:
        assert started, "the analyses ran in the daemon: the race needs the child"
        assert fret.read_text() == conflict  # the edit happened, mid-reload
        assert [r.id for r in session.requirements] == ["r1"]
    finally:
        if session.cleanup is not None:
            session.cleanup()


def _analyses_child_of(pid: int) -> bool:
    """Whether ``pid`` has a child process running the analyses."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue  # gone meanwhile
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        if ppid == pid and b"analysis" in cmdline:
            return True
    return False


@pytest.mark.ros
def test_a_daemon_reloaded_while_the_file_is_saved_again_runs_and_records_one_config(
    tmp_path: Path,
) -> None:
    # The real daemon and SIGHUP. The edit lands once the daemon has started the
    # analyses' child, so after the daemon's read: /proc is polled, as no event
    # says that a process started another.
    import signal
    import time

    from rosutil import Daemon

    config = tmp_path / "c.yaml"
    config.write_text(CLEAN)  # small: analysed in the daemon itself
    d = Daemon(tmp_path, config)
    try:
        d.wait_notify("READY=1", timeout=120)
        config.write_text(GOOD)
        d.proc.send_signal(signal.SIGHUP)
        deadline = time.monotonic() + 60
        while not _analyses_child_of(d.proc.pid):
            assert time.monotonic() < deadline, d.explain()
            assert d.proc.poll() is None, d.explain()
            time.sleep(0.005)
        config.write_text(BAD)
        d.wait_record(lambda r: r.get("what") == "reload", "the reload record", timeout=120)
        [reload] = [r for r in d.records() if r.get("what") == "reload"]
        assert reload["ok"] is True, reload.get("why")
        assert reload["config_sha256"] == sha256(GOOD), reload
        d.terminate()
    finally:
        d.close()
