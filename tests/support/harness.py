"""Shared by the backend tests: the input set, random traces with edge values,
the interpreter's expected flags and a compiled monitor's actual flags."""

from __future__ import annotations

import math
import random

from monitors.ir.spec import MonitorSpec, VarDecl
from monitors.verify.interpret import verdicts

I64_MIN, I64_MAX = -(1 << 63), (1 << 63) - 1
BOOLS, INTS, REALS = ("b0", "b1", "b2"), ("i0", "i1"), ("d0", "d1")
INPUTS = (
    *(VarDecl(n, "bool") for n in BOOLS),
    *(VarDecl(n, "int64") for n in INTS),
    *(VarDecl(n, "double") for n in REALS),
)


INT_EDGES = [
    I64_MIN,
    I64_MIN + 1,
    I64_MAX,
    I64_MAX - 1,
    0,
    1,
    -1,
    2,
    2**53 + 1,
    -(2**53) - 1,
    2**32,
]
REAL_EDGES = [
    math.nan,
    math.inf,
    -math.inf,
    0.0,
    -0.0,
    1.0,
    -1.0,
    2.0**53,
    2.0**63,
    -(2.0**63),
    9.2e18,
    1e308,
    -1e308,
    5e-324,
    float(2**53 + 2),
    4294967296.0,
]


def make_trace(seed: int, n: int) -> list[dict[str, bool | int | float]]:
    rnd = random.Random(seed)
    p_true = {b: rnd.choice([0.1, 0.5, 0.9]) for b in BOOLS}

    def int_value() -> int:
        r = rnd.random()
        if r < 0.6:
            return rnd.randint(-8, 8)
        if r < 0.85:
            return rnd.choice(INT_EDGES)
        return rnd.randint(I64_MIN, I64_MAX)

    def real_value() -> float:
        r = rnd.random()
        if r < 0.5:
            return rnd.randint(-16, 16) / 2
        if r < 0.75:
            return rnd.choice(REAL_EDGES)
        return rnd.uniform(-1e19, 1e19) if r < 0.9 else float(int_value())

    rows = []
    for _ in range(n):
        row: dict[str, bool | int | float] = {b: rnd.random() < p_true[b] for b in BOOLS}
        row.update({i: int_value() for i in INTS})
        row.update({d: real_value() for d in REALS})
        rows.append(row)
    return rows


def oracle(spec: MonitorSpec, trace: list[dict]) -> list[list[bool]]:
    """Expected violation flags per requirement."""
    return [[not v for v in verdicts(spec.expanded(r), trace)] for r in spec.requirements]


def run(mon: object, spec: MonitorSpec, trace: list[dict]) -> list[list[bool]]:
    """Flags per requirement per tick from the compiled monitor."""
    names = [v.name for v in spec.inputs]
    ticks = [mon.tick([row[n] for n in names]) for row in trace]
    return [[bool(t[i]) for t in ticks] for i in range(len(spec.requirements))]
