"""The z3 planner of an injection: a short trace over the topic variables whose
last tick violates REQ while every other requirement, assumptions and variable
ranges included, holds at every tick, posed (with the analyses' encoder,
:mod:`monitors.verify.bmc`, the monitor's semantics) over the states the
supervisor will step on.  When that is impossible, a MaxSAT objective keeps as
many of the others as possible and the ones that must break are named.  The
interpreter re-checks the result (:mod:`supervisor.tools.inject.recheck`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import z3

from monitors.ir.formula import max_bound
from monitors.verify.bmc import Encoder, fp_const, fresh_rows, model_trace, z3_value
from monitors.verify.interpret import Value
from supervisor.pipeline import Project
from supervisor.tools.inject.errors import InjectError, Unviolable
from supervisor.tools.inject.fields import INT_FIELD_RANGE
from supervisor.tools.inject.injection import Injection
from supervisor.tools.inject.recheck import explain, recheck
from supervisor.tools.inject.target import WARMUP, Target, lookback

PLAUSIBLE = 1000  # unranged ints prefer |v| <= this (a readable value, not 2^63 - 1)


class Planner(Target):
    """Computes injections for one loaded project (z3 through ``monitors.verify.bmc``)."""

    def __init__(self, project: Project, *, warmup: int = WARMUP) -> None:
        super().__init__(project, warmup=warmup)
        self._nominal: dict[str, Value] | None = None
        self._nominal_done = False

    # -------------------------------------------------------------- z3 building blocks

    def _quiet(self, name: str) -> Value:
        """A readable default: the configured initial value, else 0 (false) moved into
        the range."""
        v = self.cfg.variables[name]
        t = self.types[name]
        if v.initial is not None:
            return bool(v.initial) if t == "bool" else v.initial
        if t == "bool":
            return False
        lo, hi = v.range if v.range is not None else (0, 0)
        x = min(max(0, lo), hi) if v.range is not None else 0
        return int(math.ceil(x)) if t == "int64" else float(x)

    def _domain(self, row: Mapping[str, Any]) -> list:
        """What the message fields can carry (hard: anything else cannot be published)."""
        out = []
        for n, leaf in self.domains.items():
            x, t = row[n], self.types[n]
            if leaf in INT_FIELD_RANGE:
                lo, hi = INT_FIELD_RANGE[leaf]
                if t == "int64":
                    out += [x >= lo, x <= hi]
                elif t == "double":  # an integer field feeding a double variable
                    out += [
                        z3.fpEQ(z3.fpRoundToIntegral(z3.RTZ(), x), x),
                        z3.fpGEQ(x, fp_const(float(lo))),
                        z3.fpLEQ(x, fp_const(float(hi))),
                    ]
            elif leaf in ("float", "float32") and t == "double":
                narrow = z3.fpToFP(z3.RNE(), x, z3.Float32())
                out.append(z3.Or(z3.fpIsNaN(x), z3.fpToFP(z3.RNE(), narrow, z3.Float64()) == x))
        return out

    def _plausible(self, row: Mapping[str, Any]) -> list:
        """Soft: values near their range (or small): an out-of-range value that must be
        injected reads as 3, not 4611686018427387904."""
        out = []
        for n in self.inputs:
            t, x = self.types[n], row[n]
            if t == "bool":
                continue
            v = self.cfg.variables[n]
            lo, hi = (v.range[0] - 1, v.range[1] + 1) if v.range else (-PLAUSIBLE, PLAUSIBLE)
            if t == "int64":
                out.append(z3.And(x >= math.ceil(lo), x <= math.floor(hi)))
            else:
                out.append(
                    z3.And(z3.fpGEQ(x, fp_const(float(lo))), z3.fpLEQ(x, fp_const(float(hi))))
                )
        return out

    # -------------------------------------------------------------- nominal state

    def nominal(self) -> dict[str, Value] | None:
        """A quiet state that satisfies every requirement and range however long it is
        held (None when the requirements cannot all hold)."""
        if self._nominal_done:
            return self._nominal
        self._nominal_done = True
        row = fresh_rows(self.types, self.inputs, 1, "nominal")[0]
        enc = Encoder(self.types, [row] * self.saturation)
        opt = z3.Optimize()
        opt.set(timeout=20_000)
        opt.add(self._domain(row))
        for r in self.reqs.values():
            opt.add(z3.And(enc.holds(r.formula)))
        for f in self.ranges.values():
            opt.add(enc.holds(f)[0])
        for n in self.inputs:
            opt.add_soft(row[n] == z3_value(self.types[n], self._quiet(n)), id="quiet")
        if opt.check() != z3.sat:
            return None
        self._nominal = model_trace(opt.model(), [row], self.types)[0]
        return self._nominal

    # -------------------------------------------------------------- one injection

    def plan(self, rid: str) -> Injection:
        if rid in self.unsupported:
            raise InjectError(f"{rid} cannot be injected: {self.unsupported[rid]}")
        if rid not in self.reqs:
            known = ", ".join(r.id for r in self.cfg.requirements)
            raise InjectError(f"no requirement '{rid}' (requirements: {known})")
        req = self.reqs[rid]
        k = max(2, max_bound(req.formula) + 2)
        inj = self._solve(rid, k)
        if inj is None and lookback(req.formula) + 2 > k:
            k = lookback(req.formula) + 2  # nested bounds can need a longer lead-in
            inj = self._solve(rid, k)
        if inj is None:
            raise Unviolable(
                f"{rid} cannot be violated: no trace of {k} ticks with values the message "
                f"fields can carry makes `{req.formula}` false (see `check` for redundancy)"
            )
        return inj

    def _solve(self, rid: str, k: int) -> Injection | None:
        rows = fresh_rows(self.types, self.inputs, k, f"{rid}.")
        tail = self.saturation
        others = [o for o in self.reqs if o != rid]
        opt = z3.Optimize()
        opt.set(timeout=30_000)
        for row in rows:
            opt.add(self._domain(row))
        early: list = []
        keep: dict[str, list] = {o: [] for o in others}
        for warm in self.variants():
            states, labels = self.observed(rows, warm, tail)
            first, last = self.span(labels, k - 1)
            enc = Encoder(self.types, states)
            mine = enc.holds(self.reqs[rid].formula)
            opt.add(z3.Not(mine[last]))  # hard: the injected tick violates REQ
            early += mine[:first]  # REQ holds until its last tick
            for o in others:
                keep[o] += enc.holds(self.reqs[o].formula)
        # after a reset (reset: after_mitigation) REQ is judged afresh on the nominal state
        fresh = Encoder(self.types, [rows[0]] * tail).holds(self.reqs[rid].formula)
        # soft goals, most important first (z3 optimises them lexicographically)
        opt.add_soft(z3.And(early + fresh), id="1-early")
        for o in others:
            opt.add_soft(z3.And(keep[o]), id="2-others")
        ranges = {n: Encoder(self.types, rows).holds(f) for n, f in self.ranges.items()}
        for xs in ranges.values():
            opt.add_soft(z3.And(xs), id="3-ranges")
        nominal = self.nominal()
        if nominal is not None:
            for n in self.inputs:
                opt.add_soft(rows[0][n] == z3_value(self.types[n], nominal[n]), id="4-nominal")
        for t in range(1, k):
            for n in self.inputs:
                opt.add_soft(rows[t][n] == rows[t - 1][n], id="5-steady")
        for row in rows:
            for c in self._plausible(row):
                opt.add_soft(c, id="6-plausible")
        result = opt.check()
        if result == z3.unsat:
            return None
        if result != z3.sat:
            raise InjectError(f"z3 gave up computing a trace for {rid} ({opt.reason_unknown()})")
        model = opt.model()
        trace = model_trace(model, rows, self.types)

        def true(x: Any) -> bool:
            return z3.is_true(model.eval(x, model_completion=True))

        inj = Injection(
            req=rid,
            text=self.reqs[rid].text,
            k=k,
            trace=trace,
            broken=[o for o in others if not true(z3.And(keep[o]))],
            broken_ranges=[n for n, xs in ranges.items() if not true(z3.And(xs))],
            early=true(z3.And(early + fresh)),
            tick_violations=[],
            expected=[],
        )
        inj.expected = [rid, *inj.broken]
        recheck(self, inj)
        explain(self, inj, self.nominal() is not None)
        return inj
