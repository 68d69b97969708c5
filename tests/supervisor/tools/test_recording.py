"""Recording directories: ``demo --record DIR`` keeps the config, the violation log
and the bags in DIR, and ``logs DIR``, ``replay DIR`` and ``report DIR`` find them
(supervisor/tools/recording.py; docs/reference/commands.md, "Recording directories").

A real demo run, recorded by its supervisor, read back by the three commands as
real processes; an ambiguous or incomplete directory is refused in one line.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from mitigations.violationlog.writer import ViolationLog

ROOT = Path(__file__).resolve().parents[3]


def cli(*args: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "supervisor", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=240,
        cwd=ROOT,
    )


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    rec = tmp_path_factory.mktemp("demo") / "rec"
    demo = cli(
        "demo", "--duration", "10", "--no-live", "--fault-rate", "0.3", "--seed", "11",
        "--rate-hz", "20", "--record", rec,
    )  # fmt: skip
    assert demo.returncode == 0, demo.stdout + demo.stderr
    assert f"read it with: safety-supervisor logs {rec}" in demo.stdout, demo.stdout
    return rec


@pytest.mark.ros
@pytest.mark.slow
def test_demo_record_keeps_the_whole_run_and_each_command_finds_it(
    recorded: Path, tmp_path: Path
) -> None:
    rec = recorded
    configs = list(rec.glob("*.yaml"))
    assert [p.name for p in configs] == ["srobot-demo.yaml"]
    log = rec / "violations.jsonl"
    assert log.exists() and any((d / "metadata.yaml").exists() for d in rec.iterdir())
    # logs DIR: the same as the log itself
    by_dir, by_file = cli("logs", rec), cli("logs", log)
    assert by_dir.returncode == 0 and by_dir.stdout == by_file.stdout, by_dir.stderr
    assert " violation " in by_dir.stdout  # the UV fault was caught
    # replay DIR: the same as the config and the directory named
    a, b = tmp_path / "a.jsonl", tmp_path / "b.jsonl"
    by_dir = cli("replay", rec, "--json", "--quiet", "-o", a)
    named = cli("replay", configs[0], rec, "--json", "--quiet", "-o", b)
    assert by_dir.returncode == 0, by_dir.stderr
    assert json.loads(by_dir.stdout)["requirements"] == json.loads(named.stdout)["requirements"]
    # report DIR: the log, and the bags and config for the inputs and why-trees
    page, other = tmp_path / "dir.html", tmp_path / "named.html"
    by_dir = cli("report", rec, "-o", page, "--quiet")
    named = cli("report", log, "--bag", rec, "--config", configs[0], "-o", other, "--quiet")
    assert by_dir.returncode == 0, by_dir.stderr
    assert by_dir.stdout.replace(str(page), "P") == named.stdout.replace(str(other), "P")
    # the same page, but for the time it was made
    made = re.compile(r"made \d{4}-\d\d-\d\dT[\d:.]+Z")
    assert made.sub("", page.read_text()) == made.sub("", other.read_text())


def _small_recording(tmp_path: Path) -> Path:
    """A directory shaped like a recording: one config, one log, one bag directory."""
    rec = tmp_path / "rec"
    (rec / "bag_0").mkdir(parents=True)
    (rec / "bag_0" / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    shutil.copy(ROOT / "supervisor/data/examples/srobot.yaml", rec / "srobot.yaml")
    with ViolationLog(rec / "violations.jsonl", "sRobot", "ab" * 32, echo=False) as log:
        log.supervisor("start")
    return rec


@pytest.mark.parametrize(
    ("change", "said"),
    [
        (lambda r: shutil.copy(r / "srobot.yaml", r / "other.yaml"), "ambiguous recording "
         "directory: 2 configs (other.yaml, srobot.yaml)"),
        (lambda r: shutil.copy(r / "violations.jsonl", r / "other.jsonl"), "ambiguous "
         "recording directory: 2 violation logs (other.jsonl, violations.jsonl)"),
        (lambda r: (r / "violations.jsonl").unlink(), "incomplete recording directory: "
         "no violation log"),
    ],
    ids=["two-configs", "two-logs", "no-log"],
)  # fmt: skip
def test_an_ambiguous_or_incomplete_directory_is_one_line(tmp_path: Path, change, said) -> None:
    rec = _small_recording(tmp_path)
    change(rec)
    runs = {"logs": cli("logs", rec), "report": cli("report", rec, "-o", tmp_path / "r.html")}
    if "log" not in said:  # replay needs the config and the bags, not the log
        runs["replay"] = cli("replay", rec)
    for command, r in runs.items():
        assert r.returncode == 1, (command, r)
        assert r.stderr == f"{rec}: {said}" + r.stderr[len(f"{rec}: {said}") :], (command, r)
        assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, (command, r)


def test_replay_of_a_directory_without_bags_is_incomplete(tmp_path: Path) -> None:
    rec = _small_recording(tmp_path)
    shutil.rmtree(rec / "bag_0")
    r = cli("replay", rec)
    assert r.returncode == 1 and r.stderr.startswith(
        f"{rec}: incomplete recording directory: no bag"
    ), r
    assert r.stderr.count("\n") == 1
    usage = cli("replay", rec / "srobot.yaml")  # a config without recordings: usage
    assert usage.returncode == 2 and "give the recordings" in usage.stderr, usage
