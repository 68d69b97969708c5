"""Exit code 3 (an internal error) is unreachable from any input.

Every command that reads a file is run here, in-process as the CLI runs it, on
real inputs that hypothesis damages: cut, bytes flipped or inserted, control
characters, deep nesting, values of the wrong type.  Each run must end in 0, 1
or 2 (docs/reference/commands.md, exit codes), with no traceback.  The network
surfaces (the UI's HTTP, the control socket) have their own adversaries.
"""

from __future__ import annotations

import contextlib
import io
import json
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mitigations.violationlog.writer import ViolationLog
from supervisor.cli import main

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "config"

HOSTILE = [
    b"\x1b]0;title\x07\x1b[2J\r",
    b"<!--<script>alert(1)</script>",
    b"[" * 3000,
    b"{" * 300,
    b"\xff\xfe\x00",
    b'"tick": "7"',
    b"0001-01-01T00:00:00Z",
    b"9999-12-31T23:59:59.999999Z",
    b"1e999",
    b"-1",
    b"null",
    b"/etc/shadow",
    b"/dev/zero",
]


@st.composite
def damaged(draw: st.DrawFn, data: bytes) -> bytes:
    """``data`` with one to three damages."""
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, len(data)))
        kind = draw(st.sampled_from(["cut", "flip", "insert", "hostile", "delete"]))
        if kind == "cut":
            data = data[:i]
        elif kind == "flip" and i < len(data):
            data = data[:i] + bytes([data[i] ^ draw(st.integers(1, 255))]) + data[i + 1 :]
        elif kind == "insert":
            data = data[:i] + draw(st.binary(min_size=1, max_size=20)) + data[i:]
        elif kind == "hostile":
            data = data[:i] + draw(st.sampled_from(HOSTILE)) + data[i:]
        else:
            data = data[:i] + data[i + draw(st.integers(1, 40)) :]
    return data


JSON_VALUES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**70), 2**70)
    | st.floats()
    | st.text(max_size=30)
    | st.sampled_from([h.decode("latin-1") for h in HOSTILE]),
    lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=8), c, max_size=3),
    max_leaves=8,
)


@st.composite
def retyped_lines(draw: st.DrawFn, data: bytes) -> bytes:
    """JSON lines with one field of one line given a value of any type."""
    lines = data.splitlines()
    i = draw(st.integers(0, len(lines) - 1))
    rec = json.loads(lines[i])
    key = draw(st.sampled_from(sorted(rec)) | st.sampled_from(["ts", "tick", "inputs", "event"]))
    rec[key] = draw(JSON_VALUES)
    lines[i] = json.dumps(rec).encode()
    return b"\n".join(lines) + b"\n"


def _run(argv: list[str]) -> tuple[int, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as e:  # argparse's usage errors
            code = e.code if isinstance(e.code, int) else 2
    return code, err.getvalue()


def _assert_handled(argv: list[str]) -> None:
    code, err = _run(argv)
    assert code in (0, 1, 2), f"{argv} exited {code}: {err[-2000:]}"
    assert "Traceback" not in err, err


@pytest.fixture(scope="module")
def violation_log(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    path = tmp_path_factory.mktemp("log") / "v.jsonl"
    with ViolationLog(path, "sRobot", "ab" * 32, echo=False) as log:
        log.supervisor("start", config=str(EXAMPLES / "srobot.yaml"))
        for tick in (1, 5, 9):
            log.violation("A", text="t", formula="H x", tick=tick, inputs={"x": tick})
            log.mitigation("A", action="stop", kind="publish", ok=True, latency_ms=1.0)
        log.reset("A", reason="operator")
        log.supervisor("stop")
    return path.read_bytes()


def _workdir() -> Path:
    d = Path(tempfile.mkdtemp(prefix="ss-fuzz-"))
    for name in ("srobot-from-fret.yaml", "srobot-fret-export.json", "srobot-ogma-variables.txt"):
        shutil.copy(EXAMPLES / name, d / name)
    return d


FUZZ = settings(
    max_examples=60,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    database=None,
)


def _fuzz_file(name: str, seed: bytes, argv: Callable[[Path], list[str]]) -> Callable[..., None]:
    @FUZZ
    @given(st.one_of(damaged(seed), *([retyped_lines(seed)] if name.endswith("jsonl") else [])))
    def run(data: bytes) -> None:
        d = _workdir()
        try:
            (d / name).write_bytes(data)
            _assert_handled(argv(d))
        finally:
            shutil.rmtree(d, ignore_errors=True)

    return run


@pytest.mark.parametrize(
    "name",
    ["srobot-from-fret.yaml", "srobot-fret-export.json", "srobot-ogma-variables.txt"],
)
def test_check_of_a_damaged_config_or_import(name: str) -> None:
    seed = (EXAMPLES / name).read_bytes()
    _fuzz_file(name, seed, lambda d: ["explain", str(d / "srobot-from-fret.yaml")])()


@pytest.mark.parametrize(
    "command",
    [["logs"], ["logs", "--summary"], ["logs", "--verify"], ["logs", "--json"], ["report"]],
    ids=lambda c: " ".join(c),
)
def test_reading_a_damaged_log(command: list[str], violation_log: bytes) -> None:
    def argv(d: Path) -> list[str]:
        extra = ["-o", str(d / "report.html")] if command == ["report"] else []
        return [*command, str(d / "v.jsonl"), *extra]

    _fuzz_file("v.jsonl", violation_log, argv)()


def test_replay_of_a_damaged_trace() -> None:
    t = 10**9
    lines = []
    for k in range(20):
        t += 10**7
        lines.append({"t_ns": t, "name": "distance_to_target", "value": 10 - k // 2})
        lines.append({"t_ns": t + 1, "name": "classifier", "value": k % 3})
        lines.append({"t_ns": t + 2, "name": "turnoffUVC", "value": k % 2 == 0})
    seed = "".join(json.dumps(x) + "\n" for x in lines).encode()
    _fuzz_file(
        "t.jsonl",
        seed,
        lambda d: [
            "replay",
            str(EXAMPLES / "srobot.yaml"),
            str(d / "t.jsonl"),
            "-o",
            str(d / "out.jsonl"),
        ],
    )()
