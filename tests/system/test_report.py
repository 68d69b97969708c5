"""``report``: one HTML file about violation logs (docs/reference/commands.md, "report").

Logs are made by ``replay`` of JSON-lines traces written here, so every violation's
tick and every subformula's value is known; the page is opened in headless Chromium
(Debian's) with every console message and request recorded. The recorded daemon run
(``run --record``) is at the end (ros, slow)."""

from __future__ import annotations

import gzip
import json
import re
import shutil
import subprocess
import sys
import time
from html import unescape
from pathlib import Path
from typing import Any

import pytest
from browser import CHROMIUM, eval_all, open_page

from mitigations.violationlog.reader import iter_records
from supervisor.cli import main

CONFIG = """\
component: R
step: {policy: on_message}
logging: {recent: 2}
variables:
  speed: {type: double, topic: /speed, msg: std_msgs/msg/Float64}
  halted: {type: bool, topic: /halted, msg: std_msgs/msg/Bool}
requirements:
  - id: limit
    text: R shall always satisfy speed <= 2.0
    rationale: the arm is rated to 2 m/s
    on_violation: [note]
    policy: {reset: after_mitigation}
  - id: react
    text: Upon speed > 3.0 R shall within 3 ticks satisfy halted
    on_violation: [note]
  - id: calm
    text: R shall always satisfy speed >= 0.0
    on_violation: [note]
mitigations:
  note: {log: {message: violated}}
"""
# tick:    0    1    2    3    4    5    6    7    8    9
SPEEDS = [1.0, 1.5, 2.5, 1.0, 3.5, 1.0, 1.2, 1.1, 1.0, 0.5]
# limit is violated at ticks 2 and 4 (reset after each), react at tick 7 (3.5 at 4,
# halted never): ticks 5..7 without halted. calm never.


def run(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "supervisor", *args], capture_output=True, text=True,
        timeout=timeout,
    )  # fmt: skip


@pytest.fixture
def logged(tmp_path: Path) -> tuple[Path, Path, Path]:
    """(config, trace, log): a replay's log of the trace."""
    config = tmp_path / "r.yaml"
    config.write_text(CONFIG)
    trace = tmp_path / "trace.jsonl"
    rows = [{"t_ns": 10**9, "name": "halted", "value": False}]
    rows += [
        {"t_ns": 10**9 + (i + 1) * 100_000_000, "name": "speed", "value": s}
        for i, s in enumerate(SPEEDS)
    ]
    trace.write_text("".join(json.dumps(r) + "\n" for r in rows))
    log = tmp_path / "log.jsonl"
    r = run("replay", str(config), str(trace), "-o", str(log), "--quiet")
    assert r.returncode == 0, r.stderr
    return config, trace, log


def why_cells(html: str, requirement: str, tick: int) -> dict[str, dict[int, str]]:
    """The why-tree of one violation: subformula text -> {tick: shown value}."""
    m = re.search(
        rf"<div class='why' id='v\d+' data-requirement='{requirement}' data-tick='{tick}'>"
        r"(.*?)</table>",
        html,
        re.S,
    )
    assert m, f"no why-tree of {requirement} at tick {tick}"
    out: dict[str, dict[int, str]] = {}
    for text, cells in re.findall(
        r"<tr class='node[^']*' data-text='([^']*)'[^>]*>(.*?)</tr>", m[1]
    ):
        out[unescape(text)] = {
            int(t): v for t, v in re.findall(r"data-tick='(\d+)'>([^<]*)</td>", cells)
        }
    return out


def test_report_from_the_log_alone(logged: tuple[Path, Path, Path], tmp_path: Path) -> None:
    config, _trace, log = logged
    out = tmp_path / "report.html"
    assert main(["report", str(log), "-o", str(out), "--quiet"]) == 0
    html = out.read_text()
    assert "Hash chain verified" in html
    # the config is the one the log's replay record names, unchanged: its reading
    assert "the arm is rated to 2 m/s" in html and "Scope: the whole execution" in html
    limit = why_cells(html, "limit", 2)
    assert limit["(speed <= 2.0)"] == {1: "T", 2: "F"}  # recent: 2 ticks
    assert limit["(H (speed <= 2.0))"][2] == "F"
    # the second violation is judged from the reset after the first (tick 3)
    assert why_cells(html, "limit", 4)["(speed <= 2.0)"] == {3: "T", 4: "F"}
    # react's cause (tick 4) is older than the record's 2 ticks: said, not explained
    assert "the window is too short" in html
    assert not re.search(r"<a [^>]*><line class='mk", html)  # (markers are SVG, double quotes)
    assert html.count('class="mk violation"') == 3


SPEED_LINE = "  speed: {type: double, topic: /speed, msg: std_msgs/msg/Float64}\n"


def _speed_from_import(config: Path) -> Path:
    """The config's ``speed`` input moved to ``variables_from: v.txt`` beside it:
    the same inputs, read from an import; the import's path."""
    text = config.read_text()
    assert SPEED_LINE in text
    config.write_text(
        text.replace(SPEED_LINE, "").replace("variables:\n", "variables_from: v.txt\nvariables:\n")
    )
    imported = config.parent / "v.txt"
    imported.write_text('("speed","double","/speed","double")\n')
    return imported


def test_an_import_edited_since_the_log_is_not_read_as_the_logs_config(
    logged: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    """The log's records carry the config file's hash; an edited ``variables_from``
    (or FRET export) under the same file judged with other inputs.  The replay record
    names the imports' hashes, and the report does not read the log with the edited
    ones: without ``--config`` it goes on without a config, with it it refuses."""
    config, trace, _log = logged
    imported = _speed_from_import(config)
    log = tmp_path / "imports.jsonl"
    assert run("replay", str(config), str(trace), "-o", str(log), "--quiet").returncode == 0
    start = next(r for r in iter_records(str(log)) if r.get("what") == "replay")
    assert list(start["imports"]) == ["v.txt"]
    out = tmp_path / "report.html"
    assert main(["report", str(log), "-o", str(out), "--quiet"]) == 0
    assert "the arm is rated to 2 m/s" in out.read_text()  # read with the config
    imported.write_text('("speed","float","/speed","double")\n')
    assert main(["report", str(log), "-o", str(out), "--quiet"]) == 0
    html = out.read_text()
    assert "the arm is rated to 2 m/s" not in html and "its import v.txt is not the one" in html
    r = run("report", str(log), "--config", str(config), "-o", str(out))
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert f"{config}:" in r.stderr and "its import v.txt is not the one" in r.stderr


def test_a_config_whose_imports_the_last_run_names_reads_logs_of_an_earlier_version(
    logged: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    """An import edited between two runs of one config file (two replays here; a
    daemon's reload after an edited FRET export writes the same into one log): the
    files as the last run had them are the log's config, as a config file among the
    records' hashes is, never refused for the earlier run's."""
    config, trace, _log = logged
    imported = _speed_from_import(config)
    first, second = tmp_path / "first.jsonl", tmp_path / "second.jsonl"
    assert run("replay", str(config), str(trace), "-o", str(first), "--quiet").returncode == 0
    imported.write_text('("speed","double","/speed","double")\n\n')  # same inputs, new bytes
    assert run("replay", str(config), str(trace), "-o", str(second), "--quiet").returncode == 0
    out = tmp_path / "report.html"
    r = run("report", str(first), str(second), "--config", str(config), "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert "the arm is rated to 2 m/s" in out.read_text()


def test_a_config_found_beside_the_log_whose_import_is_gone_is_not_used(
    logged: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    """An import removed since the log was written is a changed import: the config
    found beside the log is not used and the report goes on without it, as for an
    edited one; with ``--config`` it is one line naming the file."""
    config, trace, _log = logged
    imported = _speed_from_import(config)
    log = tmp_path / "imports.jsonl"
    assert run("replay", str(config), str(trace), "-o", str(log), "--quiet").returncode == 0
    imported.unlink()
    out = tmp_path / "report.html"
    r = run("report", str(log), "-o", str(out))
    assert r.returncode == 0, r.stderr
    html = out.read_text()
    assert "the arm is rated to 2 m/s" not in html and "v.txt" in html
    r = run("report", str(log), "--config", str(config), "-o", str(out))
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "v.txt" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.slow
def test_report_with_the_bag_replays_the_whole_window(
    logged: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    config, trace, log = logged
    out = tmp_path / "report.html"
    r = run("report", str(log), "--bag", str(trace), "--config", str(config), "-o", str(out))
    assert r.returncode == 0, r.stderr
    # no progress on a pipe (tests/supervisor/tools/replay/test_replay_names.py)
    assert "wrote" in r.stdout and "\r" not in r.stderr
    html = out.read_text()
    react = why_cells(html, "react", 7)
    assert react["(speed > 3.0)"][4] == "T" and react["halted"][7] == "F"
    assert react[next(t for t in react if t.startswith("(H "))][7] == "F"
    assert "the window is too short" not in html
    assert "replayed from the bag: ticks 0..7" in html
    # the inputs come from the bag: every speed of the trace is on the timeline
    data = json.loads(re.search(r"id='timeline-data'>(.*?)</script>", html)[1])
    speed = next(s for s in data["series"] if s["name"] == "speed")
    assert speed["v"] == SPEEDS


@pytest.mark.slow
def test_rotated_and_compressed_logs_and_a_broken_chain(
    logged: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    log = logged[2]
    gz = tmp_path / "log.jsonl.1.gz"
    gz.write_bytes(gzip.compress(log.read_bytes()))
    config, trace, _ = logged
    later = tmp_path / "later.jsonl"  # a second run, in its own file
    assert run("replay", str(config), str(trace), "-o", str(later), "--quiet").returncode == 0
    out = tmp_path / "a.html"
    assert main(["report", str(later), str(gz), "-o", str(out), "--quiet"]) == 0
    html = out.read_text()
    assert "Hash chain verified: 18 records in 2 file(s)" in html
    assert "<tr class='req-row' data-requirement='limit' data-violations='4'>" in html
    assert html.count('class="mk violation"') == 6

    lines = log.read_text().splitlines(keepends=True)
    n = next(i for i, s in enumerate(lines) if '"event":"violation"' in s)
    lines[n] = lines[n].replace('"speed":2.5', '"speed":1.5')
    edited = tmp_path / "edited.jsonl"
    edited.write_text("".join(lines))
    r = run("report", str(edited), "-o", str(out))
    assert r.returncode == 1  # written, and the chain does not verify
    html = out.read_text()
    assert f"{edited}:{n + 1}: hash chain broken: line was edited" in html
    assert "data-ok='false'" in html


@pytest.mark.slow
def test_errors_are_one_line_naming_the_file(
    logged: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    config, trace, log = logged
    out = str(tmp_path / "x.html")
    garbage = tmp_path / "garbage.jsonl"
    garbage.write_text("not a log\n")
    bad_bag = tmp_path / "bad.mcap"
    bad_bag.write_bytes(b"junk")
    other = tmp_path / "other.yaml"
    other.write_text(CONFIG.replace("2.0", "2.5"))
    moved = tmp_path / "moved.jsonl"
    moved.write_text(log.read_text())
    cases = [
        (["report", str(tmp_path / "none.jsonl"), "-o", out], "none.jsonl"),
        (["report", str(garbage), "-o", out], "garbage.jsonl"),
        (
            ["report", str(log), "--bag", str(bad_bag), "--config", str(config), "-o", out],
            "bad.mcap",
        ),
        (["report", str(log), "--bag", str(tmp_path / "nobag"), "-o", out], "nobag"),
        (["report", str(log), "--config", str(other), "-o", out], "other.yaml"),
    ]
    # last: the config the log names has changed since
    cases.append((["report", str(moved), "--bag", str(trace), "-o", out], str(config)))
    for argv, name in cases:
        if argv[1] == str(moved):
            config.write_text(CONFIG + "# edited\n")
        r = run(*argv)
        assert r.returncode == 1, (argv, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and name in lines[0] and "Traceback" not in r.stderr, r.stderr


# ---------------------------------------------------------------- in the browser


def check_page(path: Path, log: Path) -> Any:
    """Opens offline, quietly; one marker per violation; zoom and hover work."""
    records = list(iter_records(str(log)))
    violated = {r["requirement"] for r in records if r["event"] == "violation"}
    pw, page, console, requests = open_page(path.as_uri())
    try:
        rows = eval_all(
            page, ".req-row", "rs => rs.map(r => [r.dataset.requirement, +r.dataset.violations])"
        )
        assert violated <= {rid for rid, n in rows if n > 0}
        markers = eval_all(
            page,
            "#timeline .mk.violation",
            "ms => ms.map(m => [m.dataset.requirement, +m.dataset.tick])",
        )
        want = [(r["requirement"], r["tick"]) for r in records if r["event"] == "violation"]
        assert sorted(map(tuple, markers)) == sorted(want)
        assert page.locator("#timeline #axis text").count() > 2  # the script drew the axis
        box = page.locator("#timeline").bounding_box()
        x, y = box["x"] + box["width"] * 0.6, box["y"] + box["height"] * 0.5
        page.mouse.move(x, y)
        assert page.locator("#tip").is_visible() and "t = " in page.locator("#tip").inner_text()
        before = page.get_attribute("#zoom", "transform")
        page.mouse.wheel(0, -600)
        page.wait_for_function(
            "b => document.getElementById('zoom').getAttribute('transform') !== b", arg=before
        )
        page.dblclick("#timeline")
        assert console == [], console
        assert requests == [path.as_uri()], requests
        # every why-tree as the DOM holds it: "req@tick" -> subformula -> {tick: value}
        return page.evaluate(
            """() => Object.fromEntries([...document.querySelectorAll('.why')].map(w => [
                 w.dataset.requirement + '@' + w.dataset.tick,
                 Object.fromEntries([...w.querySelectorAll('tr.node')].map(tr => [
                   tr.dataset.text,
                   Object.fromEntries([...tr.querySelectorAll('td[data-tick]')].map(
                     td => [td.dataset.tick, td.textContent]))]))]))"""
        )
    finally:
        pw.stop()


@pytest.mark.slow
def test_the_page_opens_offline_with_every_violation_and_its_why_tree(
    logged: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    config, trace, log = logged
    out = tmp_path / "report.html"
    r = run("report", str(log), "--bag", str(trace), "-o", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    trees = check_page(out, log)
    assert trees["limit@2"]["(speed <= 2.0)"] == {"0": "T", "1": "T", "2": "F"}
    assert trees["limit@4"]["(speed <= 2.0)"] == {"3": "T", "4": "F"}  # since the reset
    react = trees["react@7"]
    assert react["(speed > 3.0)"]["4"] == "T"
    assert [react["halted"][k] for k in "567"] == ["F", "F", "F"]


# ---------------------------------------------------------------- a recorded daemon run


RECORDED = """\
component: R
step: {policy: periodic, period_ms: 20, stale_after_ms: 300}
variables:
  speed: {type: double, topic: /speed, msg: std_msgs/msg/Float64}
  halted: {type: bool, topic: /halted, msg: std_msgs/msg/Bool}
requirements:
  - id: limit
    text: R shall always satisfy speed <= 2.0
    on_violation: [note]
    policy: {debounce_steps: 2, cooldown_ms: 100, reset: after_mitigation}
  - id: halt_when_fast
    text: R shall always satisfy speed > 3.0 -> halted
    on_violation: [note]
    policy: {latch: true, repeat_ms: 100}
on_stale: [note]
mitigations:
  note: {log: {message: violated}}
"""


@pytest.mark.ros
@pytest.mark.slow
def test_a_report_of_a_recorded_daemon_run(tmp_path: Path) -> None:
    pytest.importorskip("rclpy")
    from rosutil import Daemon, ros_node, wait_matched
    from std_msgs.msg import Bool, Float64

    config = tmp_path / "r.yaml"
    config.write_text(RECORDED)
    bags = tmp_path / "bags"
    with ros_node() as node:
        d = Daemon(tmp_path, config, args=["--record", str(bags)])
        try:
            d.wait_notify("READY=1", timeout=30)
            speed = node.create_publisher(Float64, "/speed", 10)
            halted = node.create_publisher(Bool, "/halted", 10)
            wait_matched([speed, halted])
            halted.publish(Bool(data=False))
            for value, seconds in ((1.0, 0.3), (2.5, 0.3), (3.5, 0.1), (1.0, 0.3)):
                end = time.monotonic() + seconds
                while time.monotonic() < end:
                    speed.publish(Float64(data=value))
                    time.sleep(0.02)
            d.wait_record(lambda r: r["event"] == "violation", "a violation")
            d.terminate(budget=10)
        finally:
            d.close()
    out = tmp_path / "report.html"
    # the config beside the log (its SHA-256 is the log's config_sha256)
    r = run("report", str(d.log), "--bag", str(bags), "-o", str(out), timeout=120)
    assert r.returncode == 0, r.stderr
    html = out.read_text()
    assert "Hash chain verified" in html and "replayed from the bag" in html
    assert "window is too short" not in html
    for what in ("start", "ready", "stop"):
        assert f"<td>{what}</td>" in html
    if shutil.which(CHROMIUM) or Path(CHROMIUM).exists():
        check_page(out, d.log)
