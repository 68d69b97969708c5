"""``safety-supervisor ARGS`` run by the CLI's main in this process, ended as its
subprocess would be (supervisor/__main__.py): exit code, stdout and stderr, without
a subprocess's start and imports.  Keep real subprocesses for what needs one: a
terminal, signals, limits, the installed entry point, the exit path itself."""

from __future__ import annotations

import contextlib
import io
import subprocess
import sys
from collections.abc import Iterator


def _stream() -> io.TextIOWrapper:
    # with a .buffer, like a real sys.stdout (some commands write bytes to it)
    return io.TextIOWrapper(io.BytesIO(), encoding="utf-8", write_through=True)


def _text(stream: io.TextIOWrapper) -> str:
    stream.flush()
    buffer = stream.buffer
    assert isinstance(buffer, io.BytesIO)
    return buffer.getvalue().decode("utf-8", "replace")


def cli_main(*args: object, stdin: str = "") -> subprocess.CompletedProcess[str]:
    import monitors.ir.formula as formula
    from supervisor.cli import main

    argv = [str(a) for a in args]
    out, err = _stream(), _stream()
    parser_cache = formula._parser_cache_dir  # replay and check point it at their cache
    try:
        with (
            contextlib.redirect_stdout(out),
            contextlib.redirect_stderr(err),
            _stdin(io.StringIO(stdin)),
        ):
            try:
                code = main(argv)
            except SystemExit as e:  # argparse: usage errors (2), --help (0)
                code = e.code if isinstance(e.code, int) else 0 if e.code is None else 1
    finally:
        formula.use_parser_cache(parser_cache)
    return subprocess.CompletedProcess(["safety-supervisor", *argv], code, _text(out), _text(err))


@contextlib.contextmanager
def _stdin(stream: io.StringIO) -> Iterator[None]:
    saved, sys.stdin = sys.stdin, stream
    try:
        yield
    finally:
        sys.stdin = saved
