"""z3 solvers within the analyses' memory limit, and how z3 says it reached it.

z3 grows without bound on some queries (gigabytes within the time budget on a few
generated requirements, docs/BENCHMARKS.md "Scaling"); its ``max_memory`` solver
parameter makes it give up with an exception instead (docs/reference/faults.md).
"""

from __future__ import annotations

import z3


def is_memout(e: z3.Z3Exception) -> bool:
    """z3's own report of its ``max_memory`` limit (a solver parameter, in MB)."""
    return "memory" in str(e.value if hasattr(e, "value") else e)


def solver(memory_mb: int | None) -> z3.Solver:
    """A solver that gives up, raising z3.Z3Exception, once z3 as a whole holds more
    than ``memory_mb`` MB (None: no limit)."""
    s = z3.Solver()
    if memory_mb is not None:
        s.set("max_memory", memory_mb)
    return s


def steps_taken(s: z3.Solver) -> int:
    """z3's resource count so far (its own steps, counted for every solver of the
    context together): the difference around a call is what that call took."""
    st = s.statistics()
    for key in st.keys():
        if key == "rlimit count":
            return int(st.get_key_value(key))
    return 0
