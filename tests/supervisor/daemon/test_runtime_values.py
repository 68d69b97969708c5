"""Runtime.on_values takes a value of exactly its input's C type in fewer steps
(supervisor/daemon/runtime.py); whatever the value, the input ends as ``coerce``
says: the same value and type, the same rejection, NaN and stale counts and events."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from supervisor.daemon.runtime import InputSpec, Runtime, coerce


class _Ticks:
    """A monitor that counts its steps (the runtime's values are what is tested)."""

    def __init__(self) -> None:
        self.steps = 0

    def tick(self, values: Sequence[Any]) -> Sequence[int]:
        self.steps += 1
        return [0]

    def reset(self) -> None: ...
    def reset_requirement(self, index: int) -> None: ...


raws = st.one_of(
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.binary(min_size=1, max_size=2),
    st.text(max_size=2),
    st.none(),
)


@settings(max_examples=500, deadline=None)
@given(
    vtype=st.sampled_from(["bool", "int64", "double"]),
    raws=st.lists(raws, min_size=1, max_size=6),
    stale_first=st.booleans(),
)
def test_each_value_ends_as_coerce_says(vtype: str, raws: list[Any], stale_first: bool) -> None:
    monitor = _Ticks()
    rt = Runtime(
        [InputSpec("x", vtype), InputSpec("go", "bool")],
        monitor,
        policy="on_trigger",
        trigger="go",
    )
    t = 1_000
    rt.on_values([("go", False)], t)
    rejected = nan = messages = 0
    last: Any = None
    stale_now = False
    for k, raw in enumerate(raws):
        t += 1_000_000
        if stale_first and k == 1:
            stale = rt.check_stale(t, 1)
            assert [e.what for e in stale] == (["input_stale"] * (1 + (last is not None)))
            stale_now = last is not None
            t += 1
        was_stale = rt.input_stats()["x"]["stale"]
        _, events = rt.on_values([("x", raw)], t)
        want, why = coerce(raw, vtype)
        what = [e.what for e in events]
        if why is not None:
            rejected += 1
            assert what == ["input_rejected"]
            continue
        messages += 1
        last, stale_now = want, False
        got = rt.snapshot()["x"]
        assert type(got) is type(want)
        assert got == want or (math.isnan(got) and math.isnan(want))
        is_nan = want != want
        nan += is_nan
        assert what == ["input_nan"] * is_nan + ["input_recovered"] * was_stale
    stats = rt.input_stats()["x"]
    assert (stats["rejected"], stats["nan"], stats["messages"]) == (rejected, nan, messages)
    assert stats["stale"] == stale_now
    if last is not None:
        rt.on_values([("go", True)], t + 1)
        assert monitor.steps == 1
