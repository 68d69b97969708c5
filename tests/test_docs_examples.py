"""Every shell example of README.md and docs/ runs, and its shown output is compared.

Sybil finds the examples; the convention (docs/README.md, "Generated and executed"):

- a ```` ```console ```` block is run: each ``$ `` line is a command (bash), the lines
  after it its output (stdout and stderr together), ``...`` matching anything, and a
  last ``[exit N]`` line the exit status when it is not 0;
- a ```` ```sh ```` block is commands whose output is not shown: each line runs and
  must exit 0;
- an example that cannot run here (it needs root, a robot, a running daemon) is
  preceded by ``<!-- skip: next "why" -->`` (Sybil's skip directive): reported as
  skipped with that reason, never silently;
- an example that reads files a robot would have (a daemon's rotated logs) is
  preceded by ``<!-- files: NAME -->``: the files of ``FILES[NAME]``, made once per
  test run with the product itself, are copied into its directory;
- a ```` ```yaml ```` block that begins with ``component:`` is a whole config: it
  must pass ``safety-supervisor check`` (an excerpt begins with another key);
- a ```` ```sql ```` block is a query run in DuckDB in the example's directory (with
  its ``<!-- files: NAME -->``), and the ```` ```text ```` block right after it is
  what it prints (``...`` matching anything);
- any other block is not an example (a synopsis, an excerpt), and may not hold a
  ``$ `` prompt line (test below).

Each block runs in a fresh directory of its own, with its own HOME and XDG
directories, ``config/`` and ``packaging/`` of the checkout linked in, the test run's
own ROS domain, and nothing of systemd's environment.
"""

from __future__ import annotations

import atexit
import doctest
import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from unittest import SkipTest

import pytest
from sybil import Document, Example, Region
from sybil.example import SybilFailure
from sybil.parsers.markdown import CodeBlockParser, SkipParser
from sybil.parsers.markdown.lexers import DirectiveInHTMLCommentLexer

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])
CHECKER = doctest.OutputChecker()
EXIT = re.compile(r"^\[exit (\d+)\]$")
# Examples that cannot run in a test, each with its reason in the markdown; a new one
# has to be argued for here too.
SKIPPED_AT_MOST = 5
# Files an example may ask for (``<!-- files: NAME -->``): NAME -> what makes them.
FILES = {"rotated-logs": "doclogs", "fleet-dataset": "fleetdata"}
# Files made by the demo over DDS: the examples that ask for them are marked ros.
FILES_ON_ROS = ("rotated-logs",)
# A ```sql block and the ```text block right after it (blank lines between).
SQL = re.compile(r"^```sql\n(?P<sql>.*?)^```\n\s*^```text\n(?P<out>.*?)^```$", re.M | re.S)
_made: dict[str, Path] = {}


def _files(name: str) -> Path:
    """The files ``name`` stands for, made on first use (the demo runs once)."""
    if name not in _made:
        import importlib

        if name not in FILES:
            raise AssertionError(f"<!-- files: {name} -->: not one of {sorted(FILES)}")
        out = Path(tempfile.mkdtemp(prefix=f"docs-files-{name}-"))
        atexit.register(shutil.rmtree, out, True)
        importlib.import_module(FILES[name]).make(out, _environment(out))
        _made[name] = out
    return _made[name]


def _environment(home: Path) -> dict[str, str]:
    from rosutil import ROS_ENV  # this test run's own DDS domain, localhost only

    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("SAFETY_SUPERVISOR_DEBUG", "STATE_DIRECTORY", "RUNTIME_DIRECTORY")
        and not k.startswith(("XDG_", "NOTIFY_", "WATCHDOG_", "LOGS_DIRECTORY"))
    }
    env |= {
        "HOME": str(home),
        "XDG_CACHE_HOME": str(home / ".cache"),
        "XDG_CONFIG_HOME": str(home / ".config"),
        "XDG_STATE_HOME": str(home / ".local/state"),
        "XDG_RUNTIME_DIR": str(home / "run"),
        "PATH": f"{Path(sys.executable).parent}:{env.get('PATH', '/usr/bin:/bin')}",
        "COLUMNS": "100",
        "LC_ALL": "C.UTF-8",
        **ROS_ENV,
    }
    return env


def _commands(source: str, console: bool) -> list[tuple[str, list[str]]]:
    """(command, shown output lines) of a block."""
    out: list[tuple[str, list[str]]] = []
    for line in source.splitlines():
        if console and line.startswith("$ "):
            out.append((line[2:], []))
        elif console and out:
            out[-1][1].append(line)
        elif not console and line.strip() and not line.lstrip().startswith("#"):
            out.append((line, []))
        elif console and line.strip():
            raise AssertionError(f"output before any '$ ' command: {line!r}")
    return out


def _run(example: Example, console: bool) -> str | None:
    with tempfile.TemporaryDirectory(prefix="docs-example-") as tmp:
        cwd = Path(tmp)
        for name in ("config", "packaging"):
            (cwd / name).symlink_to(ROOT / name)
        (cwd / "run").mkdir(mode=0o700)
        env = _environment(cwd)
        name = example.namespace.pop("files", None)
        if name is not None:
            shutil.copytree(_files(name), cwd, dirs_exist_ok=True, symlinks=True)
        for command, shown in _commands(example.parsed, console):
            done = subprocess.run(
                ["bash", "-c", command],
                cwd=cwd,
                env=env,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
                timeout=600,
            )
            want = list(shown)
            status = 0
            if want and EXIT.match(want[-1]):
                status = int(EXIT.match(want[-1]).group(1))  # type: ignore[union-attr]
                want.pop()
            got = "\n".join(line.rstrip() for line in done.stdout.splitlines()).rstrip("\n")
            expected = "\n".join(line.rstrip() for line in want).rstrip("\n")
            if done.returncode != status:
                return f"$ {command}\nexit {done.returncode}, the doc shows {status}\n{got}"
            if console and not CHECKER.check_output(expected + "\n", got + "\n", doctest.ELLIPSIS):
                return f"$ {command}\nthe doc shows:\n{expected}\nthe command printed:\n{got}"
    return None


def _check_config(example: Example) -> str | None:
    """A whole config shown in the docs passes `check` (warnings allowed)."""
    if not example.parsed.startswith("component:"):
        return None
    with tempfile.TemporaryDirectory(prefix="docs-config-") as tmp:
        path = Path(tmp) / "shown.yaml"
        path.write_text(example.parsed)
        done = subprocess.run(
            [sys.executable, "-m", "supervisor", "check", str(path)],
            cwd=tmp,
            env=_environment(Path(tmp)),
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=600,
        )
    if done.returncode != 0:
        return f"the config shown does not pass check (exit {done.returncode}):\n" + "\n".join(
            line for line in (done.stdout + done.stderr).splitlines() if not line.startswith("ok ")
        )
    return None


@dataclass(frozen=True)
class Query:
    """A ```sql block and its ```text block (not a tuple: Sybil's skips are tuples)."""

    sql: str
    shown: str


def _sql(example: Example) -> str | None:
    """A query in DuckDB, run where an example runs; its printed table compared."""
    query, shown = example.parsed.sql, example.parsed.shown
    with tempfile.TemporaryDirectory(prefix="docs-sql-") as tmp:
        cwd = Path(tmp)
        name = example.namespace.pop("files", None)
        if name is not None:
            shutil.copytree(_files(name), cwd, dirs_exist_ok=True, symlinks=True)
        done = subprocess.run(
            [sys.executable, "-c", "import duckdb, sys; print(duckdb.sql(sys.stdin.read()))"],
            cwd=cwd,
            env=_environment(cwd),
            input=query,
            capture_output=True,
            text=True,
            timeout=600,
        )
    got = "\n".join(line.rstrip() for line in done.stdout.splitlines()).strip("\n")
    expected = "\n".join(line.rstrip() for line in shown.splitlines()).strip("\n")
    if done.returncode != 0:
        return f"the query failed (exit {done.returncode}):\n{query}\n{done.stderr}"
    if not CHECKER.check_output(expected + "\n", got + "\n", doctest.ELLIPSIS):
        return f"the doc shows:\n{expected}\nthe query printed:\n{got}"
    return None


def _sql_parser(document: Document):  # noqa: ANN202 (Sybil's parser protocol)
    for m in SQL.finditer(document.text):
        yield Region(m.start(), m.end(), Query(m.group("sql"), m.group("out")), _sql)


def _evaluator(console: bool):  # noqa: ANN202 (Sybil's evaluator protocol)
    def evaluate(example: Example) -> str | None:
        return _run(example, console)

    return evaluate


def _files_parser(document: Document):  # noqa: ANN202 (Sybil's parser protocol)
    """``<!-- files: NAME -->``: the next example runs beside the files NAME stands for."""

    def ask(example: Example) -> None:
        example.namespace["files"] = example.parsed

    for lexed in DirectiveInHTMLCommentLexer("files")(document):
        yield Region(lexed.start, lexed.end, lexed.lexemes["arguments"].strip(), ask)


PARSERS = [
    CodeBlockParser("console", _evaluator(console=True)),
    CodeBlockParser("sh", _evaluator(console=False)),
    CodeBlockParser("yaml", _check_config),
    SkipParser(),
    _files_parser,
    _sql_parser,
]


def _examples(path: Path) -> list[Example]:
    return list(Document.parse(str(path), *PARSERS))


def _marks(path: Path) -> list[pytest.MarkDecorator]:
    # The demo runs the daemon and the simulated robot over DDS (on the test's own
    # ROS_DOMAIN_ID, which the examples inherit); so do the files an example asks for.
    text = path.read_text()
    on_ros = any(f"<!-- files: {name} -->" in text for name in FILES_ON_ROS)
    return [pytest.mark.ros] if "\n$ safety-supervisor demo " in text or on_ros else []


@pytest.mark.parametrize(
    "path", [pytest.param(p, marks=_marks(p), id=str(p.relative_to(ROOT))) for p in DOCS]
)
def test_the_shell_examples_print_what_the_docs_show(path: Path) -> None:
    failures: list[str] = []
    for example in _examples(path):
        where = f"{path.relative_to(ROOT)}:{example.line}"
        try:
            example.evaluate()
        except SkipTest:
            continue
        except SybilFailure as e:
            failures.append(f"{where}:\n{e.result}")
        except subprocess.TimeoutExpired as e:
            failures.append(f"{where}: timed out: {e.cmd}")
    assert not failures, "\n\n".join(failures)


def test_examples_that_do_not_run_say_why_and_are_few() -> None:
    skips = [
        (path, example.line, example.parsed)
        for path in DOCS
        for example in _examples(path)
        if isinstance(example.region.parsed, tuple)
    ]
    assert all(reason for _, _, (_, reason) in skips), skips
    assert len(skips) <= SKIPPED_AT_MOST, skips


def test_a_prompt_is_never_in_a_block_that_does_not_run() -> None:
    fence = re.compile(r"^```(\S*)\n(.*?)^```", re.M | re.S)
    hidden = [
        f"{path.relative_to(ROOT)}: a ```{m.group(1)} block with a '$ ' line"
        for path in DOCS
        for m in fence.finditer(path.read_text())
        if m.group(1) not in ("console", "sh")
        and any(line.startswith("$ ") for line in m.group(2).splitlines())
    ]
    assert not hidden, "\n".join(hidden)


def test_every_sql_block_shows_its_output() -> None:
    fence = re.compile(r"^```sql$", re.M)
    alone = [
        f"{path.relative_to(ROOT)}: {len(fence.findall(text)) - len(SQL.findall(text))} "
        "```sql block(s) without a ```text block right after"
        for path in DOCS
        if len(fence.findall(text := path.read_text())) != len(SQL.findall(text))
    ]
    assert not alone, "\n".join(alone)


def test_a_query_whose_output_differs_fails(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text(
        "```sql\nSELECT 40 + 2 AS n;\n```\n\n```text\n...\n│    42 │\n...\n```\n\n"
        "```sql\nSELECT 40 + 2 AS n;\n```\n```text\n...\n│    41 │\n...\n```\n\n"
        "```sql\nSELECT * FROM no_such_table;\n```\n\n```text\n```\n"
    )
    outcomes = []
    for example in _examples(page):
        try:
            example.evaluate()
            outcomes.append("ok")
        except SybilFailure as e:
            outcomes.append(str(e.result).splitlines()[0])
    assert outcomes == ["ok", "the doc shows:", "the query failed (exit 1):"]


def test_an_example_whose_output_differs_fails(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text(
        "```console\n$ printf 'one\\ntwo\\n'\none\n...\n```\n\n"
        "```console\n$ printf 'one\\ntwo\\n'\none\nthree\n```\n\n"
        "```console\n$ false\n```\n\n"
        '<!-- skip: next "shown, not run" -->\n```console\n$ false\n```\n'
    )
    outcomes = []
    for example in _examples(page):
        try:
            example.evaluate()
            outcomes.append("ok")
        except SybilFailure as e:
            outcomes.append(str(e.result).splitlines()[1])
        except SkipTest as e:
            outcomes.append(f"skipped: {e}")
    assert outcomes == [
        "ok",
        "the doc shows:",
        "exit 1, the doc shows 0",
        "ok",  # the skip directive itself
        "skipped: shown, not run",
    ]
