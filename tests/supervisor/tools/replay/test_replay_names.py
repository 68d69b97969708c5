"""``replay`` and names as ROS resolves them: rosbag2's relative topic names, a
robot's namespaced bag mapped onto the config (``--namespace``, ``ros.namespace``),
a replay that matched no topic is a failure, missing topics are said at the end,
progress only on a terminal and never glued to an error; also ``check`` on a
variable read only through ``rate_of``.  Real CLI subprocesses on the corpus of
rosbag2's own bags (tests/data/bags/README.md) and on bags written with rosbags."""

from __future__ import annotations

import json
import os
import select
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

BAGS = Path(__file__).resolve().parents[3] / "data" / "bags"
TS = get_typestore(Stores.ROS2_JAZZY)
MS = 1_000_000


def cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "supervisor", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def sqlite_counts(bag: Path) -> dict[str, int]:
    """Messages per topic as the bag's own sqlite3 files hold them: an independent reader."""
    counts: dict[str, int] = {}
    for db in sorted(bag.glob("*.db3")):
        with sqlite3.connect(f"file:{db}?immutable=1", uri=True) as c:
            rows = c.execute(
                "SELECT topics.name, COUNT(*) FROM messages JOIN topics "
                "ON messages.topic_id = topics.id GROUP BY topics.name"
            )
            for name, n in rows:
                counts[name] = counts.get(name, 0) + n
    return counts


def event_config(tmp: Path, topic: str, msg: str, extra: str = "") -> Path:
    """An event variable on ``topic``: every message is a tick whose event is true,
    so ``always !e`` is violated at exactly one tick per message."""
    return write(
        tmp / "c.yaml",
        f"""\
component: R
step: {{policy: on_message}}
variables:
  e: {{type: bool, topic: {topic}, msg: {msg}, event: true}}
{extra}requirements:
  - id: quiet
    text: R shall always satisfy !e
    on_violation: [note]
    policy: {{reset: after_mitigation}}
mitigations:
  note: {{log: {{message: violated}}}}
""",
    )


@pytest.mark.parametrize(
    ("bag", "recorded", "topic", "msg"),
    [
        ("sqlite3/test_bag_for_seek", "topic1", "/topic1", "test_msgs/msg/BasicTypes"),
        ("sqlite3/wbag", "CCC", "/CCC", "std_msgs/msg/String"),
    ],
)
def test_a_relative_topic_in_a_bag_is_the_config_s_absolute_one(
    cli_main, tmp_path, bag, recorded, topic, msg
):
    """rosbag2 records ``topic1``; rclpy resolves it in the root namespace as ``/topic1``."""
    path = BAGS / bag
    want = sqlite_counts(path)[recorded]
    assert want > 0
    run = cli_main("replay", str(event_config(tmp_path, topic, msg)), str(path), "--json")
    assert run.returncode == 0, run.stderr
    result = json.loads(run.stdout)
    assert result["messages"] == want
    assert result["ticks"] == want
    assert {q["id"]: q["violations"] for q in result["requirements"]} == {"quiet": want}
    assert result["missing_topics"] == []


def namespaced_bag(path: Path, speeds: list[float]) -> Path:
    """A robot's bag as ``ros2 bag record`` in namespace /robot1 writes it."""
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        speed = w.add_connection("/robot1/speed", "std_msgs/msg/Float64", typestore=TS)
        other = w.add_connection("/robot1/odom_rate", "std_msgs/msg/Float64", typestore=TS)
        cls = TS.types["std_msgs/msg/Float64"]
        for i, v in enumerate(speeds):
            t = 10**9 + i * 100 * MS
            w.write(speed, t, bytes(TS.serialize_cdr(cls(data=v), "std_msgs/msg/Float64")))
        w.write(other, 10**9, bytes(TS.serialize_cdr(cls(data=1.0), "std_msgs/msg/Float64")))
    return path


SPEEDS = [0.5, 2.5, 1.0, 3.0, 2.1, 0.0]  # over 2.0: the 2nd, 4th and 5th


def speed_config(tmp: Path, ros: str = "", extra: str = "") -> Path:
    check = "speed <= 2.0 & odom < 100.0" if "odom" in extra else "speed <= 2.0"
    return write(
        tmp / "speed.yaml",
        f"""\
component: R
{ros}step: {{policy: on_message}}
variables:
  speed: {{type: double, topic: /speed, msg: std_msgs/msg/Float64}}
{extra}requirements:
  - id: limit
    text: R shall always satisfy {check}
    on_violation: [note]
    policy: {{reset: after_mitigation}}
mitigations:
  note: {{log: {{message: violated}}}}
""",
    )


@pytest.mark.parametrize("how", ["option", "config"])
def test_a_namespaced_bag_maps_onto_the_config(cli_main, tmp_path, how):
    bag = namespaced_bag(tmp_path / "bag", SPEEDS)
    if how == "option":
        args = [str(speed_config(tmp_path)), str(bag), "--namespace", "/robot1"]
    else:
        args = [str(speed_config(tmp_path, ros="ros: {namespace: /robot1}\n")), str(bag)]
    out = tmp_path / "out.jsonl"
    run = cli_main("replay", *args, "--json", "-o", str(out))
    assert run.returncode == 0, run.stderr
    result = json.loads(run.stdout)
    assert result["messages"] == len(SPEEDS)
    assert {q["id"]: q["violations"] for q in result["requirements"]} == {
        "limit": sum(v > 2.0 for v in SPEEDS)
    }


@pytest.mark.parametrize("bad", ["robot1", "/robot 1", "/robot1/", "/1robot", ""])
def test_a_bad_namespace_is_one_line(cli_main, tmp_path, bad):
    bag = namespaced_bag(tmp_path / "bag", SPEEDS)
    run = cli_main("replay", str(speed_config(tmp_path)), str(bag), f"--namespace={bad}")
    assert run.returncode == 2 if "usage" in run.stderr else run.returncode == 1
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert "Traceback" not in run.stderr
    assert len(lines) == 1 and "--namespace" in lines[0], run.stderr


def test_a_replay_that_matched_no_topic_fails_and_lists_both_sides(cli_main, tmp_path):
    bag = namespaced_bag(tmp_path / "bag", SPEEDS)  # no --namespace: nothing matches
    run = cli_main("replay", str(speed_config(tmp_path)), str(bag))
    assert run.returncode == 1, run.stdout
    assert "Traceback" not in run.stderr
    last = run.stderr.strip().splitlines()[-1]
    assert "no topic of the config" in last
    assert "/robot1/speed" in last and "/robot1/odom_rate" in last and "/speed" in last


MISSING = "  odom: {type: double, topic: /odom_speed, msg: std_msgs/msg/Float64, initial: 0.0}\n"


def test_missing_topics_are_a_warning_block_at_the_end_and_in_json(cli_main, tmp_path):
    bag = namespaced_bag(tmp_path / "bag", SPEEDS)
    cfg = speed_config(tmp_path, extra=MISSING)
    run = cli_main("replay", str(cfg), str(bag), "--namespace", "/robot1")
    assert run.returncode == 0, run.stderr
    out = run.stdout.strip().splitlines()
    table = next(i for i, line in enumerate(out) if line.startswith("limit "))
    # last, after the requirement table, not lost among the notes before it
    assert [i for i, line in enumerate(out) if "/odom_speed" in line] == [len(out) - 1]
    assert table < len(out) - 1 and "odom" in out[-1] and out[-1].startswith("warning: ")
    as_json = cli_main("replay", str(cfg), str(bag), "--namespace", "/robot1", "--json")
    assert as_json.returncode == 0, as_json.stderr
    assert json.loads(as_json.stdout)["missing_topics"] == ["/odom_speed"]


def test_require_all_topics_makes_a_missing_topic_an_error(cli_main, tmp_path):
    bag = namespaced_bag(tmp_path / "bag", SPEEDS)
    cfg = speed_config(tmp_path, extra=MISSING)
    run = cli_main("replay", str(cfg), str(bag), "--namespace", "/robot1", "--require-all-topics")
    assert run.returncode == 1
    assert "Traceback" not in run.stderr
    last = run.stderr.strip().splitlines()[-1]
    assert last.startswith("safety-supervisor: ") and "/odom_speed" in last
    ok = cli_main("replay", str(speed_config(tmp_path)), str(bag), "--namespace=/robot1",
             "--require-all-topics")  # fmt: skip
    assert ok.returncode == 0, ok.stderr


def test_a_variable_read_only_through_rate_of_is_used(cli_main, tmp_path):
    cfg = write(
        tmp_path / "rate.yaml",
        """\
component: R
step: {policy: periodic, period_ms: 100}
variables:
  scan: {type: double, topic: /scan, msg: std_msgs/msg/Float64, initial: 0.0}
  scan_hz: {type: double, rate_of: scan, window_ms: 1000}
requirements:
  - id: rate
    text: R shall always satisfy scan_hz >= 5.0
    on_violation: [note]
mitigations:
  note: {log: {message: violated}}
""",
    )
    run = cli_main("check", str(cfg))
    assert run.returncode == 0, run.stderr
    assert "unused" not in run.stderr and "no requirement uses" not in run.stderr


def pty_replay(args: list[str]) -> tuple[int, bytes]:
    """The real CLI with its stderr on a pseudo-terminal: its exit code and what the
    terminal received."""
    master, slave = os.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "supervisor", "replay", *args],
        stdout=subprocess.DEVNULL,
        stderr=slave,
        stdin=subprocess.DEVNULL,
    )
    os.close(slave)
    data = b""
    while True:
        ready, _, _ = select.select([master], [], [], 120)
        if not ready:
            proc.kill()
            break
        try:
            chunk = os.read(master, 65536)
        except OSError:  # EIO: the child closed the terminal's last writer
            break
        if not chunk:
            break
        data += chunk
    os.close(master)
    return proc.wait(timeout=60), data


def test_the_error_after_progress_starts_on_its_own_line(tmp_path):
    bag = namespaced_bag(tmp_path / "bag", SPEEDS)
    cfg = speed_config(tmp_path, extra=MISSING)
    code, data = pty_replay([str(cfg), str(bag), "--namespace", "/robot1", "--require-all-topics"])
    assert code == 1
    assert b"\rreplay: " in data  # progress was drawn on the terminal
    error = data.rindex(b"safety-supervisor: ")
    assert data[:error].endswith(b"\n"), data  # not glued to the last \r progress line


def test_no_progress_when_stderr_is_not_a_terminal(tmp_path):
    """A CI log gets no ``\r`` lines, and so no error glued to the last of them."""
    cls = TS.types["std_msgs/msg/Float64"]
    bag = tmp_path / "plain"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        speed = w.add_connection("/speed", "std_msgs/msg/Float64", typestore=TS)
        for i, v in enumerate(SPEEDS):
            data = bytes(TS.serialize_cdr(cls(data=v), "std_msgs/msg/Float64"))
            w.write(speed, 10**9 + i * 100 * MS, data)
    run = cli("replay", str(speed_config(tmp_path)), str(bag))
    assert run.returncode == 0, run.stderr
    assert "\r" not in run.stderr and "replay: " not in run.stderr


def test_report_shows_no_progress_when_stderr_is_not_a_terminal(tmp_path):
    """``report --bag`` as replay: a CI log or the journal gets no ``\r`` lines."""
    cls = TS.types["std_msgs/msg/Float64"]
    bag = tmp_path / "plain"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        speed = w.add_connection("/speed", "std_msgs/msg/Float64", typestore=TS)
        for i, v in enumerate(SPEEDS):
            data = bytes(TS.serialize_cdr(cls(data=v), "std_msgs/msg/Float64"))
            w.write(speed, 10**9 + i * 100 * MS, data)
    cfg = speed_config(tmp_path)
    log = tmp_path / "log.jsonl"
    assert cli("replay", str(cfg), str(bag), "-o", str(log)).returncode == 0
    page = tmp_path / "r.html"
    run = cli("report", str(log), "--bag", str(bag), "--config", str(cfg), "-o", str(page))
    assert run.returncode == 0, run.stderr
    assert "\r" not in run.stderr and "report: " not in run.stderr, run.stderr


def test_report_bag_reads_relative_names(cli_main, tmp_path):
    """``report --bag`` resolves names as replay does: rosbag2's ``CCC`` is ``/CCC``."""
    bag = BAGS / "sqlite3/wbag"
    cfg = event_config(tmp_path, "/CCC", "std_msgs/msg/String")
    log = tmp_path / "log.jsonl"
    assert cli_main("replay", str(cfg), str(bag), "-o", str(log)).returncode == 0
    page = tmp_path / "r.html"
    run = cli_main("report", str(log), "--bag", str(bag), "--config", str(cfg), "-o", str(page))
    assert run.returncode == 0, run.stderr
    assert "Traceback" not in run.stderr
    html = page.read_text()
    assert "none of the recordings" not in html


def test_report_bag_takes_the_namespace_replay_takes(cli_main, tmp_path):
    """``report --bag --namespace`` maps a namespaced bag as ``replay --namespace``
    does; a bad one is one line, exit 1."""
    bag = namespaced_bag(tmp_path / "bag", SPEEDS)
    cfg = speed_config(tmp_path)
    log = tmp_path / "log.jsonl"
    assert (
        cli_main("replay", str(cfg), str(bag), "--namespace", "/robot1", "-o", str(log)).returncode
        == 0
    )
    page = tmp_path / "r.html"
    argv = ["report", str(log), "--bag", str(bag), "--config", str(cfg), "-o", str(page)]
    run = cli_main(*argv, "--namespace", "/robot1")
    assert run.returncode == 0 and "Traceback" not in run.stderr, run.stderr
    assert "none of the recordings" not in page.read_text()
    bad = cli_main(*argv, "--namespace", "robot1")
    assert bad.returncode == 1 and "Traceback" not in bad.stderr, bad.stderr
    assert bad.stderr.strip().splitlines() == [
        "report: --namespace 'robot1' is not a ROS namespace "
        "(absolute, like /robot1 or /fleet/robot1)"
    ], bad.stderr


def test_a_second_replay_compiles_nothing_from_the_user_s_cache(tmp_path):
    """Without STATE_DIRECTORY replay keeps its monitor in $XDG_CACHE_HOME, made 0700
    and checked as the daemon's cache is (supervisor/cache.py); the compiler behind a
    wrapper that logs each compilation (as tests/supervisor/test_startup_cache.py does)."""
    from tests.supervisor.test_startup_cache import _wrapper

    bag = namespaced_bag(tmp_path / "bag", SPEEDS)
    cfg = speed_config(tmp_path)
    log = tmp_path / "cc.log"
    xdg = tmp_path / "xdg"
    env = {k: v for k, v in os.environ.items() if k != "STATE_DIRECTORY"}
    env.update(XDG_CACHE_HOME=str(xdg), CC=str(_wrapper(tmp_path / "cc", log)))

    def replay() -> dict[str, object]:
        run = subprocess.run(
            [sys.executable, "-m", "supervisor", "replay", str(cfg), str(bag),
             "--namespace", "/robot1", "--json"],
            capture_output=True, text=True, env=env, timeout=300,
        )  # fmt: skip
        assert run.returncode == 0 and "Traceback" not in run.stderr, run.stderr
        return json.loads(run.stdout)

    def compiles() -> int:
        n = len(log.read_text().splitlines()) if log.exists() else 0
        log.unlink(missing_ok=True)
        return n

    first = replay()
    assert compiles() > 0
    root = xdg / "safety-supervisor"
    assert root.stat().st_mode & 0o777 == 0o700
    assert list(root.glob("*/monitor.json")) and list(root.glob("lark-*.tables"))
    second = replay()
    timing = ("seconds", "rate")
    assert {k: v for k, v in second.items() if k not in timing} == {
        k: v for k, v in first.items() if k not in timing
    }
    assert compiles() == 0
    root.chmod(0o777)  # others could swap the library: not used, said, built afresh
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "replay", str(cfg), str(bag), "--namespace=/robot1"],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip
    assert run.returncode == 0 and "not used" in run.stderr, run.stderr
    assert compiles() > 0


def test_a_matched_topic_without_messages_judged_nothing(cli_main, tmp_path):
    """rosbag2's empty_bag has /rosout, no message on it: exit 1, not a 0-tick success."""
    cfg = write(
        tmp_path / "rosout.yaml",
        """\
component: R
step: {policy: on_message}
variables:
  level: {type: int64, topic: /rosout, msg: rcl_interfaces/msg/Log, field: level}
requirements:
  - id: calm
    text: R shall always satisfy level < 40
    on_violation: [note]
mitigations:
  note: {log: {message: violated}}
""",
    )
    assert sqlite_counts(BAGS / "sqlite3/empty_bag") == {}
    run = cli_main("replay", str(cfg), str(BAGS / "sqlite3/empty_bag"))
    assert run.returncode == 1 and "Traceback" not in run.stderr
    last = run.stderr.strip().splitlines()[-1]
    assert "no message on the config's topics (/rosout)" in last


def test_a_missing_event_topic_is_not_said_to_keep_the_monitor_from_stepping(cli_main, tmp_path):
    """An event is false until its message comes (docs/reference/config.md), so only
    the value without 'initial:' is named as never getting one."""
    bag = namespaced_bag(tmp_path / "bag", SPEEDS)
    extra = (
        "  odom: {type: double, topic: /odom_speed, msg: std_msgs/msg/Float64}\n"
        "  bump: {type: bool, topic: /bumper, msg: std_msgs/msg/Float64, event: true}\n"
    )
    cfg = speed_config(tmp_path, extra=extra)
    cfg.write_text(cfg.read_text().replace("odom < 100.0", "odom < 100.0 & !bump"))
    run = cli_main("replay", str(cfg), str(bag), "--namespace=/robot1")
    assert "Traceback" not in run.stderr, run.stderr
    said = [line for line in (run.stdout + run.stderr).splitlines() if "never" in line]
    assert said and all("without 'initial:', odom never gets a value" in s for s in said), said
    assert not [s for s in said if "bump" in s.split("never")[0].split("without")[-1]], said
