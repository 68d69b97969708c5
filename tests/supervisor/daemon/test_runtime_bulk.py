"""``Runtime.step_rows``, the bulk step (supervisor/daemon/runtime.py): a batch of
rows in, the same decisions out as ``on_values`` row by row, and the runtime left
as row-by-row stepping leaves it.  Two copies of the real compiled sRobot monitor,
one per runtime; the whole replay paths are compared in test_step_paths.py."""

from __future__ import annotations

import random
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from monitors.backends.load import compile_spec
from supervisor.daemon.runtime import InputSpec, Rows, Runtime
from supervisor.pipeline import project_for

ROOT = Path(__file__).resolve().parents[3]
MS = 1_000_000
RANGES = {"classifier": (0, 2), "distance_to_target": (0, 100), "OpState": (0, 3)}


@pytest.fixture(scope="module")
def monitors(tmp_path_factory: pytest.TempPathFactory) -> Any:
    spec = project_for(ROOT / "config" / "srobot.yaml", ros=False).spec()
    # each runtime its own copy: each has its own C state
    return spec, [compile_spec(spec, tmp_path_factory.mktemp(f"bulk{k}")) for k in range(2)]


def rows(seed: int, n: int, names: list[str], types: dict[str, str]) -> list[tuple[int, str, Any]]:
    rng = random.Random(seed)
    t, out = 0, []
    for _ in range(n):
        t += rng.randint(1, 3 * MS)
        name = rng.choice(names)
        lo, hi = RANGES.get(name, (0, 1))
        value = rng.randint(lo, hi)
        out.append((t, name, bool(value) if types[name] == "bool" else value))
    return out


def as_rows(msgs: list[tuple[int, str, Any]], types: dict[str, str]) -> Rows:
    t = np.array([m[0] for m in msgs], dtype=np.int64)
    values = {}
    for name, vtype in types.items():
        mask = np.array([m[1] == name for m in msgs])
        dtype = np.bool_ if vtype == "bool" else np.int64
        column = np.array([m[2] if m[1] == name else 0 for m in msgs], dtype=dtype)
        values[name] = (mask, column)
    return Rows(t, values)


def state(rt: Runtime) -> Any:
    return rt.tick, list(rt.recent), rt.snapshot(), rt.input_stats(), rt.bulk_ready


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32),
    trigger=st.sampled_from([None, "turnoffUVC", "classifier", "halt"]),
    stale_ms=st.sampled_from([None, 4, 50]),
    n=st.integers(1, 400),
)
def test_step_rows_decides_as_on_values_row_by_row(monitors, seed, trigger, stale_ms, n):
    spec, (bulk_mon, exact_mon) = monitors
    types = {v.name: v.type for v in spec.inputs}
    names = list(types)
    policy = "on_message" if trigger is None else "on_trigger"
    runtimes = []
    for mon in (bulk_mon, exact_mon):
        mon.reset()
        inputs = [InputSpec(v.name, v.type) for v in spec.inputs]
        runtimes.append(Runtime(inputs, mon, policy=policy, trigger=trigger))
    bulk_rt, exact_rt = runtimes
    stale_ns = None if stale_ms is None else stale_ms * MS
    start = [(k * 10, name, False if types[name] == "bool" else 0) for k, name in enumerate(names)]
    msgs = rows(seed, n, names, types)
    for t, name, value in start:  # every input a value: the runtime is ready
        for rt in runtimes:
            rt.on_message(name, value, t)

    exact = [exact_rt.on_message(name, value, t)[0] for t, name, value in msgs]
    exact_steps = [(r.tick, r.t_ns, r.violated, r.inputs) for r in exact if r is not None]

    done = bulk_rt.step_rows(as_rows(msgs, types), stale_ns)
    assert done.rows <= n
    event("none taken" if not done.rows else "all taken" if done.rows == n else "some taken")
    event("stopped at a violation" if done.result is not None else "no violation")
    taken = [r for r in exact[: done.rows] if r is not None]
    assert done.ticks == len(taken)
    if done.result is None:
        assert not any(r.violated for r in taken)
    else:  # the bulk step stops after the first violating step, and hands it on
        assert (done.result.tick, done.result.t_ns, done.result.violated, done.result.inputs) == (
            exact_steps[done.ticks - 1]
        )
        assert [r for r in taken if r.violated] == [taken[-1]]
    rest = [bulk_rt.on_message(name, value, t)[0] for t, name, value in msgs[done.rows :]]
    bulk_steps = [(r.tick, r.t_ns, r.violated, r.inputs) for r in rest if r is not None]
    assert bulk_steps == exact_steps[done.ticks :]
    assert state(bulk_rt) == state(exact_rt)
    if stale_ns is None and exact_steps and not any(s[2] for s in exact_steps):
        assert done.rows == n  # nothing stops a batch without violations
