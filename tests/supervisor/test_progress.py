"""supervisor/progress.py: the one progress line of replay, report and fleet."""

from __future__ import annotations

import io
import os

from supervisor.progress import Line


def test_a_pipe_gets_nothing_not_even_the_closing_newline() -> None:
    out = io.StringIO()
    line = Line("replay", out)
    line.messages(10, 100)
    line.end()
    assert out.getvalue() == ""


def _drain(master: int) -> bytes:
    """All the pty gave, its writer closed: one read may return only a first part."""
    out = b""
    while True:
        try:
            chunk = os.read(master, 4096)
        except OSError:  # EIO: the slave side is closed and everything was read
            break
        if not chunk:
            break
        out += chunk
    os.close(master)
    return out


def test_a_terminal_gets_one_line_redrawn_in_place_and_closed_once() -> None:
    master, slave = os.openpty()
    with open(slave, "w", closefd=True) as tty:
        line = Line("replay", tty)
        assert line.on
        line.messages(10, 100)
        line.messages(1_000, None)
        line.end()
        line.end()  # a second end adds nothing
    text = _drain(master).decode()
    # the terminal's line discipline turns \n into \r\n
    assert text == "\rreplay: 10 messages of 100 (10 %)  \rreplay: 1,000 messages  \r\n"


def test_quiet_is_silent_on_a_terminal_too() -> None:
    master, slave = os.openpty()
    with open(slave, "w", closefd=True) as tty:
        line = Line("fleet", tty, on=False)
        line.show("1/2 bags")
        line.end()
        tty.write("x")
    assert _drain(master) == b"x"
