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


def test_a_terminal_gets_one_line_redrawn_in_place_and_closed_once() -> None:
    master, slave = os.openpty()
    with open(slave, "w", closefd=True) as tty:
        line = Line("replay", tty)
        assert line.on
        line.messages(10, 100)
        line.messages(1_000, None)
        line.end()
        line.end()  # a second end adds nothing
    text = os.read(master, 4096).decode()
    os.close(master)
    # the terminal's line discipline turns \n into \r\n
    assert text == "\rreplay: 10 messages of 100 (10 %)  \rreplay: 1,000 messages  \r\n"


def test_quiet_is_silent_on_a_terminal_too() -> None:
    master, slave = os.openpty()
    with open(slave, "w", closefd=True) as tty:
        line = Line("fleet", tty, on=False)
        line.show("1/2 bags")
        line.end()
        tty.write("x")
    assert os.read(master, 4096) == b"x"
    os.close(master)
