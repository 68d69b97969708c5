"""The solver context every analysis shares: one k-tick unrolling of the
requirements, indicator literals, minimal unsatisfiable cores, and re-checking
of z3's traces with the reference interpreter."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence

import z3

from monitors.ir.formula import Formula, variables
from monitors.verify.analysis.requirements import DEFAULT_RLIMIT, Req, VarInfo, range_formula
from monitors.verify.analysis.results import Limit, Trace
from monitors.verify.analysis.solvers import solver, steps_taken
from monitors.verify.bmc import (
    Encoder,
    OutOfTime,
    Row,
    Unsupported,
    check_deadline,
    encoding_cells,
    fresh_rows,
    model_trace,
)
from monitors.verify.interpret import verdicts


class TooLarge(Exception):
    """Unrolling the set would take most of the time budget (measured on its start)."""


# Unrolling may take at most this share of what is left of the budget: the solver
# calls of the analyses need the rest.
ENCODE_SHARE = 0.5
PROJECT_AFTER_S = 0.5  # measure this long before projecting the whole unrolling


class _Projection:
    """The unrolling's time, projected from the rate of its first requirements on
    this machine, so that a set too large for the budget is given up at once
    instead of when the budget has run out (docs/reference/faults.md)."""

    def __init__(self, reqs: Sequence[Req], k: int, deadline: float | None) -> None:
        self.deadline = deadline
        self.cells = [encoding_cells([r.formula, r.activation], k) for r in reqs]
        self.total = sum(self.cells)
        self.done = 0
        self.i = 0
        self.t0 = time.monotonic()

    def next(self, r: Req) -> None:
        if self.deadline is not None and self.i:
            elapsed = time.monotonic() - self.t0
            if elapsed >= PROJECT_AFTER_S and self.done:
                rest = (self.total - self.done) * elapsed / self.done
                left = self.deadline - time.monotonic()
                if rest > ENCODE_SHARE * left:
                    raise TooLarge(
                        f"unrolling all {len(self.cells)} requirements would take about "
                        f"{elapsed + rest:.0f} s here (measured on the first {self.i}), "
                        f"more than half of the {left + elapsed:.0f} s left of the budget"
                    )
        if self.i < len(self.cells):
            self.done += self.cells[self.i]
        self.i += 1


class Context:
    """One k-tick unrolling of every requirement, shared by all the analyses; each
    requirement and each range is switched on by an indicator literal, so one
    incremental solver answers every query (and names its unsat cores)."""

    def __init__(
        self,
        reqs: Sequence[Req],
        vars_: dict[str, VarInfo],
        k: int,
        timeout_s: float,
        deadline: float | None = None,
        memory_mb: int | None = None,
        rlimit: int = DEFAULT_RLIMIT,
    ) -> None:
        self.k = k
        self.memory_mb = memory_mb
        self.rlimit = rlimit  # z3 resource units per solver call
        self.per_call_ms = int(timeout_s * 1000)  # the wall-clock cap per solver call
        # which limit stopped the last solver call that gave up (None: neither)
        self.stopped_by: Limit | None = None
        self.last_steps = 0  # z3's resource units the last call took
        self.last_cap_ms = self.per_call_ms  # its wall-clock cap
        self.max_steps = 0  # the most any one call took (bench: choosing analysis.rlimit)
        self.deadline = deadline  # time.monotonic() when the analyses' budget runs out
        self.vars = vars_
        self.types = {v.name: v.type for v in vars_.values()}
        names = list(dict.fromkeys(n for r in reqs for n in variables(r.formula)))
        names += [n for n in vars_ if n not in names]
        self.names = names
        self.rows: list[Row] = fresh_rows(self.types, names, k, deadline=deadline)
        self.enc = Encoder(self.types, self.rows, deadline)
        self.reqs: dict[str, Req] = {}
        self.holds: dict[str, list[z3.BoolRef]] = {}
        self.unsupported: dict[str, str] = {}
        projection = _Projection(reqs, k, deadline)
        for r in reqs:
            projection.next(r)
            try:
                self.holds[r.id] = self.enc.holds(r.formula)
                self.enc.holds(r.activation)  # fails here, not mid-analysis, if unsupported
                self.reqs[r.id] = r
            except Unsupported as e:
                self.unsupported[r.id] = str(e)
        self.ranges: dict[str, Formula] = {}
        for v in vars_.values():
            rf = range_formula(v)
            if rf is not None and v.name in names:
                self.ranges[v.name] = rf
        self.solver = self.new_solver()
        self._lits: dict[tuple, z3.BoolRef] = {}

    def new_solver(self) -> z3.Solver:
        """A solver within the analyses' memory limit (every solver starts here)."""
        return solver(self.memory_mb)

    @property
    def timeout_ms(self) -> int:
        """The next solver call's timeout: ``timeout_s``, cut to what is left of the
        budget; OutOfTime once nothing is left (every solver call starts here)."""
        if self.deadline is None:
            return self.per_call_ms
        check_deadline(self.deadline)
        left = int((self.deadline - time.monotonic()) * 1000)
        return max(1, min(self.per_call_ms, left))

    def run(
        self,
        s: z3.Solver,
        assumptions: Sequence[z3.BoolRef] = (),
        rlimit: int | None = None,
        cap_ms: int | None = None,
    ) -> z3.CheckSatResult:
        """``s.check(*assumptions)`` within z3's resource limit (``rlimit``, default
        the context's) and, as a safety net, the wall-clock cap (at most ``cap_ms``);
        when z3 gives up, ``stopped_by`` says which limit stopped it, and
        ``last_steps`` is what the call took (every solver call starts here)."""
        units = max(1, self.rlimit if rlimit is None else rlimit)
        timeout = self.timeout_ms if cap_ms is None else max(1, min(cap_ms, self.timeout_ms))
        s.set(rlimit=units, timeout=timeout)
        before = steps_taken(s)
        r = s.check(*assumptions)
        self.last_steps = steps_taken(s) - before
        self.max_steps = max(self.max_steps, self.last_steps)
        self.last_cap_ms = timeout
        if r == z3.unknown:
            # z3 words both limits alike ("canceled"): the count of steps tells them apart
            why = s.reason_unknown()
            self.stopped_by = (
                Limit.SOLVER_RLIMIT
                if self.last_steps >= units or "resource limit" in why
                else Limit.SOLVER_TIMEOUT
                if "timeout" in why or "canceled" in why
                else None
            )
        return r

    def stop_text(self) -> str:
        """What stopped the last solver call that gave up, for a finding's message."""
        if self.stopped_by is Limit.SOLVER_RLIMIT:
            return f"z3 gave up: resource limit {self.rlimit}"
        if self.stopped_by is Limit.SOLVER_TIMEOUT:
            return f"z3 gave up: wall-clock cap {self.per_call_ms / 1000:g} s"
        return "z3 gave up (its methods are incomplete here)"

    # -------------------------------------------------------------- building blocks

    def at(self, f: Formula) -> list[z3.BoolRef]:
        return self.enc.holds(f)

    def ok(self, rid: str, n: int) -> z3.BoolRef:
        """Requirement ``rid`` is satisfied by the first ``n`` ticks."""
        xs = self.holds[rid]
        if self.reqs[rid].monotone:
            return z3.And(xs[:n]) if n > 1 else xs[0]
        return xs[n - 1]

    def in_range(self, name: str, n: int) -> z3.BoolRef:
        xs = self.at(self.ranges[name])
        return z3.And(xs[:n]) if n > 1 else xs[0]

    def lit(self, key: tuple, build: Callable[[], z3.BoolRef]) -> z3.BoolRef:
        """An indicator literal b with b -> build() asserted once."""
        if key not in self._lits:
            b = z3.Bool("|" + ":".join(map(str, key)) + "|")
            self.solver.add(z3.Implies(b, build()))
            self._lits[key] = b
        return self._lits[key]

    def fresh_lit(self, tag: str, build: Callable[[], z3.BoolRef]) -> z3.BoolRef:
        """A new indicator literal at every call (``lit`` reuses one per key)."""
        return self.lit((tag, len(self._lits)), build)

    def ok_lit(self, item: str, n: int) -> z3.BoolRef:
        """'item' is a requirement id or 'range:NAME'."""
        if item.startswith("range:"):
            name = item[6:]
            return self.lit(("range", name, n), lambda: self.in_range(name, n))
        return self.lit(("ok", item, n), lambda: self.ok(item, n))

    def viol_lit(self, rid: str, n: int) -> z3.BoolRef:
        return self.lit(("viol", rid, n), lambda: z3.Not(self.ok(rid, n)))

    def fired_lit(self, rid: str, n: int) -> z3.BoolRef:
        xs = self.at(self.reqs[rid].activation)
        return self.lit(("fired", rid, n), lambda: z3.Or(xs[:n]) if n > 1 else xs[0])

    def check(self, lits: Sequence[z3.BoolRef], rlimit: int | None = None) -> z3.CheckSatResult:
        """z3's answer; OutOfTime when z3 gave up because the budget ran out (its own
        timer may stop it a little before the deadline), so the analysis is reported
        as stopped by the budget rather than as undecided."""
        r = self.run(self.solver, lits, rlimit)
        if r == z3.unknown and self.stopped_by is Limit.SOLVER_TIMEOUT:
            if self.deadline is not None and self.last_cap_ms < self.per_call_ms:
                raise OutOfTime()
        return r

    def minimal_core(
        self, items: Sequence[str], n: int, fixed: Sequence[z3.BoolRef] = ()
    ) -> list[str] | None:
        """A minimal subset of ``items`` that is unsatisfiable on ``n`` ticks together
        with ``fixed`` (z3's core, then deletion), or None if they are satisfiable."""
        lits = {item: self.ok_lit(item, n) for item in items}
        if self.check([*fixed, *lits.values()]) != z3.unsat:
            return None
        core_names = {str(c) for c in self.solver.unsat_core()}
        core = [i for i in items if str(lits[i]) in core_names]
        for item in list(core):
            trial = [i for i in core if i != item]
            if self.check([*fixed, *(lits[i] for i in trial)]) == z3.unsat:
                names = {str(c) for c in self.solver.unsat_core()}
                core = [i for i in trial if str(lits[i]) in names]
        return core

    def late_violation(self, lits: list[z3.BoolRef], victim: str, n: int) -> z3.ModelRef | None:
        """A model of ``lits`` (which violate ``victim`` on n ticks) where the victim
        holds as long as possible: the trace then shows where the conflict bites."""
        if self.check(lits) != z3.sat:
            return None
        model = self.solver.model()
        if self.reqs[victim].monotone:
            for m in range(n - 1, 0, -1):
                if self.check([*lits, self.ok_lit(victim, m)]) == z3.sat:
                    return self.solver.model()
        return model

    def model_trace(self, model: z3.ModelRef, n: int) -> Trace:
        return model_trace(model, self.rows[:n], self.types)

    # -------------------------------------------------------------- re-checking

    def recheck(self, trace: Trace, ids: Iterable[str]) -> dict[str, list[bool]]:
        """The interpreter's verdicts per tick for ``ids`` on ``trace``."""
        return {rid: verdicts(self.reqs[rid].formula, trace) for rid in ids}

    def satisfied(self, rid: str, v: list[bool]) -> bool:
        return all(v) if self.reqs[rid].monotone else v[-1]

    def range_ok(self, name: str, trace: Trace) -> bool:
        return all(verdicts(self.ranges[name], trace))

    def assert_agrees(self, trace: Trace, sat: Iterable[str], viol: Iterable[str] = ()) -> None:
        """z3 said items in ``sat`` hold and those in ``viol`` do not: the interpreter
        must say the same."""
        for item in sat:
            if item.startswith("range:"):
                assert self.range_ok(item[6:], trace), f"z3/interpreter disagree on {item}"
            else:
                v = verdicts(self.reqs[item].formula, trace)
                assert self.satisfied(item, v), f"z3/interpreter disagree: {item} {v} {trace}"
        for item in viol:
            v = verdicts(self.reqs[item].formula, trace)
            assert not self.satisfied(item, v), f"z3/interpreter disagree: {item} {v} {trace}"

    def columns(self, trace: Trace, ids: Iterable[str]) -> Trace:
        """Only the variables the given requirements read (readable tables)."""
        keep: list[str] = []
        for rid in ids:
            if rid.startswith("range:"):
                keep.append(rid[6:])
            elif rid in self.reqs:
                keep.extend(variables(self.reqs[rid].formula))
        keep = [n for n in self.names if n in set(keep)] or list(self.names)
        return [{n: row[n] for n in keep} for row in trace]

    # -------------------------------------------------------------- items

    def all_items(self, exclude: Iterable[str] = ()) -> list[str]:
        """Every requirement and 'range:NAME' item, but those in ``exclude``."""
        ex = set(exclude)
        return [r for r in self.reqs if r not in ex] + [
            f"range:{n}" for n in self.ranges if f"range:{n}" not in ex
        ]

    def assumption_items(self) -> list[str]:
        """The assumptions and every range: what the environment is held to."""
        return [r for r, q in self.reqs.items() if q.assumption] + [
            f"range:{n}" for n in self.ranges
        ]
