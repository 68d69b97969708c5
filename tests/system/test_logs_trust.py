"""A violation log is attacker-controlled input: its hash chain has no key, so anyone
who can write a file can write a log that verifies (docs/reference/faults.md,
"Trust").  ``logs`` and ``report`` are run here, in process and as the real command,
on crafted logs whose chain is recomputed as the format defines it (tests/support/logcraft.py):
records of the wrong shape are skipped with one located line and counted, nothing
reaches a terminal as control sequences or the report page as markup, ``report``
opens no path a log names, and a compressed log is inflated within a bound."""

from __future__ import annotations

import gzip
import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import zlib
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import pytest
from browser import open_page
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from logcraft import DEEP, chain, record

from supervisor.cli import main

# Anything a terminal could act on: C0 but newline, DEL, C1, and the format characters
# that reorder or hide text (what monitors/untrusted.py's printable escapes).
RAW_CONTROL = re.compile(r"[\x00-\x09\x0b-\x1f\x7f-\x9f\u200b-\u200f\u202a-\u202e\u2066-\u2069]")
NASTY = "\x1b]0;pwned\x07\x1b[2J\rover\x9b31m\u202eevil\x00"
INJECT = "</script><b id=pwn1>x</b><!--<script><img id=pwn2 src=x>"


def write_log(
    tmp_path: Path, records: list[dict[str, Any]], name: str = "v.jsonl", raw: Any = None
) -> Path:
    path = tmp_path / name
    path.write_bytes(chain(records, raw))
    return path


def cli(argv: list[str], capsys: Any) -> tuple[int, str, str]:
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


def commands(log: Path, out: Path) -> list[list[str]]:
    f = str(log)
    return [
        ["logs", f],
        ["logs", "--summary", f],
        ["logs", "--summary", "--json", f],
        ["logs", "--why", f],
        ["logs", "--verify", f],
        ["report", f, "-o", str(out), "--quiet"],
    ]


# ---------------------------------------------------------------- records of the wrong shape

BAD = {
    "string_tick": (record("violation", tick="2"), None),
    "list_inputs": (record("violation", inputs=[1, 2]), None),
    "nested_input": (record("violation", inputs={"speed": {"a": 1}}), None),
    "year_1": (record("violation", ts="0001-01-01T00:00:00Z"), None),
    "year_9999": (record("violation", ts="9999-12-31T23:59:59.999999Z"), None),
    "ts_not_a_string": (record("reset", ts=5), None),
    "huge_tick": (record("violation", tick=10**30), None),
    "negative_tick": (record("reset", tick=-1), None),
    "recent_row_not_a_mapping": (record("violation", recent=[5]), None),
    "recent_tick_string": (record("violation", recent=[{"tick": "1", "speed": 1.0}]), None),
    "requirement_a_list": (record("mitigation", requirement=["a"]), None),
    "latency_a_string": (record("mitigation", latency_ms="fast"), None),
    "what_a_mapping": (record("supervisor", what={"a": 1}), None),
    "deep_detail": (record("supervisor", what="check_warning", detail="@deep"), {"@deep": DEEP}),
    "deep_input": (record("violation", inputs={"speed": "@deep"}), {"@deep": DEEP}),
    "long_requirement": (record("violation", requirement="r" * 100_000), None),
    "recorded_ts_year_1": (record("violation", recorded_ts="0001-01-01T00:00:00Z"), None),
    "input_beyond_int64": (record("violation", recent=[{"tick": 2, "speed": 10**400}]), None),
}


def test_a_constant_input_too_large_for_a_float_step_is_drawn(tmp_path: Path, capsys: Any) -> None:
    """Found by the fuzz test below: 2^53+3 and 2^53+3+1 are one float apart from zero."""
    big = 2**53 + 3
    rec = record(
        "violation", inputs={"n": big}, recent=[{"tick": 1, "n": big}, {"tick": 2, "n": big}]
    )
    log = write_log(tmp_path, [record("supervisor"), rec])
    rc, _, err = cli(["report", str(log), "-o", str(tmp_path / "r.html"), "--quiet"], capsys)
    assert rc == 0, err
    check_markup((tmp_path / "r.html").read_text())


def around(bad: dict[str, Any]) -> list[dict[str, Any]]:
    """A start, a violation, the bad record (line 3), a mitigation, a reset."""
    return [record("supervisor"), record("violation"), bad, record("mitigation"), record("reset")]


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_record_of_the_wrong_shape_is_skipped_located_and_counted(
    case: str, tmp_path: Path, capsys: Any
) -> None:
    bad, raw = BAD[case]
    log = write_log(tmp_path, around(bad), raw=raw)
    for argv in commands(log, tmp_path / "r.html"):
        rc, out, err = cli(argv, capsys)
        assert rc != 3 and "internal error" not in err, (argv, err)
        if "--verify" in argv:
            # the chain is the writer's, whatever the records hold
            assert rc == 0 and "5 records, chain intact" in out, (argv, out)
            continue
        assert rc == 0, (argv, err)
        assert f"{log}:3: skipped: " in err, (argv, err)
        assert f"{log}: 1 line skipped" in err, (argv, err)
        assert len(err.strip().splitlines()) == 2, (argv, err)
    # --json: the records that pass, exactly as stored
    lines = log.read_text().splitlines()
    rc, out, _ = cli(["logs", "--json", str(log)], capsys)
    assert out.splitlines() == lines[:2] + lines[3:]


def test_a_line_that_is_not_json_or_not_utf8_is_skipped_too(tmp_path: Path, capsys: Any) -> None:
    log = tmp_path / "v.jsonl"
    good = chain([record("supervisor"), record("violation")])
    log.write_bytes(good + b"\xff\xfe not json\n" + b"[1, 2]\n")
    rc, out, err = cli(["logs", str(log)], capsys)
    assert rc == 0
    assert f"{log}:3: skipped: not UTF-8" in err and f"{log}:4: skipped: " in err
    assert f"{log}: 2 lines skipped" in err
    assert len(out.splitlines()) == 3  # header and the two records


# ---------------------------------------------------------------- terminals


def nasty_log(tmp_path: Path) -> Path:
    return write_log(
        tmp_path,
        [
            record("supervisor", what="start", config=NASTY),
            record(
                "violation",
                requirement=f"req{NASTY}",
                text=NASTY,
                inputs={f"in{NASTY}": 1, "speed": 2.5},
                recent=[{"tick": 2, f"in{NASTY}": 1, "speed": 2.5}],
                stale=[NASTY],
            ),
            record("mitigation", requirement=f"req{NASTY}", action=NASTY, ok=False, error=NASTY),
            record("reset", requirement=f"req{NASTY}", reason=NASTY),
            record("supervisor", what=f"input_stale{NASTY}", input=NASTY, detail=NASTY),
        ],
    )


def test_control_characters_never_reach_the_terminal(tmp_path: Path, capsys: Any) -> None:
    log = nasty_log(tmp_path)
    for argv in commands(log, tmp_path / "r.html") + [["logs", "-n", "2", str(log)]]:
        rc, out, err = cli(argv, capsys)
        assert rc in (0, 1), (argv, err)
        assert not RAW_CONTROL.search(out + err), (argv, out + err)
        if argv[:2] == ["logs", str(log)]:
            assert "\\x1b]0;pwned\\x07" in out  # escaped, as journalctl shows them
    rc, out, _ = cli(["logs", "--json", str(log)], capsys)
    assert out == log.read_text()  # --json stays exact (JSON escapes them itself)


# ---------------------------------------------------------------- the config a log names


# A reader of /dev/zero runs out here, not on the shared machine.
LIMITED = ["prlimit", f"--as={2 << 30}"]
# A child's ru_maxrss starts at the size of the process it was forked from (the kernel
# keeps the old image's high-water mark at exec), and the test process is hundreds of
# MB by now: a small wrapper runs the command and writes the peak of its own child.
MEASURED = (
    "import resource, subprocess, sys;"
    f"resource.setrlimit(resource.RLIMIT_AS, ({2 << 30}, {2 << 30}));"
    "rc = subprocess.call(sys.argv[2:]);"
    "open(sys.argv[1], 'w').write(str(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss));"
    "sys.exit(rc)"
)


def _report_traced(log: Path, out: Path, tmp_path: Path) -> tuple[int, str, list[str]]:
    """``report`` as the real command under strace: (exit code, output, paths opened)."""
    trace = tmp_path / "strace.txt"
    argv = ["strace", "-f", "-qq", "-e", "trace=open,openat,openat2", "-o", str(trace)]
    argv += [sys.executable, "-m", "supervisor", "report", str(log), "-o", str(out)]
    r = subprocess.run([*LIMITED, *argv], capture_output=True, text=True, timeout=60)
    opened = re.findall(r'open(?:at2?)?\((?:[^,]*, )?"([^"]*)"', trace.read_text())
    return r.returncode, r.stdout + r.stderr, opened


@pytest.mark.skipif(shutil.which("strace") is None, reason="strace is not installed")
@pytest.mark.parametrize(
    "target", ["secret", "/etc/shadow", "/dev/zero", "fifo", "matching", "link_beside"]
)
def test_report_never_opens_a_path_the_log_names(target: str, tmp_path: Path, capsys: Any) -> None:
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    secret = elsewhere / "secret.yaml"
    secret.write_text("root:$6$SECRET-LINE:19000:0:99999:7:::\n")
    digest = ""  # no config_sha256: a reader that trusted the named path would parse it
    if target == "secret":
        path = str(secret)
    elif target == "fifo":
        path = str(elsewhere / "fifo")
        os.mkfifo(path)
    elif target == "matching":  # even the right config is not opened where the log says
        path, digest = str(secret), hashlib.sha256(secret.read_bytes()).hexdigest()
    elif target == "link_beside":  # a link beside the log is not a config beside it
        path, digest = str(tmp_path / "config.yaml"), "ab" * 32
        os.symlink("/etc/shadow", path)
    else:
        path = target
    records = [record("supervisor", config=path, config_sha256=digest)]
    records += [record(ev, config_sha256=digest) for ev in ("violation", "mitigation")]
    log = write_log(tmp_path, records)
    out = tmp_path / "r.html"
    rc, text, opened = _report_traced(log, out, tmp_path)
    assert rc in (0, 1) and "Traceback" not in text and "internal error" not in text, text
    assert path not in opened, f"report opened {path}"
    page = out.read_text() if out.exists() else ""
    for shown in (text, page):
        # nothing of a file that is not the log's config is ever shown
        assert "SECRET-LINE" not in shown and "root:" not in shown, "a foreign file was echoed"


CONFIG = """\
component: R
step: {policy: on_message}
logging: {recent: 2}
variables:
  speed: {type: double, topic: /speed, msg: std_msgs/msg/Float64}
requirements:
  - id: limit
    text: R shall always satisfy speed <= 2.0
    rationale: the arm is rated to 2 m/s
    on_violation: [note]
mitigations:
  note: {log: {message: violated}}
"""


def test_report_finds_the_config_beside_the_log_by_its_hash(tmp_path: Path, capsys: Any) -> None:
    beside = tmp_path / "incident"
    beside.mkdir()
    (beside / "robot-config.yaml").write_text(CONFIG)
    (beside / "other.yaml").write_text(CONFIG + "# another config\n")
    digest = hashlib.sha256(CONFIG.encode()).hexdigest()
    records = [record("supervisor", config="/opt/robot/r.yaml", config_sha256=digest)]
    records += [record(ev, config_sha256=digest) for ev in ("violation", "mitigation")]
    log = write_log(beside, records)
    out = tmp_path / "r.html"
    rc, stdout, err = cli(["report", str(log), "-o", str(out), "--quiet"], capsys)
    assert rc == 0, err
    html = out.read_text()
    assert "the arm is rated to 2 m/s" in html  # the config's rationale: it was read
    assert str(beside / "robot-config.yaml") in html


# ---------------------------------------------------------------- the page


class Elements(HTMLParser):
    """The page as a real HTML parser sees it: elements, ids, script texts."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.ids: list[str] = []
        self.tags: list[str] = []
        self.scripts: list[str] = []
        self._in_script = False

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append(tag)
        self.ids += [v or "" for k, v in attrs if k == "id"]
        if tag == "script":
            self._in_script = True
            self.scripts.append("")

    def handle_endtag(self, tag: str) -> None:
        if tag == "script":
            self._in_script = False

    def handle_data(self, data: str) -> None:
        if self._in_script:
            self.scripts[-1] += data

    def handle_comment(self, data: str) -> None:
        self.tags.append("!--")


def check_markup(html: str) -> Elements:
    """No text of a record became markup: no injected element, no comment, and no
    script whose text could end it early or start a nested one (the HTML standard's
    script data states: ``<!--`` followed by ``<script`` moves the end tag)."""
    page = Elements()
    page.feed(html)
    page.close()
    assert not [i for i in page.ids if i.startswith("pwn")], page.ids
    assert "img" not in page.tags and "!--" not in page.tags
    assert page.tags.count("script") == 2, page.tags.count("script")
    for text in page.scripts:
        low = text.lower()
        assert "<!--" not in low and "<script" not in low and "</script" not in low, text[:200]
    assert "supervisor" in page.ids  # the page goes on to its last section
    return page


def injection_log(tmp_path: Path) -> Path:
    return write_log(
        tmp_path,
        [
            record("supervisor", what="start", config=INJECT, component=INJECT),
            record(
                "violation",
                requirement=f"r{INJECT}",
                text=INJECT,
                formula=INJECT,
                inputs={INJECT: 1, "speed": 2.5},
                recent=[{"tick": 1, INJECT: 0, "speed": 1.0}, {"tick": 2, INJECT: 1, "speed": 2.5}],
                stale=[INJECT],
                policy_state={INJECT: INJECT},
            ),
            record("mitigation", requirement=f"r{INJECT}", action=INJECT, error=INJECT, ok=False),
            record("reset", requirement=f"r{INJECT}", reason=INJECT),
            record("supervisor", what=INJECT, detail=INJECT),
            record("supervisor", what="input_stale", input=INJECT, detail="silent\u2028for"),
        ],
    )


def test_record_text_never_becomes_markup(tmp_path: Path, capsys: Any) -> None:
    log = injection_log(tmp_path)
    out = tmp_path / "r.html"
    rc, _, err = cli(["report", str(log), "-o", str(out), "--quiet"], capsys)
    assert rc == 0, err
    page = check_markup(out.read_text())
    data = json.loads(page.scripts[0])  # the timeline's data, intact
    assert INJECT in [s["name"] for s in data["series"]]


@pytest.mark.slow
def test_the_injected_page_opens_in_chromium_whole(tmp_path: Path, capsys: Any) -> None:
    log = injection_log(tmp_path)
    out = tmp_path / "r.html"
    assert cli(["report", str(log), "-o", str(out), "--quiet"], capsys)[0] == 0
    pw, page, console, requests = open_page(out.as_uri())
    try:
        assert page.locator("script").count() == 2
        assert page.locator("#pwn1, #pwn2, img").count() == 0
        assert page.locator("#supervisor-table").count() == 1
        assert page.locator("#timeline #axis text").count() > 2  # the script ran
        names = page.evaluate(
            "JSON.parse(document.getElementById('timeline-data').textContent)"
            ".series.map(s => s.name)"
        )
        assert INJECT in names
        assert console == [], console
        assert requests == [out.as_uri()], requests
    finally:
        pw.stop()


# ---------------------------------------------------------------- compressed logs


def _gzip_of_zeros(path: Path, size: int) -> None:
    z = zlib.compressobj(9, zlib.DEFLATED, 31)
    block = bytes(1 << 20)
    with path.open("wb") as f:
        for _ in range(size >> 20):
            f.write(z.compress(block))
        f.write(z.flush())


@pytest.mark.slow
def test_a_gzip_bomb_is_damage_within_bounded_memory(tmp_path: Path) -> None:
    bomb = tmp_path / "v.jsonl.2.gz"
    _gzip_of_zeros(bomb, 3 << 30)  # 3 GiB of zeros in 3 MB
    log = write_log(tmp_path, [record("supervisor"), record("violation")])
    for args in (["--verify"], [], ["--summary"]):
        argv = [sys.executable, "-m", "supervisor", "logs", *args, str(bomb), str(log)]
        peak = tmp_path / "peak"
        p = subprocess.run(
            [sys.executable, "-c", MEASURED, str(peak), *argv], capture_output=True, text=True
        )
        out, err = p.stdout, p.stderr
        assert p.returncode == (1 if args == ["--verify"] else 0), (args, out, err)
        assert "internal error" not in err and "Traceback" not in err, err
        damaged = [s for s in (out + err).splitlines() if str(bomb) in s and "damaged" in s]
        assert len(damaged) == 1, out + err
        kib = int(peak.read_text())
        assert kib < 512 * 1024, kib  # peak memory under 512 MB
        if args == ["--verify"]:
            assert f"{log}: 2 records, chain intact" in out


def test_a_gzip_log_is_read_as_it_is(tmp_path: Path, capsys: Any) -> None:
    data = chain([record("supervisor"), record("violation")])
    gz = tmp_path / "v.jsonl.1.gz"
    gz.write_bytes(gzip.compress(data))
    rc, out, _ = cli(["logs", "--verify", str(gz)], capsys)
    assert rc == 0 and f"{gz}: 2 records, chain intact" in out
    rc, out, _ = cli(["logs", "--json", str(gz)], capsys)
    assert out.encode() == data


# ---------------------------------------------------------------- the kept adversary

_text = st.one_of(
    st.text(max_size=12),
    st.sampled_from([NASTY, INJECT, "</script>", "<!--", "\u2028", "r" * 5000]),
)
_scalar = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), _text)
_value = st.recursive(
    _scalar,
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(_text, inner, max_size=3),
    max_leaves=8,
)
_ts = st.one_of(
    st.just("2026-11-21T14:00:00.000000Z"),
    st.sampled_from(["0001-01-01T00:00:00Z", "9999-12-31T23:59:59.999999Z", "", "yesterday"]),
    st.datetimes().map(lambda d: d.isoformat() + "Z"),
    _value,
)


_name = st.one_of(
    st.text(min_size=1, max_size=12),
    st.sampled_from([NASTY, INJECT, "</script>", "<!--", "a\u2028b"]),
)
# the string fields a valid record may fill with any text
_STRINGS = ("requirement", "text", "formula", "action", "kind", "error", "reason", "what")


@st.composite
def _records(draw: Any) -> dict[str, Any]:
    event = draw(st.sampled_from(["violation", "mitigation", "reset", "supervisor"]))
    rec = record(event)
    for key in draw(st.lists(st.sampled_from(_STRINGS), max_size=4, unique=True)):
        if key in rec:  # valid, with text meant for a terminal or a page
            rec[key] = draw(_name)
    for key in draw(st.lists(st.sampled_from(sorted(rec)), max_size=3, unique=True)):
        if key not in ("prev_sha256", "seq"):
            rec[key] = draw(_ts if key == "ts" else _value)
    if draw(st.booleans()):
        rec[draw(_text)] = draw(_value)
    if event == "violation" and draw(st.booleans()):
        name = draw(_name)
        number = st.integers() | st.floats() | st.booleans()
        rec["inputs"] = {name: draw(number | _scalar)}
        tick = draw(st.integers(-2, 3) | st.integers(0, 2**63) | _value)
        rec["recent"] = [{"tick": tick, name: draw(number | _value)}]
    return rec


@settings(
    max_examples=100,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(st.lists(_records(), min_size=1, max_size=6), st.booleans())
def test_any_crafted_log_is_read_without_an_internal_error(
    tmp_path: Path, capsys: Any, records: list[dict[str, Any]], deep: bool
) -> None:
    raw = None
    if deep:  # one record nested deeper than any parser recurses
        records = [*records, record("supervisor", what="x", detail="@deep")]
        raw = {"@deep": DEEP}
    log = write_log(tmp_path, records, raw=raw)
    out = tmp_path / "r.html"
    out.unlink(missing_ok=True)
    for argv in commands(log, out):
        rc, stdout, err = cli(argv, capsys)
        assert rc != 3 and "internal error" not in err, (argv, err)
        assert not RAW_CONTROL.search(stdout + err), (argv, stdout + err)
    if out.exists():
        check_markup(out.read_text())
    rc, stdout, _ = cli(["logs", "--json", str(log)], capsys)
    stored = set(log.read_text().splitlines())
    assert set(stdout.splitlines()) <= stored  # --json: records as stored, or none


def test_the_real_command_on_a_crafted_log(tmp_path: Path) -> None:
    """Subprocess smoke test: the installed entry point, no traceback, no raw control."""
    log = write_log(
        tmp_path,
        [
            record("supervisor", config=NASTY),
            record("violation", requirement=INJECT, inputs={NASTY: 1}),
            record("violation", tick="2"),
            record("violation", ts="9999-12-31T23:59:59Z"),
            record("mitigation", error=NASTY),
        ],
    )
    out = tmp_path / "r.html"
    for argv in commands(log, out):
        r = subprocess.run(
            [sys.executable, "-m", "supervisor", *argv], capture_output=True, text=True, timeout=60
        )
        assert r.returncode in (0, 1), (argv, r.stderr)
        assert "Traceback" not in r.stderr and not RAW_CONTROL.search(r.stdout + r.stderr)
    check_markup(out.read_text())


@pytest.mark.slow
def test_follow_escapes_and_says_what_it_skips(tmp_path: Path) -> None:
    from tests.supervisor.tools.test_logs_query import _Follow

    live = tmp_path / "v.jsonl"
    live.write_bytes(chain([record("supervisor"), record("violation", tick="x")]))
    f = _Follow("-f", str(live))
    try:
        assert f.take(2)[1].split()[1:3] == ["supervisor", "-"]  # after the header
        with live.open("ab") as out:
            out.write(chain([record("reset", tick=-1), record("violation", requirement=NASTY)]))
        row = f.take(1)[0]
        assert "violation" in row and "\\x1b]0;pwned\\x07" in row
        assert not RAW_CONTROL.search(row)
        assert f.quiet()
        code, err = f.stop(signal.SIGTERM)
        assert code == 0, err
        skipped = [s for s in err.splitlines() if ": skipped: " in s]
        assert len(skipped) == 2 and all(s.startswith(f"{live}: byte ") for s in skipped), err
        assert "tick must be" in skipped[0] and "tick must be" in skipped[1]
    finally:
        if f.proc.poll() is None:
            f.proc.kill()


def test_every_record_the_writer_makes_passes_the_schema(tmp_path: Path, capsys: Any) -> None:
    """The schema is the writer's format: nothing the daemon writes is skipped."""
    from mitigations.violationlog.writer import ViolationLog

    path = tmp_path / "v.jsonl"
    with ViolationLog(path, "R", "ab" * 32, echo=False) as log:
        log.supervisor("start", config=str(tmp_path / "r.yaml"), pid=1)
        log.supervisor("input_stale", input="speed", detail="silent for 612 ms")
        log.violation(
            "limit",
            text="t",
            formula="f",
            tick=2,
            inputs={"speed": float("nan"), "on": True, "n": -(2**63)},
            recent=[{"tick": 2, "speed": float("inf"), "on": True, "n": 1}],
            stale=["speed"],
            policy_state={"flagged_steps": 1, "reset": "after_ms:5", "latched": False},
            formula_inputs="g",
        )
        log.mitigation("limit", action="off", kind="ssh", ok=False, error="e", latency_ms=1.5,
                       stage="violation", detail={"exit_status": 1, "stderr": "x"})  # fmt: skip
        log.mitigation(
            "limit", action="confirm:halt", kind="confirm", ok=True, latency_ms=float("inf")
        )
        log.reset("*", reason="operator reset", tick=3, via="control_socket", refused=[],
                  caller={"uid": 0, "gid": 0, "pid": 1})  # fmt: skip
        log.supervisor("reload", ok=True, config="r.yaml", kept_state=["limit"], tick=4)
        log.supervisor("records_lost", lost=[[5, 9]], count=5, reason="ENOSPC", events={})
        log.supervisor("record_closed", written=1, dropped=0, skipped=0, lost=3, bags=[])
        log.supervisor("stop", ticks=4, violations=1, reloads=1, inputs={"speed": {"nan": 1}})
    rc, out, err = cli(["logs", "--json", str(path)], capsys)
    assert rc == 0 and err == "", err
    assert out == path.read_text()
