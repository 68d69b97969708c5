"""A mitigation policy's deadlines (mitigations/policy.py) as the core's clock uses
them: ``Core.advance`` runs ``on_time`` at each deadline until the next one is
later, so ``on_time(t)`` must leave ``next_deadline()`` None or after ``t``, or the
daemon's loop (and ``replay``) never gets past ``t``.  Pure state, no monitor."""

from __future__ import annotations

import pytest

from mitigations.policy import RequirementPolicy
from mitigations.settings import Confirm, Escalation, PolicyConfig

MS = 1_000_000

CONFIGS = [
    PolicyConfig(debounce_ms=25),
    PolicyConfig(debounce_steps=3, debounce_ms=4, cooldown_ms=50, reset="after_mitigation"),
    PolicyConfig(reset="after_ms", reset_after_ms=30),
    PolicyConfig(latch=True, repeat_ms=40, reset="after_mitigation"),
    PolicyConfig(escalate=Escalation(20, ("stop",)), reset="after_mitigation"),
    PolicyConfig(confirm=Confirm("halt", True, 15), reset="after_mitigation"),
]


@pytest.mark.parametrize("config", CONFIGS, ids=lambda c: repr(c)[:60])
@pytest.mark.parametrize("flagged", [[True], [True, True], [True, False, True]])
def test_time_alone_moves_every_deadline_past_now(config, flagged):
    pol = RequirementPolicy(config, ("stop",), ("stop",))
    for k, f in enumerate(flagged):
        pol.on_step(f, k, k * MS, {"halt": False})
    t = len(flagged) * MS
    end = t + 200 * MS
    while True:  # the core's advance loop, without a step, for 200 ms (a latch repeats)
        d = pol.next_deadline()
        if d is None or d > end:
            return
        t = max(t, d)
        pol.on_time(t, {"halt": False})
        after = pol.next_deadline()
        assert after is None or after > t, f"on_time({t}) left the deadline at {after}"
