"""SIGTERM as Ctrl-C, and both held off while a command's children are being stopped
(supervisor/tools/stopping.py), with real signals sent to this process."""

from __future__ import annotations

import os
import signal

import pytest

from supervisor.tools.stopping import sigterm_as_interrupt, uninterrupted


def _handlers_run() -> None:
    """Python runs a signal's handler at its next check, which a loop's jump makes."""
    for _ in range(1000):
        pass


def test_sigterm_in_the_block_is_a_keyboard_interrupt_and_the_handler_is_put_back() -> None:
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt), sigterm_as_interrupt():
        os.kill(os.getpid(), signal.SIGTERM)
        _handlers_run()
    assert signal.getsignal(signal.SIGTERM) is before


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_a_stop_signal_during_a_stop_waits_for_its_end(sig: signal.Signals) -> None:
    stopped = False
    with pytest.raises(KeyboardInterrupt), sigterm_as_interrupt():
        with uninterrupted():
            os.kill(os.getpid(), sig)
            _handlers_run()
            stopped = True  # reached: the signal did not cut the stop short
        pytest.fail("the signal held off was not raised after the stop")
    assert stopped
