"""The command line as a user runs it: real files, real compiler, and real
subprocesses for each exit path (success, bad config, usage error); the other
error lines are read from the CLI's main in this process (conftest.py, ``cli_main``)."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SROBOT = ROOT / "config" / "srobot.yaml"


def cli(*args, stdin=None, cwd=None):
    env = {k: v for k, v in os.environ.items() if k != "SAFETY_SUPERVISOR_DEBUG"}
    return subprocess.run(
        [sys.executable, "-m", "supervisor", *map(str, args)],
        input=stdin,
        capture_output=True,
        text=True,
        cwd=cwd or ROOT,
        env=env,
        timeout=300,
    )


CONFIG = """\
component: sw
step: {policy: periodic, period_ms: 100}
variables:
  p: {type: bool, topic: /p, msg: std_msgs/msg/Bool}
  halt: {type: bool, topic: /halt, msg: std_msgs/msg/Bool}
  x: {type: int64, topic: /x, msg: std_msgs/msg/Int64}
requirements:
  - id: r1
    text: sw shall always satisfy p | halt
  - id: r2
    text: upon x > 3 sw shall within 1 second satisfy halt
mitigations:
  stop: {publish: {topic: /stop, msg: std_msgs/msg/Bool, value: {data: true}}}
"""


def write(tmp_path, text):
    p = tmp_path / "cfg.yaml"
    p.write_text(textwrap.dedent(text))
    return p


def test_formalize_arguments_and_json_stdin(cli_main):
    r = cli_main("formalize", "sw shall always satisfy p")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "(H p)"
    r = cli_main(
        "formalize", "--json", stdin="sw shall always satisfy p\nsw will always satisfy q\n"
    )
    assert r.returncode == 1
    rows = [json.loads(line) for line in r.stdout.splitlines()]
    assert rows[0] == {"text": "sw shall always satisfy p", "formula": "(H p)", "error": None}
    assert rows[1]["formula"] is None and rows[1]["error"].startswith("<stdin>:2:")


def test_check_srobot_config_compiles():
    r = cli("check", SROBOT)
    assert r.returncode == 0, r.stdout + r.stderr
    lines = r.stdout.splitlines()
    assert sum(1 for line in lines if line.startswith("ok ")) == 13
    assert "13 requirements ok" in lines[-1]


def test_explain_shows_formula_reading_variables_handler(cli_main):
    r = cli_main("explain", SROBOT, "state_req103")
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "state_req103" in out and "(H ((classifier = 1) -> ((! dgt_3) -> (OpState = 3))))" in out
    assert "handlerstate_req103" in out
    assert "dgt_3 (= distance_to_target > 3)" in out
    assert "reading:" in out


QUOTED_CONFIG = """\
component: sw
step: {policy: periodic, period_ms: 100}
variables:
  T: {type: bool, topic: /t, msg: std_msgs/msg/Bool}
  left wheel: {type: int64, topic: /lw, msg: std_msgs/msg/Int64}
  MODE: {type: bool, topic: /m, msg: std_msgs/msg/Bool}
  fast: {type: bool, define: "_DQT_left_SPC_wheel_DQT_ > 5"}
requirements:
  - id: r1
    text: in "MODE" mode, when "T" & "left wheel" > 3, sw shall within 2 ticks satisfy !"T" | fast
    on_violation: [halt]
mitigations:
  halt: {publish: {topic: /halt, msg: std_msgs/msg/Bool, value: {data: true}}}
"""


@pytest.mark.slow
def test_quoted_and_keyword_like_names_check_and_explain(tmp_path):
    # docs/reference/fretish.md, "Names": sentence -> formula -> C -> explain.
    cfg = tmp_path / "c.yaml"
    cfg.write_text(QUOTED_CONFIG)
    r = cli("check", cfg)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "monitor compiled" in r.stdout
    r = cli("explain", cfg, "r1")
    assert r.returncode == 0, r.stderr
    assert "_DQT_left_SPC_wheel_DQT_ > 3" in r.stdout
    assert "T (bool, /t, formula name _DQT_T_DQT_)" in r.stdout
    assert "left wheel (int64, /lw, formula name _DQT_left_SPC_wheel_DQT_, C name left_wheel)" in (
        r.stdout
    )


def test_explain_unknown_requirement(cli_main):
    r = cli_main("explain", SROBOT, "state_req999")
    assert r.returncode == 1 and "no requirement 'state_req999'" in r.stderr


def test_compile_writes_sources_library_manifest(tmp_path, cli_main):
    r = cli_main("compile", SROBOT, "-o", tmp_path / "out")
    assert r.returncode == 0, r.stdout + r.stderr
    out = tmp_path / "out"
    assert (out / "monitor.c").exists() and (out / "monitor.h").exists()
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["backend"] == "native" and len(manifest["requirements"]) == 13
    assert (out / manifest["library"]).exists()
    assert manifest["config_sha256"] and manifest["inputs"][0]["c_name"] == "classifier"
    req = {r["id"]: r for r in manifest["requirements"]}["state_req103"]
    assert req["handler"] == "handlerstate_req103" and req["variables"] == [
        "classifier",
        "dgt_3",
        "OpState",
    ]


@pytest.mark.parametrize("target", ["/dev/null", "a-file"])
def test_compile_into_a_file_says_it_is_not_a_directory(tmp_path, cli_main, target):
    """It said "File exists", which sent the user looking for a file to delete."""
    out = Path(target) if target.startswith("/") else tmp_path / target
    if not out.exists():
        out.write_text("")
    r = cli_main("compile", SROBOT, "-o", out)
    assert r.returncode == 1, r.stdout + r.stderr
    assert r.stderr.strip().splitlines() == [
        f"{out}: cannot build the monitor here: not a directory"
        " (hint: TMPDIR, --build-dir or -o: a directory with room that this user can write)"
    ]


@pytest.mark.parametrize(
    ("edit", "line", "needle"),
    [
        # unknown variable
        (("satisfy p | halt", "satisfy p | hault"), 9, "undeclared variable 'hault'"),
        # type mismatch: bool in arithmetic
        (("satisfy p | halt", "satisfy halt + 1 > 0"), 9, "'+' needs numbers"),
        # int used as a condition
        (("satisfy p | halt", "satisfy p & x"), 9, "x is int64"),
        # reserved name unquoted in a sentence (FRET refuses it; "O" would do)
        (("satisfy p | halt", "satisfy O | halt"), 9, "reserved"),
        # duplicate id
        (("  - id: r2", "  - id: r1"), 10, "duplicate requirement id 'r1'"),
        # unparseable sentence
        (("sw shall always satisfy p | halt", "sw shall always p | halt"), 9, "expected"),
        # duration not a whole number of ticks (period 100 ms)
        (("within 1 second", "within 150 milliseconds"), 11, "not a whole number"),
    ],
)
def test_bad_input_is_one_located_line(tmp_path, cli_main, edit, line, needle):
    cfg = write(tmp_path, CONFIG.replace(*edit))
    r = cli_main("check", cfg)
    text = r.stdout + r.stderr
    assert r.returncode == 1, text
    assert "Traceback" not in text
    hits = [t for t in text.splitlines() if f"{cfg}:{line}" in t]
    assert hits, text
    assert needle in hits[0], hits


def test_bad_config_in_a_subprocess_is_one_located_line(tmp_path):
    """The bad-config exit path as users meet it; the cases above check the lines."""
    cfg = write(tmp_path, CONFIG.replace("satisfy p | halt", "satisfy p | hault"))
    r = cli("check", cfg)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "Traceback" not in r.stdout + r.stderr
    hits = [t for t in (r.stdout + r.stderr).splitlines() if f"{cfg}:9" in t]
    assert hits and "undeclared variable 'hault'" in hits[0], r.stdout + r.stderr


def test_unparseable_sentence_points_at_column(tmp_path, cli_main):
    cfg = write(
        tmp_path, CONFIG.replace("sw shall always satisfy p | halt", "sw shall always p | halt")
    )
    r = cli_main("check", cfg)
    assert r.returncode == 1, r.stdout + r.stderr
    # 'text: ' starts at column 5; the bad token 'p' is the 17th character of the sentence
    assert f"{cfg}:9:{11 + 16}:" in r.stdout + r.stderr


def test_usage_error_exit_2():
    r = cli("check")
    assert r.returncode == 2


@pytest.mark.ros
def test_run_leaves_no_ros_log_directory_behind(tmp_path):
    """Outside systemd (no ROS_LOG_DIR, no LOGS_DIRECTORY) run makes a temporary
    directory for rclpy's own log files, and removes it at exit."""
    from rosutil import Daemon

    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    daemon = Daemon(tmp_path, env={"ROS_LOG_DIR": "", "LOGS_DIRECTORY": "", "TMPDIR": str(tmpdir)})
    try:
        daemon.wait_notify("READY=1", timeout=60)
        made = list(tmpdir.glob("safety-supervisor-ros-log-*"))
        assert len(made) == 1, daemon.explain()
        daemon.terminate()
    finally:
        daemon.close()
    assert list(tmpdir.glob("safety-supervisor-ros-log-*")) == []


def test_version_is_the_installed_packages():
    from importlib.metadata import version

    r = cli("--version")
    assert r.returncode == 0, r
    assert r.stdout == f"safety-supervisor {version('safety-supervisor')}\n", r


def test_check_prints_each_requirements_margin_state_and_fallback(tmp_path):
    # step.margins: one line per requirement with its margin state; a window longer
    # than the C monitor keeps says its margin is boolean (docs/reference/margins.md)
    path = write(
        tmp_path,
        CONFIG.replace("period_ms: 100}", "period_ms: 100, margins: true}").replace(
            "within 1 second", "within 4 seconds"
        ),
    )
    r = cli("check", path)
    assert r.returncode == 0, r.stdout + r.stderr
    lines = [line for line in r.stdout.splitlines() if line.startswith("  margin ")]
    assert lines[0] == "  margin r1: 8 bytes of state"  # H: its running minimum
    # within 40 ticks: its delay of 40 is kept, its window of 40 falls back
    assert lines[1].startswith("  margin r2: ") and lines[1].endswith(
        "; boolean (window over 32 or lower bound over 1024 ticks): (O[0,39] ((Z FALSE) | halt))"
    )
    r = cli("compile", path, "--backend", "copilot", "-o", tmp_path / "out")
    assert r.returncode == 1
    assert r.stderr.strip().splitlines() == [
        "copilot: the Copilot backend computes no margins (hint: use the native backend "
        "(--backend native), or turn margins off)"
    ]


def test_check_says_what_a_prediction_fits_and_its_second_monitor(tmp_path):
    # predict: fits the margin of the invariant's body in a monitor of its own, stepped
    # beside the boolean one (docs/reference/prediction.md, "What is fitted")
    path = write(
        tmp_path,
        CONFIG.replace(
            "    text: sw shall always satisfy p | halt\n",
            "    text: sw shall always satisfy x <= 10 | p\n"
            "    on_violation: [stop]\n"
            "    predict: {horizon_ms: 1000, actions: [stop]}\n",
        ),
    )
    r = cli("check", path)
    assert r.returncode == 0, r.stdout + r.stderr
    lines = [line for line in r.stdout.splitlines() if line.startswith("  predict ")]
    assert lines == [
        "  predict r1: fits the margin of ((x <= 10) | p) in a second monitor, "
        "stepped beside the boolean one (0 bytes of margin state)"
    ], r.stdout


@pytest.mark.parametrize("command", ["compile", "check"])
def test_a_build_on_a_noexec_filesystem_is_one_line(tmp_path, command) -> None:
    # A hardened robot mounts /tmp (so TMPDIR) noexec: a library there cannot be mapped,
    # and the command ended in an "internal error" (exit 3). The mount lives in a mount
    # namespace of the command's own (unshare), gone with it.
    shut = tmp_path / "noexec"
    shut.mkdir()
    argv = [sys.executable, "-m", "supervisor", command, str(SROBOT)]
    if command == "compile":
        argv += ["-o", str(shut / "out")]
    script = f"mount -t tmpfs -o noexec tmpfs {shut} && exec " + " ".join(map(str, argv))
    env = {**os.environ, "TMPDIR": str(shut), "XDG_CACHE_HOME": str(shut / "cache")}
    env.pop("STATE_DIRECTORY", None)
    r = subprocess.run(
        ["unshare", "--mount", "sh", "-c", script], capture_output=True, text=True, env=env,
        timeout=300,
    )  # fmt: skip
    assert r.returncode == 1, (r.returncode, r.stderr)
    said = [line for line in r.stderr.splitlines() if "noexec" in line]
    assert len(said) == 1 and str(shut) in said[0], r.stderr
    assert "internal error" not in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("command", [["check", str(SROBOT)], ["--help"]])
def test_output_that_cannot_be_written_is_one_line(command) -> None:
    # stdout on a full disk (here /dev/full): an internal error (exit 3) before.
    with open("/dev/full", "w") as full:
        r = subprocess.run(
            [sys.executable, "-m", "supervisor", *command], stdout=full, stderr=subprocess.PIPE,
            text=True, timeout=300,
        )  # fmt: skip
    assert r.returncode == 1, (r.returncode, r.stderr)
    assert r.stderr.splitlines() == [
        "<stdout>: cannot write the output: No space left on device"
    ], r.stderr


LONG = "a" * 300  # a path part longer than a filesystem's 255 bytes: ENAMETOOLONG


@pytest.mark.parametrize(
    "command",
    [
        ["replay", str(SROBOT), f"{LONG}.jsonl", "--quiet"],
        ["logs", f"{LONG}.jsonl"],
        ["init", LONG],
        ["fleet", "report", LONG, "-o", "x.html", "--quiet"],
    ],
)
def test_a_path_the_system_refuses_is_one_line_naming_it(tmp_path, command) -> None:
    # Path.exists() and is_dir() raise on ENAMETOOLONG and EACCES (only "not there"
    # is False): each such path ended in an internal error (exit 3).
    r = subprocess.run(
        [sys.executable, "-m", "supervisor", *command], capture_output=True, text=True,
        cwd=tmp_path, timeout=300,
    )  # fmt: skip
    assert r.returncode == 1, (r.returncode, r.stderr)
    said = r.stderr.strip().splitlines()
    assert len(said) == 1 and LONG in said[0] and "File name too long" in said[0], r.stderr


@pytest.mark.parametrize(
    ("command", "code"), [(["check"], 2), (["bogus"], 2), (["check", str(SROBOT)], 0)]
)
def test_a_closed_stderr_changes_no_exit_code(command, code) -> None:
    # argparse and the error line wrote to sys.stderr, None when fd 2 is closed: exit 3.
    r = subprocess.run(
        ["sh", "-c", 'exec "$@" 2>&-', "sh", sys.executable, "-m", "supervisor", *command],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == code, (r.returncode, r.stdout)
    assert "internal error" not in r.stdout


@pytest.mark.parametrize(
    ("command", "code"),
    [(["replay", str(SROBOT), "recorded.jsonl", "--quiet"], 0), (["check", "nothing.yaml"], 1)],
)
def test_stderr_on_a_full_disk_changes_no_exit_code(tmp_path, command, code) -> None:
    # A warning (here the start-up cache's: XDG_CACHE_HOME under a file) or an error line
    # written to a full stderr raised in the middle of the command: a replay that
    # succeeded ended in exit 1 or 3.
    (tmp_path / "a-file").write_text("")
    (tmp_path / "recorded.jsonl").write_text('{"t_ns": 0, "name": "classifier", "value": 0}\n')
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "a-file" / "cache")}
    env.pop("STATE_DIRECTORY", None)
    with open("/dev/full", "w") as full:
        r = subprocess.run(
            [sys.executable, "-m", "supervisor", *command], stdout=subprocess.PIPE, stderr=full,
            text=True, cwd=tmp_path, env=env, timeout=300,
        )  # fmt: skip
    assert r.returncode == code, (r.returncode, r.stdout)


@pytest.mark.parametrize(
    ("stdin", "says"), [("<&-", "no requirement"), ("</dev/zero", "more than")]
)
def test_formalize_reads_a_bounded_stdin(stdin, says) -> None:
    # stdin closed was a TypeError, /dev/zero memory without end (exit 3, or killed).
    r = subprocess.run(
        ["sh", "-c", f'ulimit -v 4000000; exec "$@" {stdin}', "sh", sys.executable, "-m", "supervisor", "formalize"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 1, (r.returncode, r.stderr)
    said = r.stderr.strip().splitlines()
    assert len(said) == 1 and said[0].startswith("<stdin>") and says in said[0], r.stderr
