"""The adversary, kept: mutations of the shipped configs and their FRETISH text.

Every outcome of ``check`` is exit 0, or exit 1 with a ``FILE:LINE`` line, within a
time and memory limit, never a traceback; and every config ``check`` accepts is
accepted by what ``run`` and reload do before monitoring (``prepare_session``:
the same validation, then the monitor and the session).  The default run tries a
few examples; the ``slow`` one many (docs/reference/faults.md, bad configs).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[3]
EXAMPLES = ROOT / "supervisor" / "data" / "examples"
CONFIGS = sorted(p.name for p in EXAMPLES.glob("*.yaml"))
TEXTS = {name: (EXAMPLES / name).read_text() for name in CONFIGS}

TIME_S = 120
MEMORY = 3 << 30  # address space of check and the compiler it runs
# The child limits itself before it becomes `python -m supervisor` (no preexec_fn:
# the test process has threads).
LIMITED = (
    "import os, resource, sys;"
    f"resource.setrlimit(resource.RLIMIT_AS, ({MEMORY}, {MEMORY}));"
    f"resource.setrlimit(resource.RLIMIT_CPU, ({TIME_S}, {TIME_S}));"
    "os.execv(sys.executable, [sys.executable, '-m', 'supervisor', *sys.argv[1:]])"
)
LOCATED = re.compile(r"^\S+:\d+(:\d+)?: \S")
NUMBER = re.compile(r"(?<![\w.])-?\d+(\.\d+)?(?![\w.])")

BAD_NUMBERS = [".nan", ".inf", "-.inf", "'nan'", "1e999", "1" + "0" * 400, "-1", "0", "true",
               "abc", "0.0001", "99999999999999999999", "1" + "0" * 5000]  # fmt: skip


def _mutate_number(text: str, data: st.DataObject) -> str:
    spots = list(NUMBER.finditer(text))
    if not spots:
        return text
    m = data.draw(st.sampled_from(spots))
    return text[: m.start()] + data.draw(st.sampled_from(BAD_NUMBERS)) + text[m.end() :]


def _mutate_line(text: str, data: st.DataObject) -> str:
    lines = text.splitlines(keepends=True)
    if not lines:  # an earlier mutation left nothing
        return text
    i = data.draw(st.integers(0, len(lines) - 1))
    how = data.draw(st.sampled_from(["delete", "duplicate", "truncate"]))
    if how == "delete":
        del lines[i]
    elif how == "duplicate":
        lines.insert(i, lines[i])
    else:
        return "".join(lines[:i]) + lines[i][: data.draw(st.integers(0, len(lines[i])))]
    return "".join(lines)


def _mutate_text(text: str, data: st.DataObject) -> str:
    """FRETISH and define text: nest deeply, or splice in an operator or number."""
    spots = [m for m in re.finditer(r"(satisfy |define: )(\S+)", text)]
    if not spots:
        return text
    m = data.draw(st.sampled_from(spots))
    n = data.draw(st.sampled_from([3, 99, 101, 3000]))
    word = m.group(2)
    new = data.draw(
        st.sampled_from(
            [
                "!" * n + word,
                "(" * n + word + ")" * n,
                " & ".join([word] * n),
                word + " & 99999999999999999999 > 0",
                word + " & 1e999 > 0",
                "within " + data.draw(st.sampled_from(BAD_NUMBERS)) + " ticks satisfy " + word,
            ]
        )
    )
    return text[: m.start(2)] + new + text[m.end(2) :]


def _mutate_nesting(text: str, data: st.DataObject) -> str:
    n = data.draw(st.sampled_from([10, 60, 5000]))
    return text + "\nanalysis: " + "[" * n + "]" * n + "\n"


MUTATIONS = [_mutate_number, _mutate_line, _mutate_text, _mutate_nesting]


def check(path: Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "SAFETY_SUPERVISOR_DEBUG"}
    return subprocess.run(
        [sys.executable, "-c", LIMITED, "check", str(path)],
        capture_output=True,
        text=True,
        cwd=path.parent,
        env=env,
        timeout=TIME_S + 30,
    )


def fuzz_once(workdir: Path, data: st.DataObject) -> None:
    name = data.draw(st.sampled_from(CONFIGS))
    text = TEXTS[name]
    for _ in range(data.draw(st.integers(1, 3))):
        text = data.draw(st.sampled_from(MUTATIONS))(text, data)
    shutil.rmtree(workdir, ignore_errors=True)
    shutil.copytree(EXAMPLES, workdir)  # the FRET and OGMA files the examples import
    path = workdir / name
    path.write_text(text)
    out = check(path)
    said = out.stdout + out.stderr
    assert "Traceback" not in said and "internal error" not in said, said[-2000:]
    assert out.returncode in (0, 1), (out.returncode, said[-2000:])
    if out.returncode == 1:
        err = out.stderr.strip().splitlines()
        if err:  # a config error: one located line
            assert len(err) == 1 and LOCATED.match(err[0]), out.stderr[-2000:]
        else:  # the requirements' table: each failure is located
            fails = [ln for ln in out.stdout.splitlines() if ln.startswith(("FAIL", "error"))]
            fails = [ln.split(None, 2 if ln.startswith("FAIL") else 1)[-1] for ln in fails]
            assert all(LOCATED.match(f) for f in fails), out.stdout[-2000:]
            assert fails or "analysis found" in out.stdout, out.stdout[-2000:]
        return
    # Accepted by check: run's start-up (and reload) must accept it too, unless check's
    # time budget skipped an analysis (its "skipped:" line, on a loaded machine) that
    # the start-up then finished: that finding is refused at its line, as check's are.
    from monitors.errors import UserError
    from supervisor.daemon.process import prepare_session

    try:
        session = prepare_session(path, workdir / "build")
    except UserError as e:
        if "skipped:" not in out.stdout:
            raise
        assert e.file and e.line and e.message.startswith("analysis:"), str(e)
        return
    assert session.cleanup is not None
    session.cleanup()


@settings(max_examples=4, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.data())
def test_mutated_configs_are_checked_cleanly(tmp_path_factory: pytest.TempPathFactory, data):
    fuzz_once(tmp_path_factory.mktemp("fuzz") / "c", data)


@pytest.mark.slow
@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.data())
def test_many_mutated_configs_are_checked_cleanly(tmp_path_factory: pytest.TempPathFactory, data):
    fuzz_once(tmp_path_factory.mktemp("fuzz") / "c", data)


@pytest.mark.slow  # a full check in a subprocess: full suite only (README, quick tier)
def test_run_validates_what_check_validates(tmp_path: Path) -> None:
    """A config check rejects only in its analyses (contradicting requirements) is
    refused by run's start-up as well, at the requirement's line."""
    from monitors.errors import UserError
    from supervisor.daemon.process import prepare_session

    text = TEXTS["template.yaml"].replace(
        "\nrequirements:\n",
        "\nrequirements:\n  - {id: halt_on, text: Robot shall always satisfy halted}\n"
        "  - {id: halt_off, text: Robot shall always satisfy !halted}\n",
    )
    path = tmp_path / "c.yaml"
    path.write_text(text)
    out = check(path)
    assert out.returncode == 1 and "analysis found" in out.stdout, out.stdout[-2000:]
    with pytest.raises(UserError) as e:
        prepare_session(path, tmp_path / "build")
    assert e.value.file == str(path) and e.value.line is not None
    assert str(e.value).startswith(f"{path}:")
