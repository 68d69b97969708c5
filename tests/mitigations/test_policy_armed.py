"""What a policy says its next violation does first (RequirementPolicy.armed, the
halt path's plan: docs/reference/log.md#the-halt-path) is what :meth:`on_step` does,
whatever the configuration, the history before and the time of that step, as long
as the time is not before ``from_ns``."""

from __future__ import annotations

import copy

from hypothesis import given, settings
from hypothesis import strategies as st

from mitigations.policy import Act, Report, RequirementPolicy
from mitigations.settings import Confirm, Escalation, PolicyConfig

MS = 1_000_000

configs = st.builds(
    PolicyConfig,
    debounce_steps=st.integers(1, 3),
    debounce_ms=st.sampled_from([0.0, 0.0, 5.0]),
    cooldown_ms=st.sampled_from([0.0, 0.0004, 3.0, 20.0, 20.5]),
    reset=st.sampled_from(["never", "after_mitigation"]),
    latch=st.booleans(),
    repeat_ms=st.just(7.0),
    escalate=st.one_of(
        st.none(),
        st.builds(
            Escalation, after_ms=st.sampled_from([0.0, 9.0]), actions=st.just(("power_off",))
        ),
    ),  # fmt: skip
    confirm=st.one_of(
        st.none(),
        st.builds(
            Confirm,
            variable=st.just("halted"),
            equals=st.just(True),
            within_ms=st.sampled_from([0.0, 4.0]),
        ),
    ),  # fmt: skip
)
# a history: (flagged, microseconds since the step before) per step, and operator resets
steps = st.lists(
    st.tuples(st.sampled_from([True, False, False, "reset"]), st.integers(1, 15_000)),
    max_size=30,
)


@settings(max_examples=400, deadline=None)
@given(config=configs, history=steps, later_us=st.integers(0, 30_000))
def test_an_armed_policy_does_first_what_it_armed(
    config: PolicyConfig, history: list[tuple[bool | str, int]], later_us: int
) -> None:
    pol = RequirementPolicy(config, ("halt", "uv_off"), repeatable=("halt",))
    t, tick, armed_seen = 10**12, 0, 0
    for flagged, gap_us in history:
        t += gap_us * 1000
        if flagged == "reset":
            pol.operator_reset()
            continue
        armed = pol.armed()
        if armed is not None:
            armed_seen += 1
            # at any time from from_ns on, on_step does first what was armed
            at = max(t, armed.from_ns) + later_us * 1000
            first = copy.deepcopy(pol).on_step(True, tick, at, {"halted": False})[:2]
            assert first == [
                Report(tick, armed.policy_state),
                Act(armed.actions, "violation"),
            ]
        pol.on_step(bool(flagged), tick, t, {"halted": False})
        pol.on_time(t, {"halted": False})
        tick += 1


def test_what_is_not_armed() -> None:
    """Live state, a debounce, a cooldown still running are not armed."""
    debounced = RequirementPolicy(PolicyConfig(debounce_steps=2), ("halt",))
    assert debounced.armed() is None
    plain = RequirementPolicy(PolicyConfig(cooldown_ms=20.0), ("halt",))
    armed = plain.armed()
    assert armed is not None and armed.actions == ("halt",)
    assert armed.policy_state["cooldown"] == "ok" and armed.policy_state["violations"] == 1
    plain.on_step(True, 0, 5 * MS, {})  # an episode: live state until it holds again
    assert plain.armed() is None
    plain.on_step(False, 1, 6 * MS, {})
    again = plain.armed()
    assert again is not None and again.from_ns == 25 * MS  # its cooldown from the act
    assert again.policy_state["violations"] == 2
