"""The ``logs`` command's reading part: table, filters, --summary, on a generated log."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mitigations.violationlog.writer import ViolationLog
from supervisor.cli import main


def _violation(log: ViolationLog, req: str, tick: int) -> None:
    log.violation(req, text="t", formula="f", tick=tick, inputs={"x": tick})


@pytest.fixture
def generated(tmp_path: Path) -> tuple[Path, list[dict]]:
    path = tmp_path / "v.log"
    with ViolationLog(path, "sRobot", "ab" * 32, echo=False) as log:
        log.supervisor("start")
        _violation(log, "A", 1)
        log.mitigation("A", action="stop", kind="topic", ok=True, latency_ms=1.0)
        log.mitigation(
            "A", action="halt", kind="service", ok=False, error="timeout", latency_ms=5.0
        )
        _violation(log, "B", 2)
        log.mitigation("B", action="stop", kind="topic", ok=True, latency_ms=2.0)
        _violation(log, "A", 3)
        log.reset("A", reason="operator")
        log.supervisor("stop")
    recs = [json.loads(line) for line in path.read_bytes().splitlines()]
    assert len({r["ts"] for r in recs}) == len(recs)  # microsecond stamps are distinct here
    return path, recs


def _table(capsys) -> list[list[str]]:
    out = capsys.readouterr().out.splitlines()
    assert out[0].split()[:4] == ["TIME", "EVENT", "REQUIREMENT", "DETAILS"]
    return [row.split() for row in out[1:]]


def test_table_lists_every_record(generated, capsys) -> None:
    path, recs = generated
    assert main(["logs", str(path)]) == 0
    rows = _table(capsys)
    assert [r[0] for r in rows] == [r["ts"] for r in recs]
    assert [r[1] for r in rows] == [r["event"] for r in recs]
    assert rows[1][2:] == ["A", "tick=1", "x=1"]
    assert rows[3][2:] == [
        "A",
        "service:halt",
        "FAILED",
        "(timeout)",
        "latency_ms=5.0",
        "attempt=1",
    ]


def test_filter_by_requirement_and_event(generated, capsys) -> None:
    path, recs = generated
    assert main(["logs", str(path), "--requirement", "A"]) == 0
    assert [r[1] for r in _table(capsys)] == [
        "violation",
        "mitigation",
        "mitigation",
        "violation",
        "reset",
    ]
    assert main(["logs", str(path), "--event", "violation"]) == 0
    assert [(r[2], r[3]) for r in _table(capsys)] == [
        ("A", "tick=1"),
        ("B", "tick=2"),
        ("A", "tick=3"),
    ]
    assert main(["logs", str(path), "--event", "reset", "--event", "supervisor"]) == 0
    assert [r[1] for r in _table(capsys)] == ["supervisor", "reset", "supervisor"]


def test_filter_by_time(generated, capsys) -> None:
    path, recs = generated
    since, until = recs[2]["ts"], recs[5]["ts"]
    assert main(["logs", str(path), "--since", since, "--until", until]) == 0
    assert [r[0] for r in _table(capsys)] == [r["ts"] for r in recs[2:6]]
    # a time without a zone is UTC; one with a zone is converted
    naive = recs[4]["ts"].rstrip("Z")
    assert main(["logs", str(path), "--since", naive]) == 0
    assert len(_table(capsys)) == len(recs) - 4
    assert main(["logs", str(path), "--until", "2000-01-01T01:00:00+01:00"]) == 0
    assert _table(capsys) == []


def test_summary(generated, capsys) -> None:
    path, recs = generated
    assert main(["logs", str(path), "--summary"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split() == ["REQUIREMENT", "VIOLATIONS", "FIRST", "LAST", "MIT_OK", "MIT_FAILED"]
    viol = {r["requirement"]: [] for r in recs if r["event"] == "violation"}
    for r in recs:
        if r["event"] == "violation":
            viol[r["requirement"]].append(r["ts"])
    assert out[1].split() == ["A", "2", viol["A"][0], viol["A"][1], "1", "1"]
    assert out[2].split() == ["B", "1", viol["B"][0], viol["B"][0], "1", "0"]
    assert len(out) == 3
    # filters apply before summarizing
    assert main(["logs", str(path), "--summary", "--requirement", "B"]) == 0
    assert [row.split()[0] for row in capsys.readouterr().out.splitlines()[1:]] == ["B"]


def test_several_files_in_time_order_and_bad_lines_skipped(generated, tmp_path: Path, capsys):
    path, recs = generated
    older = tmp_path / "v.log.1"
    older.write_text(
        '{"ts":"2020-01-01T00:00:00.000000Z","event":"violation",'
        '"requirement":"A","tick":0,"inputs":{}}\nnot json\n'
    )
    assert main(["logs", str(path), str(older), "--event", "violation"]) == 0
    captured = capsys.readouterr()
    rows = [row.split() for row in captured.out.splitlines()[1:]]
    assert [r[0] for r in rows][0] == "2020-01-01T00:00:00.000000Z"
    assert len(rows) == 4
    assert f"{older}:2: skipped: not JSON" in captured.err
    assert f"{older}: 1 line skipped" in captured.err


def test_errors(generated, tmp_path: Path, capsys) -> None:
    path, _ = generated
    missing = tmp_path / "missing.log"
    assert main(["logs", str(missing)]) == 1
    assert capsys.readouterr().err.startswith(f"{missing}: cannot read log")
    with pytest.raises(SystemExit) as e:
        main(["logs", str(path), "--since", "last tuesday"])
    assert e.value.code == 2
    assert "not a time: 'last tuesday'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["logs", str(path), "--event", "bogus"])
    assert e.value.code == 2


# ---------------------------------------------------------------- not a log; long records


@pytest.mark.parametrize(
    "text",
    [
        "# A README\n\nSome prose.\n" * 70,  # 210 lines of text
        '{"level": "info", "msg": "another program\'s JSON lines"}\n' * 206,
    ],
    ids=["text", "foreign-jsonl"],
)
def test_a_file_that_is_not_a_log_is_one_line_and_exit_1(tmp_path: Path, text: str) -> None:
    from inproc import cli_main

    path = tmp_path / "notes.jsonl"
    path.write_text(text)
    for mode in ([], ["--summary"], ["--why"], ["--json"]):
        r = cli_main("logs", *mode, path)
        assert r.returncode == 1, (mode, r)
        assert r.stdout == "", (mode, r)
        assert r.stderr.count("\n") == 1, (mode, r.stderr)
        assert r.stderr.startswith(f"{path}:1: not a violation log: "), (mode, r.stderr)


def test_a_log_with_a_damaged_line_further_on_is_read_with_a_warning(
    generated, tmp_path: Path
) -> None:
    from inproc import cli_main

    path, recs = generated
    lines = path.read_text().splitlines(keepends=True)
    damaged = tmp_path / "damaged.log"
    damaged.write_text("".join(lines[:3]) + "garbage\n" + "".join(lines[3:]))
    r = cli_main("logs", damaged)
    assert r.returncode == 0, r
    assert len(r.stdout.splitlines()) == 1 + len(recs), r.stdout
    assert f"{damaged}:4: skipped: not JSON" in r.stderr and "1 line skipped" in r.stderr


def test_the_stop_record_reads_one_input_per_line_and_floats_at_their_precision(
    tmp_path: Path,
) -> None:
    from inproc import cli_main

    path = tmp_path / "v.log"
    names = [f"input_{i:02d}_with_a_long_name" for i in range(8)]
    per_input = {
        "messages": 81,
        "rejected": 0,
        "nan": 0,
        "lost": 0,
        "own": 0,
        "by_publisher": [{"first": 1, "last": 81, "received": 81, "lost": 0}],
    }
    with ViolationLog(path, "sRobot", "ab" * 32, echo=False) as log:
        log.supervisor("start")
        # a float32 field's 0.8 as the monitor's double holds it; a double as it is
        log.violation(
            "A", text="t", formula="f", tick=7, inputs={"speed": 0.800000011920929, "d": 0.1}
        )
        log.supervisor(
            "stop", ticks=79, violations=1, reloads=0, inputs=dict.fromkeys(names, per_input)
        )
    r = cli_main("logs", path)
    assert r.returncode == 0, r
    out = r.stdout.splitlines()
    assert max(len(line) for line in out) < 200, out
    violation = next(line for line in out if " violation " in line)
    assert violation.split()[-3:] == ["tick=7", "speed=0.8", "d=0.1"], violation
    stop = next(i for i, line in enumerate(out) if " stop " in line)
    assert out[stop].split()[-4:] == ["stop", "ticks=79", "violations=1", "reloads=0"]
    assert out[stop + 1].split() == ["inputs:"]
    for name, line in zip(names, out[stop + 2 :], strict=True):
        assert line.split()[:3] == [name, "messages=81", "rejected=0"], line
    assert main(["logs", "--json", str(path)]) == 0  # as stored: untouched


def test_a_value_just_over_a_threshold_still_reads_over_it() -> None:
    import struct

    from supervisor.tools.logs import number

    over = struct.unpack("f", struct.pack("f", 2.0000002))[0]  # float32 next above 2
    assert over != 2.0 and number(over) == "2.0000002"
    assert number(1.0000000001) == "1.0000000001"  # a double keeps a double's digits
    assert number(0.800000011920929) == "0.8" and number(81.0) == "81.0"
    assert number(float("nan")) == "nan" and number(1e300) == "1e+300"


@pytest.mark.parametrize(
    "argv",
    [["logs"], ["logs", "--verify"], ["logs", "--follow"], ["report", "-o", "page.html"]],
    ids=["logs", "verify", "follow", "report"],
)
def test_a_fifo_is_refused_in_one_line_not_waited_on(tmp_path: Path, argv: list[str]) -> None:
    """A log is read more than once (its first line, its chain, its records): a FIFO
    or a device held each reader open for a writer that never came."""
    import os
    import subprocess
    import sys

    fifo = tmp_path / "v.log"
    os.mkfifo(fifo)
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", argv[0], str(fifo), *argv[1:]],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )
    assert run.returncode == 1, run.stdout + run.stderr
    said = [s for s in run.stderr.splitlines() if "start-up cache" not in s]
    assert said == [f"{fifo}: cannot read log: not a regular file"], run.stderr
