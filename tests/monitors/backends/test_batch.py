"""``LoadedMonitor.tick_batch`` (the shim's ``ss_tick_batch``) against ``tick`` and the
reference interpreter, with real gcc and cffi (and GHC + Copilot for one test).

A batch must step exactly as ``tick`` does row by row: the same flags, the state
carried over between calls and across resets, and the violating-row output exactly
the rows with a flag.  ``pack_columns`` must pack as ``tick``'s ``struct.pack`` does.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest
from harness import I64_MAX, I64_MIN, INPUTS, make_trace, oracle
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from monitors.backends.build import build_library, host_source, layout
from monitors.backends.c99 import write_c
from monitors.backends.load import Batch, LoadedMonitor, compile_spec, load_monitor
from monitors.backends.throughput import batch_rate, spec_rates
from monitors.errors import UserError
from monitors.ir.formula import parse_formula
from monitors.ir.spec import MonitorSpec, RequirementSpec, VarDecl
from tests.monitors.backends.test_c99 import WITHIN
from tests.monitors.backends.test_c99 import bool_f as c99_formula
from tests.monitors.backends.test_c99 import make_spec as c99_spec
from tests.monitors.backends.test_copilot import batch_formulas
from tests.monitors.backends.test_copilot import make_spec as copilot_spec

NAMES = [v.name for v in INPUTS]
QUICK = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def values(trace: list[dict]) -> list[list]:
    return [[row[n] for n in NAMES] for row in trace]


def columns(trace: list[dict]) -> list[list]:
    return [[row[n] for row in trace] for n in NAMES]


def one_by_one(mon: LoadedMonitor, trace: list[dict]) -> np.ndarray:
    """Flags of ``tick`` row by row, shaped as tick_batch's."""
    nreq = len(mon.requirement_ids)
    got = b"".join(mon.tick(v) for v in values(trace))
    return np.frombuffer(got, dtype=np.uint8).reshape(len(trace), nreq)


def check(batch: Batch, want: np.ndarray, what: str) -> None:
    assert batch.flags.dtype == np.uint8 and batch.flags.shape == want.shape, what
    if not np.array_equal(batch.flags, want):
        row, req = np.argwhere(batch.flags != want)[0]
        raise AssertionError(
            f"{what}: row {row}, requirement {req}: batch {batch.flags[row, req]}, "
            f"expected {want[row, req]}"
        )
    # the violating rows: exactly those with a flag, ascending, as intp
    assert batch.violating.dtype == np.intp, what
    assert np.array_equal(batch.violating, np.flatnonzero(want.any(axis=1))), what


def interpreted(spec: MonitorSpec, trace: list[dict]) -> np.ndarray:
    want = oracle(spec, trace)  # per requirement, per tick
    return np.array(want, dtype=np.uint8).T.reshape(len(trace), len(spec.requirements))


# ------------------------------------------------------------------ one spec, many traces


@pytest.fixture(scope="module")
def native(tmp_path_factory: pytest.TempPathFactory) -> tuple[MonitorSpec, LoadedMonitor]:
    # every operator and bound shape (test_copilot's targeted list) plus random ones
    spec = copilot_spec([*batch_formulas(seed=7, n=20), WITHIN], prefix="bt")
    return spec, compile_spec(spec, tmp_path_factory.mktemp("batch"))


@QUICK
@given(seed=st.integers(0, 2**32), n=st.integers(0, 300), cut=st.floats(0, 1))
def test_batch_equals_ticks_and_interpreter(native, seed: int, n: int, cut: float) -> None:
    spec, mon = native
    trace = make_trace(seed, n)
    want = interpreted(spec, trace)
    mon.reset()
    check(mon.tick_batch(mon.pack_columns(columns(trace))), want, "one batch, columns")
    mon.reset()
    check(Batch(one_by_one(mon, trace), np.flatnonzero(want.any(axis=1))), want, "tick")
    # split in two calls: the state carries over from the first to the second
    k = int(cut * n)
    mon.reset()
    first = mon.tick_batch(mon.pack_rows(values(trace[:k])))
    second = mon.tick_batch(mon.pack_rows(values(trace[k:])))
    check(first, want[:k], "first half")
    check(second, want[k:], "second half")


@QUICK
@given(seed=st.integers(0, 2**32), n=st.integers(1, 200), cut=st.floats(0, 1))
def test_batch_and_tick_interleave(native, seed: int, n: int, cut: float) -> None:
    # tick and tick_batch share one monitor state and one handler mechanism
    spec, mon = native
    trace = make_trace(seed, n)
    k = int(cut * n)
    mon.reset()
    got = np.concatenate(
        [one_by_one(mon, trace[:k]), mon.tick_batch(mon.pack_rows(values(trace[k:]))).flags]
    )
    assert np.array_equal(got, interpreted(spec, trace))


def test_resets_between_batches(native) -> None:
    spec, mon = native
    trace = make_trace(11, 120)
    rows = mon.pack_columns(columns(trace))
    mon.reset()
    fresh = mon.tick_batch(rows)
    mon.tick_batch(rows[:37])  # some pending state
    mon.reset()
    check(mon.tick_batch(rows), fresh.flags, "after reset")
    # one requirement reset between batches: it restarts, the others carry on
    victim = spec.requirements.index(next(r for r in spec.requirements if r.formula == WITHIN))
    mon.reset()
    mon.tick_batch(rows[:60])
    mon.reset_requirement(victim)
    got = mon.tick_batch(rows[60:])
    want = interpreted(spec, trace)[60:]
    want[:, victim] = interpreted(spec, trace[60:])[:, victim]
    check(got, want, "after resetting one requirement")


def test_empty_and_single_row_batches(native) -> None:
    spec, mon = native
    nreq = len(spec.requirements)
    trace = make_trace(3, 5)
    mon.reset()
    for empty in (b"", mon.pack_columns([[] for _ in NAMES]), np.empty(0, mon.row_dtype)):
        got = mon.tick_batch(empty)
        assert got.flags.shape == (0, nreq) and got.violating.shape == (0,)
    for i, row in enumerate(values(trace)):  # n = 1, five times: the state carries over
        got = mon.tick_batch(mon.pack_rows([row]))
        check(got, interpreted(spec, trace)[i : i + 1], f"single row {i}")


def test_violating_rows_are_exactly_the_flagged_rows(tmp_path: Path) -> None:
    spec = c99_spec([parse_formula("! b0"), parse_formula("i0 < 5")])
    mon = compile_spec(spec, tmp_path)
    b0 = [False, True, False, False, True, False]
    i0 = [0, 0, 9, 0, 9, 0]
    cols = [b0, [False] * 6, [False] * 6, i0, [0] * 6, [0.0] * 6, [0.0] * 6]
    got = mon.tick_batch(mon.pack_columns(cols))
    assert got.flags.tolist() == [[0, 0], [1, 0], [0, 1], [0, 0], [1, 1], [0, 0]]
    assert got.violating.tolist() == [1, 2, 4]
    holds = mon.tick_batch(mon.pack_rows([[False, False, False, 0, 0, 0.0, 0.0]] * 3))
    assert holds.violating.size == 0 and not holds.flags.any()


# ------------------------------------------------------------------ packing


def test_pack_columns_packs_as_tick_does(native) -> None:
    _, mon = native
    edge = [
        [True, False, True, True],
        [1, 0, 2.5, math.nan],  # any truth value, as struct's '?'
        [np.True_, False, 0, 1],
        [I64_MIN, I64_MAX, 0, True],
        [-1, 2**53 + 1, 7, 1],
        [math.nan, -0.0, math.inf, 1e-320],
        [2**53 + 1, -(2**63), 3, True],  # ints to double round as Python's float()
    ]
    rows = [list(r) for r in zip(*edge, strict=True)]
    assert mon.pack_columns(edge).tobytes() == mon.pack_rows(rows)
    assert mon.pack_columns([np.asarray(c) for c in edge]).tobytes() == mon.pack_rows(rows)
    assert mon.row_dtype.itemsize == mon.row_size == len(mon.pack_rows(rows[:1]))
    as_numpy = [
        np.asarray(c).astype(t)
        for c, t in zip(edge, ["?", "f4", "?", "i8", "i8", "f8", "i8"], strict=True)
    ]
    assert mon.pack_columns(as_numpy).tobytes() == mon.pack_columns(edge).tobytes()
    unsigned = [*edge[:4], np.array([0, 5, 2**32 - 1, 1], dtype=np.uint32), *edge[5:]]
    want = [list(r) for r in zip(*edge[:4], [0, 5, 2**32 - 1, 1], *edge[5:], strict=True)]
    assert mon.pack_columns(unsigned).tobytes() == mon.pack_rows(want)


@pytest.mark.parametrize(
    "column, error",
    [
        ([1.5], "int64 needs integers"),
        (np.array([1.0]), "int64 needs integers"),
        ([2**63], "int64 range"),
        (np.array([2**63], dtype=np.uint64), "int64 range"),
        ([-(2**63) - 1], "int64 range"),
        (["3"], "int64 needs integers"),
    ],
)
def test_pack_columns_refuses_what_tick_refuses(native, column, error: str) -> None:
    _, mon = native
    cols: list = [[False], [False], [False], column, [0], [0.0], [0.0]]
    with pytest.raises(TypeError, match=error):
        mon.pack_columns(cols)
    with pytest.raises(TypeError):
        mon.tick([c[0] for c in cols])  # the same value refused one by one
    with pytest.raises(TypeError, match="double needs numbers"):
        mon.pack_columns([[False], [False], [False], [0], [0], ["x"], [0.0]])


def test_malformed_batches_are_refused(native) -> None:
    _, mon = native
    with pytest.raises(ValueError, match="whole number"):
        mon.tick_batch(b"\0" * (mon.row_size + 1))
    with pytest.raises(TypeError, match="dtype"):
        mon.tick_batch(np.zeros(3, dtype=np.float64))
    with pytest.raises(ValueError, match="columns"):
        mon.pack_columns([[0]])
    with pytest.raises(ValueError, match="expected a sequence of 2"):
        mon.pack_columns([[False, True], [False], *([[0]] * 5)])


def test_strided_rows_are_made_contiguous(native) -> None:
    spec, mon = native
    trace = make_trace(5, 80)
    rows = mon.pack_columns(columns(trace))
    mon.reset()
    got = mon.tick_batch(rows[::2])  # a view with twice the stride
    check(got, interpreted(spec, trace[::2]), "every other row")


def test_layout_covers_the_row_size(tmp_path: Path) -> None:
    spec = c99_spec([parse_formula("H b0")])
    assert ";row=35;" in layout(spec)  # 3 bools, 2 int64, 2 doubles, no padding
    mon = compile_spec(spec, tmp_path / "a")
    other = MonitorSpec("test", (*INPUTS[:6], VarDecl("d1", "int64")), spec.requirements)
    with pytest.raises(UserError, match="does not match the spec"):
        load_monitor(mon.path, other)  # same names, another packing


def test_shim_parameters_cannot_be_shadowed_by_input_names(tmp_path: Path) -> None:
    # inputs named like the shim's C parameters and locals of a plain C host
    names = ("in", "n", "flags", "rows", "i", "found")
    spec = MonitorSpec(
        "shadow",
        tuple(VarDecl(x, "int64" if x == "n" else "bool") for x in names),
        (RequirementSpec("R", parse_formula("! (in & rows) | (n > 2)")),),
    )
    assert "ss_in" in host_source(spec, reset=True, reset_each=True)
    mon = compile_spec(spec, tmp_path)
    cols = [
        [True, True, False],
        [0, 3, 0],
        *([[False] * 3] * 1),
        [True, True, True],
        *([[False] * 3] * 2),
    ]
    got = mon.tick_batch(mon.pack_columns(cols))
    assert got.flags[:, 0].tolist() == [1, 0, 0]
    assert mon.tick([True, 0, False, True, False, False]) == b"\x01"


def test_a_monitor_without_inputs_takes_an_array(tmp_path: Path) -> None:
    spec = MonitorSpec("none", (), (RequirementSpec("R", parse_formula("Y true")),))
    mon = compile_spec(spec, tmp_path)
    got = mon.tick_batch(np.zeros(3, dtype=mon.row_dtype))
    assert got.flags.tolist() == [[1], [0], [0]] and got.violating.tolist() == [0]
    with pytest.raises(ValueError, match="without inputs"):
        mon.tick_batch(b"")


def test_a_library_without_reset_functions_batches_too(tmp_path: Path) -> None:
    # what a Copilot library looks like to build/load: the same shim, no resets
    spec = c99_spec([parse_formula("Y b0"), parse_formula("H b0")])
    c_path, _ = write_c(spec, tmp_path / "src")
    lib = build_library(spec, [c_path], tmp_path / "src", tmp_path, reset=False, reset_each=False)
    mon = load_monitor(lib, spec)
    trace = make_trace(9, 50)
    check(mon.tick_batch(mon.pack_columns(columns(trace))), interpreted(spec, trace), "no resets")
    mon.reset()  # a fresh copy of the library
    check(mon.tick_batch(mon.pack_rows(values(trace))), interpreted(spec, trace), "fresh copy")


def test_throughput_functions_return_rates(tmp_path: Path) -> None:
    spec = c99_spec([parse_formula("H (b0 -> (O[0,3] b1))")])
    rates = spec_rates(spec, (100,), out_dir=tmp_path, min_seconds=0.01)
    assert set(rates) == {"tick", "batch 100", "pack 100"} and min(rates.values()) > 0
    assert batch_rate(compile_spec(spec, tmp_path), 10, min_seconds=0.01) > 0


# ------------------------------------------------------------------ random formulas


@pytest.mark.slow
@settings(
    max_examples=30,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(
    formulas=st.lists(c99_formula(4), min_size=5, max_size=12),
    seed=st.integers(0, 2**32),
    n=st.integers(1, 300),
    cut=st.floats(0, 1),
)
def test_random_formulas_batch_as_they_tick(tmp_path_factory, formulas, seed, n, cut) -> None:
    spec = c99_spec([*formulas, WITHIN])
    mon = compile_spec(spec, tmp_path_factory.mktemp("mon"))
    trace = make_trace(seed, n)
    want = interpreted(spec, trace)
    check(mon.tick_batch(mon.pack_columns(columns(trace))), want, "one batch")
    mon.reset()
    assert np.array_equal(one_by_one(mon, trace), want)
    k = int(cut * n)
    mon.reset()
    first = mon.tick_batch(mon.pack_rows(values(trace[:k])))
    second = mon.tick_batch(mon.pack_rows(values(trace[k:])))
    check(first, want[:k], "first half")
    check(second, want[k:], "second half")


# ------------------------------------------------------------------ Copilot


@pytest.mark.ghc
def test_copilot_monitor_batches_as_it_ticks(tmp_path: Path) -> None:
    from monitors.backends.copilot import build_copilot_monitor, require_copilot

    try:
        require_copilot()
    except UserError as e:
        if os.environ.get("SAFETY_SUPERVISOR_REQUIRE_COPILOT") == "1":
            pytest.fail(f"SAFETY_SUPERVISOR_REQUIRE_COPILOT=1 but Copilot is unusable: {e}")
        pytest.skip(f"NASA Copilot is not installed ({e})")
    spec = copilot_spec(batch_formulas(seed=5, n=10), prefix="cb")
    mon = build_copilot_monitor(spec, tmp_path)
    assert not mon.has_reset
    for seed in range(3):
        trace = make_trace(seed, 250)
        want = interpreted(spec, trace)
        mon.reset()  # a fresh copy: the batch entry point is bound again
        check(mon.tick_batch(mon.pack_columns(columns(trace[:100]))), want[:100], "copilot")
        rest = mon.tick_batch(mon.pack_rows(values(trace[100:])))
        check(rest, want[100:], "copilot, second batch")
        mon.reset()
        assert np.array_equal(one_by_one(mon, trace), want)


def test_tick_until_stops_after_the_first_violating_row(tmp_path):
    """tick_until: the rows up to the first violation, state exactly after it."""
    import numpy as np

    from monitors.backends.load import compile_spec
    from monitors.ir.formula import parse_formula
    from monitors.ir.spec import MonitorSpec, RequirementSpec, VarDecl

    spec = MonitorSpec(
        "c",
        (VarDecl("x", "int64"),),
        (RequirementSpec("small", parse_formula("H (x < 5)")),
         RequirementSpec("up", parse_formula("x >= preInt(0, x)"))),
    )  # fmt: skip
    a, b = compile_spec(spec, tmp_path / "a"), compile_spec(spec, tmp_path / "b")
    xs = [1, 2, 3, 2, 4, 9, 1]
    rows = a.pack_columns([np.array(xs, dtype=np.int64)])
    n, flags = a.tick_until(rows)
    assert (n, flags) == (4, bytes([0, 1]))  # 3 -> 2 breaks 'up' at the 4th row
    n2, flags2 = a.tick_until(rows[n:])
    assert (n2, flags2) == (2, bytes([1, 0]))  # 9 breaks 'small' ('up' holds: 4 -> 9)
    n3, flags3 = a.tick_until(rows[n + n2 :])
    assert (n3, flags3) == (1, bytes([1, 1]))  # H stays broken, 9 -> 1 breaks 'up'
    # the same as one tick at a time
    assert [b.tick([x]) for x in xs][3] == bytes([0, 1])
    assert a.tick_until(rows[:0]) == (0, bytes([0, 0]))
