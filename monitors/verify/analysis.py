"""Formal analysis of a requirement set by bounded model checking with z3.

For safety engineers, before a monitor is deployed: can all requirements hold
together (consistency), which smallest set cannot (conflicts), can a controller
meet the guarantees whatever the sensed inputs do (realizability), which
requirement can never be triggered (vacuity) or is implied by the others
(redundancy), and which are non-monotone.

Semantics (the same as the monitor's, through ``monitors.verify.bmc``): a trace of
``k`` ticks satisfies a monotone requirement when its formula holds at every
tick, and a non-monotone one (a pending obligation) when it holds at the last
tick.  Variable ranges are constraints too: on inputs they are assumptions, on
outputs they limit what the controller may choose.

Realizability is a game: the environment picks inputs allowed by the
assumptions and input ranges, the controller picks outputs, and at each tick t,
if the assumptions held up to t, the guarantees must hold at t.

- When every requirement is a pure invariant (``H p``, p without temporal
  operators) the game has no memory: "for every allowed input at one tick there
  are outputs" is checked once and proves realizability for all time.
- Otherwise it is bounded to k ticks.  "Causal" means the outputs at tick t may
  depend on inputs up to t only (forall i0 exists o0 forall i1 exists o1 ...);
  that is what a controller can do and what is reported as realizable.  The
  weaker "clairvoyant" check (for every whole input sequence there are outputs,
  which may depend on future inputs) is what finds a concrete defeating input
  sequence; when only it could be decided, the report says so.  Requirements
  that share no variable are solved as separate games, and comparisons over
  numbers are abstracted into Booleans when none mixes inputs with outputs
  (exact, see _abstract_arena).

Every trace reported in a finding is re-evaluated with the reference
interpreter (``monitors.verify.interpret``) and must agree with what z3 claimed; a
disagreement raises ``AssertionError`` (an encoding bug, never hidden).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import z3

from monitors.frontend.parse import Requirement
from monitors.ir.formula import (
    REL_OPS,
    TRUE,
    BinOp,
    Const,
    Formula,
    O,
    Var,
    Y,
    and_,
    map_children,
    max_bound,
    not_,
    variables,
)
from monitors.ir.formula import H as H_
from monitors.verify.bmc import (
    Encoder,
    Row,
    Unsupported,
    fp_const,
    fresh_row,
    fresh_rows,
    model_trace,
    pure_invariant,
    tick_encoding,
)
from monitors.verify.interpret import Value, verdicts

Trace = list[dict[str, Value]]
SEVERITIES = ("error", "warning", "info")
DEFAULT_TIMEOUT_S = 10.0


# ------------------------------------------------------------------ inputs


@dataclass(frozen=True)
class VarInfo:
    name: str
    type: str  # bool | int64 | double
    role: str = "input"  # input | output
    range: tuple[float, float] | None = None


@dataclass(frozen=True)
class Req:
    """One requirement to analyse; its formula is over declared variables only
    (defines already expanded)."""

    id: str
    formula: Formula
    assumption: bool = False
    monotone: bool = True
    activation: Formula = TRUE  # when its scope and condition hold (vacuity)
    note: str | None = None  # the formalizer's non-monotone explanation
    text: str = ""


def activation(req: Requirement) -> Formula:
    """When ``req`` can be triggered: its scope is active and its condition holds.

    A requirement whose activation never holds constrains nothing (vacuous).
    Scopes (FRET's intervals): ``in M`` while M; ``not in M``/``only in M``
    (the constrained part is outside M) while !M; ``after M`` once M has first
    ended; ``before M`` until M first holds; ``only after M`` until M first ends
    (always from tick 0); ``only before M`` once M has held."""
    act: Formula = TRUE
    if req.scope is not None:
        m = req.scope.mode
        left_m = and_(not_(m), Y(m))
        act = {
            "in": lambda: m,
            "notin": lambda: not_(m),
            "onlyIn": lambda: not_(m),
            "after": lambda: O(left_m),
            "before": lambda: H_(not_(m)),
            "onlyAfter": lambda: H_(not_(left_m)),
            "onlyBefore": lambda: O(m),
        }[req.scope.kind]()
    if req.condition is not None:
        act = and_(act, req.condition.expr)
    return act


# ------------------------------------------------------------------ results


@dataclass
class Finding:
    kind: str  # conflict | unrealizable | realizability | vacuous | unreachable | redundant
    #            | non-monotone | not-analysed | assumption-reads-outputs | no-outputs
    #            | k-too-small
    severity: str  # error | warning | info
    requirements: tuple[str, ...]
    message: str
    fix: str
    trace: Trace | None = None
    trace_note: str = ""
    # the interpreter's verdict per tick for each requirement of the finding on its
    # trace (what the report prints next to the values)
    verdicts: dict[str, list[bool]] = field(default_factory=dict)


@dataclass
class Analysis:
    k: int
    requirements: list[Req]
    variables: dict[str, VarInfo]
    findings: list[Finding]
    consistent: bool | None
    consistency: str
    realizability: str
    seconds: dict[str, float]
    ctx: _Context | None = field(default=None, repr=False)

    @property
    def errors(self) -> list[Finding]:
        return [f for f in self.findings if f.severity == "error"]

    @property
    def warnings(self) -> list[Finding]:
        return [f for f in self.findings if f.severity == "warning"]

    def concerning(self, rid: str) -> list[Finding]:
        return [f for f in self.findings if rid in f.requirements]

    def examples(self, rid: str) -> tuple[Example | None, Example | None]:
        """A shortest trace satisfying ``rid`` (triggered, if it can be) and one
        violating it, both re-checked with the interpreter."""
        if self.ctx is None or rid not in self.ctx.holds:
            return None, None
        return self.ctx.satisfying_example(rid), self.ctx.violating_example(rid)


@dataclass
class Example:
    trace: Trace
    note: str
    verdicts: dict[str, list[bool]]


def default_k(reqs: Iterable[Req]) -> int:
    """The largest time bound plus 2 (a window and the ticks on either side), at least 3."""
    return max([3] + [max_bound(r.formula) + 2 for r in reqs])


# ------------------------------------------------------------------ the solver context


def _range_formula(v: VarInfo) -> Formula | None:
    if v.range is None or v.type == "bool":
        return None
    lo, hi = v.range
    if v.type == "int64":
        c_lo, c_hi = Const(math.ceil(lo)), Const(math.floor(hi))
    else:
        c_lo, c_hi = Const(float(lo)), Const(float(hi))
    return BinOp("&", BinOp(">=", Var(v.name), c_lo), BinOp("<=", Var(v.name), c_hi))


class _Context:
    """One k-tick unrolling of every requirement, shared by all the analyses; each
    requirement and each range is switched on by an indicator literal, so one
    incremental solver answers every query (and names its unsat cores)."""

    def __init__(
        self, reqs: Sequence[Req], vars_: dict[str, VarInfo], k: int, timeout_s: float
    ) -> None:
        self.k = k
        self.timeout_ms = int(timeout_s * 1000)
        self.vars = vars_
        self.types = {v.name: v.type for v in vars_.values()}
        names = list(dict.fromkeys(n for r in reqs for n in variables(r.formula)))
        names += [n for n in vars_ if n not in names]
        self.names = names
        self.rows: list[Row] = fresh_rows(self.types, names, k)
        self.enc = Encoder(self.types, self.rows)
        self.reqs: dict[str, Req] = {}
        self.holds: dict[str, list[z3.BoolRef]] = {}
        self.unsupported: dict[str, str] = {}
        for r in reqs:
            try:
                self.holds[r.id] = self.enc.holds(r.formula)
                self.enc.holds(r.activation)  # fails here, not mid-analysis, if unsupported
                self.reqs[r.id] = r
            except Unsupported as e:
                self.unsupported[r.id] = str(e)
        self.ranges: dict[str, Formula] = {}
        for v in vars_.values():
            rf = _range_formula(v)
            if rf is not None and v.name in names:
                self.ranges[v.name] = rf
        self.solver = z3.Solver()
        self.solver.set(timeout=self.timeout_ms)
        self._lits: dict[tuple, z3.BoolRef] = {}

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

    def check(self, lits: Sequence[z3.BoolRef]) -> z3.CheckSatResult:
        return self.solver.check(*lits)

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

    # -------------------------------------------------------------- examples

    def _all_items(self, exclude: Iterable[str] = ()) -> list[str]:
        ex = set(exclude)
        return [r for r in self.reqs if r not in ex] + [
            f"range:{n}" for n in self.ranges if f"range:{n}" not in ex
        ]

    def _assumption_items(self) -> list[str]:
        return [r for r, q in self.reqs.items() if q.assumption] + [
            f"range:{n}" for n in self.ranges
        ]

    def satisfying_example(self, rid: str) -> Example | None:
        def trig(n: int) -> list[z3.BoolRef]:
            return [self.ok_lit(rid, n), self.fired_lit(rid, n)]

        def plain(n: int) -> list[z3.BoolRef]:
            return [self.ok_lit(rid, n)]

        return (
            self._example_for(rid, trig, [], "it is triggered and satisfied", greedy=False)
            or self._example_for(rid, plain, [], "it is satisfied", greedy=False)
            or self._example_for(rid, trig, [], "it is triggered and satisfied")
            or self._example_for(rid, plain, [], "it is satisfied")
        )

    def violating_example(self, rid: str) -> Example | None:
        return self._example_for(rid, lambda n: [self.viol_lit(rid, n)], [rid], "it is violated")

    def _example_for(
        self,
        rid: str,
        base: Callable[[int], list[z3.BoolRef]],
        viol: list[str],
        what: str,
        greedy: bool = True,
    ) -> Example | None:
        """The shortest trace meeting ``base`` and every other requirement and range;
        if there is none, the shortest meeting ``base``, keeping greedily as many of
        the others as possible (assumptions and ranges first) and naming the rest."""
        others = [i for i in self._assumption_items() + self._all_items() if i != rid]
        others = list(dict.fromkeys(others))
        for n in range(1, self.k + 1):
            if self.check([*base(n), *(self.ok_lit(i, n) for i in others)]) == z3.sat:
                trace = self.model_trace(self.solver.model(), n)
                self.assert_agrees(trace, others, viol)
                note = f"a {n}-tick trace where {what} and every other requirement holds"
                return self._example(trace, [rid], note)
        for n in range(1, self.k + 1 if greedy else 1):
            if self.check(base(n)) != z3.sat:
                continue
            kept: list[str] = []
            for i in others:
                if self.check([*base(n), *(self.ok_lit(j, n) for j in [*kept, i])]) == z3.sat:
                    kept.append(i)
            assert self.check([*base(n), *(self.ok_lit(j, n) for j in kept)]) == z3.sat
            trace = self.model_trace(self.solver.model(), n)
            self.assert_agrees(trace, kept, viol)
            broken = [i for i in others if i not in kept]
            note = f"a {n}-tick trace where {what}; only possible by also breaking {_names(broken)}"
            return self._example(trace, [rid, *(b for b in broken if b in self.reqs)], note)
        return None

    def _example(self, trace: Trace, ids: list[str], note: str) -> Example:
        return Example(self.columns(trace, ids), note, self.recheck(trace, ids))


# ------------------------------------------------------------------ the analyses


def _names(items: Iterable[str]) -> str:
    out = []
    for i in items:
        out.append(f"the range of {i[6:]}" if i.startswith("range:") else i)
    if len(out) <= 1:
        return "".join(out)
    return ", ".join(out[:-1]) + " and " + out[-1]


def _ticks(n: int) -> str:
    return f"{n} tick{'' if n == 1 else 's'}"


def _first_false(v: list[bool]) -> int | None:
    return next((t for t, x in enumerate(v) if not x), None)


class _Analyser:
    def __init__(self, ctx: _Context, findings: list[Finding]) -> None:
        self.ctx = ctx
        self.findings = findings

    # -------------------------------------------------------------- consistency

    def consistency(self) -> tuple[bool, str]:
        ctx = self.ctx
        items = ctx._all_items()
        k = ctx.k
        lits = [ctx.ok_lit(i, k) for i in items]
        r = ctx.check(lits)
        if r == z3.sat:
            return True, f"consistent: a {k}-tick trace satisfies all {len(ctx.reqs)} requirements"
        if r != z3.unsat:
            return False, f"unknown: z3 gave up ({ctx.solver.reason_unknown()})"
        active = list(items)
        for _ in range(5):  # report independent conflicts, not only the first
            core = ctx.minimal_core(active, k)
            if core is None:
                break
            self._conflict(core)
            drop = {i for i in core if not i.startswith("range:")} or set(core)
            active = [i for i in active if i not in drop]
        return False, "inconsistent: no trace satisfies all requirements (see conflicts)"

    def _conflict(self, core: list[str]) -> None:
        ctx = self.ctx
        n = next(n for n in range(1, ctx.k + 1) if ctx.minimal_core(core, n) is not None)
        reqs = [i for i in core if not i.startswith("range:")]
        trace, vrd, note = None, {}, ""
        for victim in reversed(reqs):  # show the others holding and one of them failing
            rest = [i for i in core if i != victim]
            lits = [ctx.viol_lit(victim, n), *(ctx.ok_lit(i, n) for i in rest)]
            model = ctx.late_violation(lits, victim, n)
            if model is not None:
                full = ctx.model_trace(model, n)
                ctx.assert_agrees(full, rest, [victim])
                vrd = ctx.recheck(full, reqs)
                trace = ctx.columns(full, core)
                t = _first_false(vrd[victim]) if ctx.reqs[victim].monotone else n - 1
                note = f"{_names(rest)} hold; {victim} is violated at tick {t}"
                break
        when = "at tick 0" if n == 1 else f"once the trace has {n} ticks (tick {n - 1})"
        self.findings.append(
            Finding(
                "conflict",
                "error",
                tuple(reqs),
                f"{_names(core)} cannot all hold: they conflict {when}",
                "decide which requirement is right in this situation and change the other "
                "(a narrower scope or condition, a different response or timing)",
                trace,
                note,
                vrd,
            )
        )

    # -------------------------------------------------------------- vacuity

    def vacuity(self, consistent: bool) -> set[str]:
        ctx, k = self.ctx, self.ctx.k
        vacuous: set[str] = set()
        base = ctx._assumption_items()
        for rid, r in ctx.reqs.items():
            if r.activation == TRUE:
                continue
            core = ctx.minimal_core(base, k, [ctx.fired_lit(rid, k)])
            if core is not None:
                vacuous.add(rid)
                why = f"allowed by {_names(core)}" if core else "at all"
                self.findings.append(
                    Finding(
                        "vacuous",
                        "warning",
                        (rid, *(c for c in core if not c.startswith("range:"))),
                        f"{rid} can never be triggered: no trace of {k} ticks {why} makes "
                        f"its scope/condition `{r.activation}` true, so it constrains nothing",
                        f"correct the scope or condition of {rid} (values the assumptions "
                        "and ranges allow), or remove it",
                    )
                )
                continue
            if not consistent:
                continue
            core = ctx.minimal_core(ctx._all_items(), k, [ctx.fired_lit(rid, k)])
            if core is not None:
                vacuous.add(rid)
                self.findings.append(
                    Finding(
                        "unreachable",
                        "warning",
                        (rid, *(c for c in core if not c.startswith("range:") and c != rid)),
                        f"{rid} is never triggered in a trace that satisfies the requirements: "
                        f"{_names(core)} together keep its scope/condition `{r.activation}` "
                        f"false (traces of {k} ticks)",
                        f"check whether {rid}'s scope/condition can really happen, or whether "
                        "the other requirements are too strong",
                    )
                )
        return vacuous

    # -------------------------------------------------------------- redundancy

    def redundancy(self, skip: set[str]) -> None:
        ctx, k = self.ctx, self.ctx.k
        for rid, r in ctx.reqs.items():
            if r.assumption or rid in skip:
                continue  # an assumption implied by the ranges still documents them
            others = ctx._all_items(exclude=[rid])
            core = ctx.minimal_core(others, k, [ctx.viol_lit(rid, k)])
            if core is None:
                continue
            if core == [] and max_bound(r.formula) + 1 >= k:
                self.findings.append(
                    Finding(
                        "k-too-small",
                        "info",
                        (rid,),
                        f"{rid} cannot be violated on traces of {k} ticks (its time bound is "
                        f"{max_bound(r.formula)}), so the analyses say little about it",
                        f"analyse longer traces: --k {max_bound(r.formula) + 2} or more",
                    )
                )
                continue
            pure = pure_invariant(r.formula) is not None and all(
                i.startswith("range:") or pure_invariant(ctx.reqs[i].formula) is not None
                for i in core
            )
            horizon = "at every tick, for all time" if pure else f"on every trace of {k} ticks"
            by = _names(core) if core else "nothing (it always holds)"
            self.findings.append(
                Finding(
                    "redundant",
                    "warning",
                    (rid, *(c for c in core if not c.startswith("range:"))),
                    f"{rid} is implied by {by} {horizon}: its handler can only fire when "
                    "another requirement's does",
                    f"remove {rid}, or check whether it was meant to say something stronger",
                )
            )

    # -------------------------------------------------------------- realizability

    def realizability(self) -> str:
        ctx = self.ctx
        outs = {n for n in ctx.names if ctx.vars[n].role == "output"}
        ins = [n for n in ctx.names if n not in outs]
        if not outs:
            self.findings.append(
                Finding(
                    "no-outputs",
                    "info",
                    (),
                    "realizability not checked: no variable has role: output, so nothing is "
                    "controlled by the robot",
                    "give the variables the robot sets (states, commands) role: output",
                )
            )
            return "not checked (no output variables)"
        assumptions, guarantees = [], []
        for rid, r in ctx.reqs.items():
            reads = set(variables(r.formula))
            if r.assumption and reads & outs:
                self.findings.append(
                    Finding(
                        "assumption-reads-outputs",
                        "warning",
                        (rid,),
                        f"assumption {rid} reads output(s) {', '.join(sorted(reads & outs))}; "
                        "assumptions constrain inputs only, so realizability treats it as a "
                        "guarantee the controller must keep",
                        f"rewrite {rid} over inputs only, or make it a guarantee",
                    )
                )
                guarantees.append(rid)
            elif r.assumption:
                assumptions.append(rid)
            else:
                guarantees.append(rid)
        outs_l = [n for n in ctx.names if n in outs]
        pure = all(
            ctx.reqs[r].monotone and pure_invariant(ctx.reqs[r].formula) is not None
            for r in ctx.reqs
        )
        if pure:
            return _Game(ctx, ins, outs_l, assumptions, guarantees).per_tick(self.findings)
        # Requirements that share no variable are independent games: the controller
        # plays each on its own (given a consistent set, the environment gains nothing
        # by linking them), and small games are what z3's quantifier engine can solve.
        results: list[tuple[str, str]] = []
        groups = _components(ctx, assumptions + guarantees)
        for group in groups:
            g_ids = [r for r in group if r in guarantees]
            if not g_ids:
                continue
            used = {v for r in group for v in variables(ctx.reqs[r].formula)}
            game = _Game(
                ctx,
                [n for n in ins if n in used],
                [n for n in outs_l if n in used],
                [r for r in group if r in assumptions],
                g_ids,
            )
            results.append(game.bounded(self.findings))
        return _summary(results, ctx.k, len(results))


def _components(ctx: _Context, ids: list[str]) -> list[list[str]]:
    """Requirements grouped by shared variables (connected components)."""
    parent = {r: r for r in ids}

    def find(x: str) -> str:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    owner: dict[str, str] = {}
    for r in ids:
        for v in variables(ctx.reqs[r].formula):
            if v in owner:
                parent[find(r)] = find(owner[v])
            else:
                owner[v] = r
    groups: dict[str, list[str]] = {}
    for r in ids:
        groups.setdefault(find(r), []).append(r)
    return list(groups.values())


def _summary(results: list[tuple[str, str]], k: int, n: int) -> str:
    bad = [text for status, text in results if status == "unrealizable"]
    if bad:
        return "; ".join(dict.fromkeys(bad))
    open_ = [text for status, text in results if status != "causal"]
    groups = f" ({n} independent groups of requirements)" if n > 1 else ""
    if open_:
        return "; ".join(dict.fromkeys(open_)) + groups
    return (
        f"realizable on every trace of {k} ticks by a causal controller (outputs depend only "
        f"on past and present inputs){groups}; bounded: not proved beyond {k} ticks"
    )


@dataclass
class _Arena:
    """What a bounded game is played on: per-tick variables, the requirements'
    truth per tick, and per tick what the environment may choose (input ranges)
    and what the controller must choose (output ranges)."""

    rows: list[Row]
    ins: list[str]
    outs: list[str]
    holds: dict[str, list[z3.BoolRef]]
    env_tick: list[z3.BoolRef]
    out_tick: list[z3.BoolRef]
    # concrete inputs (for the context's rows) from a model of this arena
    concretize: Callable[[z3.ModelRef, int], list[dict[str, z3.ExprRef]]]
    boolean: bool  # the Boolean abstraction (fast games) or the values themselves


class _Abstraction(Exception):
    """The requirements do not allow the Boolean abstraction (see _abstract_arena)."""


def _concrete_arena(game: _Game) -> _Arena:
    ctx = game.ctx

    def ranges(names: list[str], t: int) -> z3.BoolRef:
        return z3.And([ctx.at(ctx.ranges[n])[t] for n in names if n in ctx.ranges] or [True])

    def concretize(model: z3.ModelRef, n: int) -> list[dict[str, z3.ExprRef]]:
        return [
            {m: model.eval(ctx.rows[t][m], model_completion=True) for m in game.ins}
            for t in range(n)
        ]

    return _Arena(
        ctx.rows,
        game.ins,
        game.outs,
        ctx.holds,
        [ranges(game.ins, t) for t in range(ctx.k)],
        [ranges(game.outs, t) for t in range(ctx.k)],
        concretize,
        False,
    )


MAX_ATOMS_PER_GROUP = 10


def _abstract_arena(game: _Game) -> _Arena:
    """The same game over Booleans: each comparison (``s0 > 86``, ``level0 = 0``)
    becomes a Boolean variable, and each tick the environment (controller) may pick
    exactly the combinations of input (output) comparisons that some values within
    the ranges make true.  Exact when no comparison mixes inputs and outputs (then
    the requirements see the values only through these comparisons, and ticks are
    independent choices); z3 solves the Boolean game far faster than the one over
    64-bit values.  Raises _Abstraction when a comparison mixes inputs and outputs
    or too many comparisons share variables."""
    ctx = game.ctx
    ins, outs = set(game.ins), set(game.outs)
    types_enc = Encoder(ctx.types, [])
    atoms: dict[Formula, str] = {}

    def go(f: Formula) -> Formula:
        if isinstance(f, BinOp) and f.op in REL_OPS and types_enc.type_of(f.left) != "bool":
            vs = set(variables(f))
            if not vs:
                return f
            if vs & ins and vs & outs:
                raise _Abstraction(f"{f} compares inputs with outputs")
            return Var(atoms.setdefault(f, f"cmp{len(atoms)}"))
        return map_children(f, go)

    ids = game.assumptions + game.guarantees
    abstract = {r: go(ctx.reqs[r].formula) for r in ids}
    side = {name: ("in" if set(variables(f)) <= ins else "out") for f, name in atoms.items()}
    bools_in = [n for n in game.ins if ctx.types[n] == "bool"]
    bools_out = [n for n in game.outs if ctx.types[n] == "bool"]
    a_ins = bools_in + [n for n in atoms.values() if side[n] == "in"]
    a_outs = bools_out + [n for n in atoms.values() if side[n] == "out"]
    types = {n: "bool" for n in a_ins + a_outs}
    rows = fresh_rows(types, a_ins + a_outs, ctx.k, f"g{id(game)}_")
    enc = Encoder(types, rows)
    holds = {r: enc.holds(f) for r, f in abstract.items()}

    # comparisons sharing a variable constrain each other: one feasibility table each
    by_atom = {name: f for f, name in atoms.items()}
    groups = _components_of({n: set(variables(f)) for n, f in by_atom.items()})
    tables = []
    for group in groups:
        if len(group) > MAX_ATOMS_PER_GROUP:
            raise _Abstraction(f"{len(group)} comparisons share variables")
        tables.append((group, _feasible(ctx, [by_atom[n] for n in group])))

    def allowed(s: str, t: int) -> z3.BoolRef:
        parts = []
        for group, combos in tables:
            if side[group[0]] != s:
                continue
            parts.append(
                z3.Or(
                    [
                        z3.And([rows[t][n] == z3.BoolVal(v) for n, v in zip(group, c, strict=True)])
                        for c in combos
                    ]
                    or [z3.BoolVal(False)]
                )
            )
        return z3.And(parts) if parts else z3.BoolVal(True)

    def concretize(model: z3.ModelRef, n: int) -> list[dict[str, z3.ExprRef]]:
        out = []
        for t in range(n):
            row: dict[str, z3.ExprRef] = {}
            for b in bools_in:
                row[b] = model.eval(rows[t][b], model_completion=True)
            for group, _ in tables:
                if side[group[0]] != "in":
                    continue
                want = [z3.is_true(model.eval(rows[t][a], model_completion=True)) for a in group]
                row.update(_realize(ctx, [by_atom[a] for a in group], want))
            for m in game.ins:  # inputs no comparison mentions: any value in range
                row.setdefault(m, _quiet_value(ctx.vars[m]))
            out.append(row)
        return out

    return _Arena(
        rows,
        a_ins,
        a_outs,
        holds,
        [allowed("in", t) for t in range(ctx.k)],
        [allowed("out", t) for t in range(ctx.k)],
        concretize,
        True,
    )


def _components_of(uses: dict[str, set[str]]) -> list[list[str]]:
    groups: list[tuple[set[str], list[str]]] = []
    for name, vs in uses.items():
        merged = [g for g in groups if g[0] & vs]
        keep = [g for g in groups if not g[0] & vs]
        vars_ = set(vs).union(*(g[0] for g in merged))
        members = [m for g in merged for m in g[1]] + [name]
        groups = keep + [(vars_, members)]
    return [sorted(g[1], key=list(uses).index) for g in groups]


def _atom_solver(ctx: _Context, fs: list[Formula]) -> tuple[z3.Solver, list[z3.BoolRef], Row]:
    names = list(dict.fromkeys(v for f in fs for v in variables(f)))
    row = fresh_row(ctx.types, names, "atom")
    s = z3.Solver()
    s.set(timeout=ctx.timeout_ms)
    for n in names:
        if n in ctx.ranges:
            s.add(tick_encoding(ctx.types, ctx.ranges[n], row))
    return s, [tick_encoding(ctx.types, f, row) for f in fs], row


def _feasible(ctx: _Context, fs: list[Formula]) -> list[tuple[bool, ...]]:
    """Every combination of truth values of the comparisons ``fs`` that values
    within the ranges can produce (all-SAT)."""
    s, xs, _ = _atom_solver(ctx, fs)
    combos = []
    while True:
        r = s.check()
        if r == z3.unknown:
            raise _Abstraction("feasible comparisons not decided")
        if r == z3.unsat:
            return combos
        m = s.model()
        c = tuple(z3.is_true(m.eval(x, model_completion=True)) for x in xs)
        combos.append(c)
        s.add(z3.Or([x != z3.BoolVal(v) for x, v in zip(xs, c, strict=True)]))


def _realize(ctx: _Context, fs: list[Formula], want: list[bool]) -> dict[str, z3.ExprRef]:
    """Values within the ranges that give the comparisons ``fs`` the truth values ``want``."""
    s, xs, row = _atom_solver(ctx, fs)
    s.add([x == z3.BoolVal(v) for x, v in zip(xs, want, strict=True)])
    assert s.check() == z3.sat, "a feasible comparison combination has no values"
    m = s.model()
    return {n: m.eval(x, model_completion=True) for n, x in row.items()}


class _Game:
    """The controller (outputs) against the environment (inputs).

    The environment picks inputs allowed by the assumptions and input ranges; the
    controller must then keep every guarantee and output range.  Strictly: at
    each tick t, if the assumptions held up to t, the guarantees hold at t."""

    def __init__(
        self,
        ctx: _Context,
        ins: list[str],
        outs: list[str],
        assumptions: list[str],
        guarantees: list[str],
    ) -> None:
        self.ctx = ctx
        self.ins, self.outs = ins, outs
        self.assumptions, self.guarantees = assumptions, guarantees
        self.in_items = assumptions + [f"range:{n}" for n in ins if n in ctx.ranges]
        self.out_items = guarantees + [f"range:{n}" for n in outs if n in ctx.ranges]
        self._arena: _Arena | None = None

    @property
    def arena(self) -> _Arena:
        if self._arena is None:
            try:
                self._arena = _abstract_arena(self)
            except _Abstraction:
                self._arena = _concrete_arena(self)
        return self._arena

    # -------------------------------------------------------------- per tick

    def per_tick(self, findings: list[Finding]) -> str:
        """All requirements are ``H p`` with p propositional: each tick is on its own,
        so "for every allowed input there is an output" at one tick proves the set
        realizable for all time (the controller answers each tick's inputs), and an
        input that has no answer defeats every controller at tick 0."""
        ctx = self.ctx
        row = fresh_row(ctx.types, ctx.names, "tick")
        env = z3.And([self._tick(i, row) for i in self.in_items] or [z3.BoolVal(True)])
        win = z3.And([self._tick(i, row) for i in self.out_items] or [z3.BoolVal(True)])
        ivars = [row[n] for n in self.ins]
        ovars = [row[n] for n in self.outs]
        status, model = _exists_forall(z3.And(env, z3.Not(win)), ivars, ovars, ctx.timeout_ms)
        if status == "unsat":
            return (
                "realizable, proved for all time: every requirement is a per-tick invariant, "
                "and for every input allowed by the assumptions and ranges there are outputs "
                "satisfying all guarantees"
            )
        if status == "unknown":
            self._unknown(findings, "per-tick")
            return "unknown (z3 could not decide within the time limit)"
        assert model is not None
        pinned = {n: model.eval(row[n], model_completion=True) for n in self.ins}
        self._defeat(findings, [pinned], 0)
        return "unrealizable: an input at a single tick defeats every controller"

    def _tick(self, item: str, row: Row) -> z3.BoolRef:
        ctx = self.ctx
        f = ctx.ranges[item[6:]] if item.startswith("range:") else ctx.reqs[item].formula
        body = pure_invariant(f) if not item.startswith("range:") else f
        assert body is not None
        return tick_encoding(ctx.types, body, row)

    # -------------------------------------------------------------- bounded

    def _ok(self, rid: str, n: int) -> z3.BoolRef:
        xs = self.arena.holds[rid]
        return z3.And(xs[:n]) if self.ctx.reqs[rid].monotone else xs[n - 1]

    def env_ok(self, n: int) -> z3.BoolRef:
        """Assumptions and input ranges hold on ticks 0..n-1."""
        parts = [self.arena.env_tick[t] for t in range(n)]
        parts += [self._ok(a, n) for a in self.assumptions]
        return z3.And(parts) if parts else z3.BoolVal(True)

    def win_at(self, t: int, horizon: int) -> z3.BoolRef:
        """Guarantees and output ranges at tick t (non-monotone ones at the horizon's end)."""
        parts = [self.arena.out_tick[t]]
        for g in self.guarantees:
            if self.ctx.reqs[g].monotone or t == horizon - 1:
                parts.append(self.arena.holds[g][t])
        return z3.And(parts)

    def vars_at(self, names: list[str], t: int) -> list[z3.ExprRef]:
        return [self.arena.rows[t][n] for n in names]

    def clairvoyant(self, n: int) -> tuple[str, z3.ModelRef | None]:
        """Is there an input sequence of n ticks, allowed throughout, that no output
        sequence answers?  (Outputs here may depend on the whole input sequence.)"""
        win = z3.And([self.win_at(t, n) for t in range(n)])
        ivars = [v for t in range(n) for v in self.vars_at(self.arena.ins, t)]
        ovars = [v for t in range(n) for v in self.vars_at(self.arena.outs, t)]
        return _exists_forall(
            z3.And(self.env_ok(n), z3.Not(win)), ivars, ovars, self.ctx.timeout_ms
        )

    def causal(self, n: int) -> str:
        """The bounded game: forall i0 exists o0 forall i1 exists o1 ... (outputs at
        tick t see inputs up to t only).  'sat': a causal controller exists for n ticks."""
        body = z3.And([z3.Implies(self.env_ok(t + 1), self.win_at(t, n)) for t in range(n)])
        for t in reversed(range(n)):
            o, i = self.vars_at(self.arena.outs, t), self.vars_at(self.arena.ins, t)
            if o:
                body = z3.Exists(o, body)
            if i:
                body = z3.ForAll(i, body)
        s = z3.Solver()
        s.set(timeout=self.ctx.timeout_ms)
        s.add(body)
        r = s.check()
        return "sat" if r == z3.sat else "unsat" if r == z3.unsat else "unknown"

    def bounded(self, findings: list[Finding]) -> tuple[str, str]:
        """(status, summary): status causal | clairvoyant | unknown | unrealizable."""
        ctx, k = self.ctx, self.ctx.k
        # On Booleans the game first: when a causal controller exists (the usual
        # case) that is the strongest answer and takes z3 milliseconds.  Over 64-bit
        # values the alternating game is slow, and the two-level clairvoyant question
        # finds most unrealizable sets faster, so it goes first there.
        causal = self.causal(k) if self.arena.boolean else None
        if causal == "sat":
            return "causal", f"realizable by a causal controller for {k} ticks"
        status, model = self.clairvoyant(k)
        if status == "sat":
            # the shortest defeating sequence: where the guarantees first break
            for n in range(1, k + 1):
                status, model = self.clairvoyant(n)
                if status == "sat":
                    break
            assert model is not None
            self._defeat(findings, self.arena.concretize(model, n), n - 1)
            return (
                "unrealizable",
                f"unrealizable: an input sequence of {_ticks(n)} defeats every controller",
            )
        if status == "unknown":
            self._unknown(findings, "bounded")
            return "unknown", f"unknown: z3 could not decide realizability for {k} ticks"
        if causal is None:
            causal = self.causal(k)
        if causal == "sat":
            return "causal", f"realizable by a causal controller for {k} ticks"
        if causal == "unknown":
            findings.append(
                Finding(
                    "realizability",
                    "warning",
                    tuple(self.guarantees),
                    f"only the weaker check passed: for every input sequence of {k} ticks "
                    "there are outputs satisfying the guarantees, but those outputs may depend "
                    "on future inputs; whether a controller that only knows past and present "
                    f"inputs exists was not decided within {ctx.timeout_ms / 1000:g} s",
                    "raise analysis.timeout_s, or lower the time bounds / k",
                )
            )
            return (
                "clairvoyant",
                f"clairvoyantly realizable for {k} ticks (whether a causal controller exists "
                "was not decided)",
            )
        n = next((n for n in range(1, k + 1) if self.causal(n) == "unsat"), k)
        core = self._causal_core(n)
        findings.append(
            Finding(
                "unrealizable",
                "error",
                tuple(core),
                f"{_names(core)} cannot be met by a controller that only knows past and present "
                f"inputs: for every input sequence there are suitable outputs, but choosing "
                f"them needs inputs that arrive later (the environment wins within {_ticks(n)})",
                "make the obligation react to inputs instead of anticipating them (e.g. "
                "'upon' + 'within' instead of requiring an output before the input it depends on)",
            )
        )
        return "unrealizable", f"unrealizable by a causal controller within {_ticks(n)}"

    def _causal_core(self, n: int) -> list[str]:
        if len(self.guarantees) > 12:
            return list(self.guarantees)  # deletion costs one game per guarantee
        core = list(self.guarantees)
        for g in list(core):
            trial = _Game(
                self.ctx, self.ins, self.outs, self.assumptions, [x for x in core if x != g]
            )
            if trial.causal(n) == "unsat":
                core = trial.guarantees
        return core

    # -------------------------------------------------------------- reporting

    def _unknown(self, findings: list[Finding], what: str) -> None:
        findings.append(
            Finding(
                "realizability",
                "warning",
                tuple(self.guarantees),
                f"realizability ({what}) not decided: z3 gave up within "
                f"{self.ctx.timeout_ms / 1000:g} s (double arithmetic is the usual cause)",
                "raise analysis.timeout_s, or give the double variables ranges",
            )
        )

    def _defeat(
        self, findings: list[Finding], pinned: list[dict[str, z3.ExprRef]], last: int
    ) -> None:
        """Report inputs (ticks 0..last) that no outputs answer: the smallest set of
        guarantees they defeat, and outputs meeting all but one of them."""
        ctx = self.ctx
        n = last + 1
        env_items = [ctx.ok_lit(i, n) for i in self.in_items]
        pinned = self._quiet(pinned, n, env_items)
        self._report_defeat(findings, n, [self._pin_lit(pinned), *env_items])

    def _pin_lit(self, pinned: list[dict[str, z3.ExprRef]]) -> z3.BoolRef:
        """A literal fixing the inputs (a literal, not push/pop: the solver's other
        indicator literals must stay asserted at the base level)."""
        ctx = self.ctx
        fix = [ctx.rows[t][m] == v for t, row in enumerate(pinned) for m, v in row.items()]
        return ctx.lit(("pin", len(ctx._lits)), lambda: z3.And(fix) if fix else z3.BoolVal(True))

    def _defeats(self, pinned: list[dict[str, z3.ExprRef]], env_items: list[z3.BoolRef]) -> bool:
        """The pinned inputs are allowed and no outputs meet the guarantees on them."""
        ctx, n = self.ctx, len(pinned)
        pin = self._pin_lit(pinned)
        if ctx.check([pin, *env_items]) != z3.sat:
            return False
        outs = [ctx.ok_lit(i, n) for i in self.out_items]
        return ctx.check([pin, *env_items, *outs]) == z3.unsat

    def _quiet(
        self, pinned: list[dict[str, z3.ExprRef]], n: int, env_items: list[z3.BoolRef]
    ) -> list[dict[str, z3.ExprRef]]:
        """Move each input value to a quiet default (false, 0 or the nearest range end)
        where the sequence still defeats every controller: the table then shows only
        the inputs that matter, not the solver's arbitrary choices."""
        ctx = self.ctx
        assert self._defeats(pinned, env_items), "z3: the defeating inputs are answered"
        budget = 64
        for t in range(n):
            for m in self.ins:
                if budget == 0:
                    return pinned
                quiet = _quiet_value(ctx.vars[m])
                if z3.eq(z3.simplify(pinned[t][m] == quiet), z3.BoolVal(True)):
                    continue
                budget -= 1
                trial = [dict(row) for row in pinned]
                trial[t][m] = quiet
                if self._defeats(trial, env_items):
                    pinned = trial
        return pinned

    def _report_defeat(self, findings: list[Finding], n: int, env_items: list[z3.BoolRef]) -> None:
        ctx = self.ctx
        last = n - 1
        fixed: list[z3.BoolRef] = list(env_items)
        core = ctx.minimal_core(self.out_items, n, fixed)
        assert core is not None, "defeating inputs are answered after all"
        reqs = [c for c in core if not c.startswith("range:")]
        trace, vrd, note = None, {}, ""
        for victim in reversed(reqs):
            rest = [i for i in self.out_items if i != victim]
            lits = [*fixed, ctx.viol_lit(victim, n), *(ctx.ok_lit(i, n) for i in rest)]
            model = ctx.late_violation(lits, victim, n)
            if model is not None:
                full = ctx.model_trace(model, n)
                ctx.assert_agrees(full, self.in_items + rest, [victim])
                vrd = ctx.recheck(full, [*reqs, *self.assumptions])
                shown = reqs + [
                    a
                    for a in self.assumptions
                    if set(variables(ctx.reqs[a].formula))
                    & {v for r in reqs for v in variables(ctx.reqs[r].formula)}
                ]
                vrd = {r: vrd[r] for r in shown}
                trace = ctx.columns(full, shown)
                t = _first_false(vrd[victim]) if ctx.reqs[victim].monotone else n - 1
                note = (
                    f"the inputs ({', '.join(self.ins)}) are allowed by the assumptions; "
                    f"outputs meeting the other guarantees violate {victim} at tick {t}"
                )
                break
        only_inputs = [r for r in reqs if not set(variables(ctx.reqs[r].formula)) & set(self.outs)]
        hint = (
            f"{_names(only_inputs)} read(s) no output: the robot cannot make it true; make it "
            "an assumption, or add the output the robot should set"
            if only_inputs
            else "weaken one of them for this input situation, or add an assumption that "
            "excludes it if it cannot happen"
        )
        findings.append(
            Finding(
                "unrealizable",
                "error",
                tuple(reqs),
                f"unrealizable: for the input sequence below (allowed by the assumptions), no "
                f"outputs satisfy {_names(core)} "
                + (f"on ticks 0..{last}" if last else "at tick 0"),
                hint,
                trace,
                note,
                vrd,
            )
        )


def _quiet_value(v: VarInfo) -> z3.ExprRef:
    lo, hi = v.range if v.range is not None else (0.0, 0.0)
    x = min(max(0.0, lo), hi)
    if v.type == "bool":
        return z3.BoolVal(False)
    if v.type == "int64":
        return z3.BitVecVal(min(max(0, math.ceil(lo)), math.floor(hi)) if v.range else 0, 64)
    return fp_const(x)


def _exists_forall(
    body: z3.BoolRef, evars: list[z3.ExprRef], uvars: list[z3.ExprRef], timeout_ms: int
) -> tuple[str, z3.ModelRef | None]:
    """Exists evars . forall uvars . body.  Two methods that fail on different
    problems: z3's quantifier engine, briefly (fast on bit-vectors where an output
    is a function of an input, hopeless for CEGIS), then a CEGIS loop (candidate
    inputs refuted by outputs that answer them; fast on Boolean games, where the
    quantifier engine can take minutes) for the rest of the time."""
    first = min(2000, max(1, timeout_ms // 4))
    s = z3.Solver()
    s.set(timeout=first)
    s.add(z3.ForAll(uvars, body) if uvars else body)
    r = s.check()
    if r == z3.sat:
        return "sat", s.model()
    if r == z3.unsat:
        return "unsat", None
    return _cegis(body, evars, uvars, max(1, timeout_ms - first))


def _cegis(
    body: z3.BoolRef, evars: list[z3.ExprRef], uvars: list[z3.ExprRef], timeout_ms: int
) -> tuple[str, z3.ModelRef | None]:
    deadline = time.monotonic() + timeout_ms / 1000
    cand, refute = z3.Solver(), z3.Solver()
    refute.add(z3.Not(body))
    while time.monotonic() < deadline:
        left = max(1, int((deadline - time.monotonic()) * 1000))
        cand.set(timeout=left)
        r = cand.check()
        if r == z3.unsat:
            return "unsat", None
        if r != z3.sat:
            break
        m = cand.model()
        pin = [(v, m.eval(v, model_completion=True)) for v in evars]
        refute.set(timeout=left)
        r2 = refute.check(*[v == x for v, x in pin])
        if r2 == z3.unsat:
            return "sat", m
        if r2 != z3.sat:
            break
        m2 = refute.model()
        answer = [(v, m2.eval(v, model_completion=True)) for v in uvars]
        cand.add(z3.substitute(body, *answer) if answer else body)
    return "unknown", None


# ------------------------------------------------------------------ entry point


def analyse(
    reqs: Sequence[Req],
    vars_: dict[str, VarInfo] | Sequence[VarInfo],
    *,
    k: int | None = None,
    timeout_s: float = DEFAULT_TIMEOUT_S,
) -> Analysis:
    """Run every analysis on traces of ``k`` ticks (default: ``default_k``)."""
    if not isinstance(vars_, dict):
        vars_ = {v.name: v for v in vars_}
    k = k or default_k(reqs)
    if k < 1:
        raise ValueError("k must be at least 1")
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    ctx = _Context(reqs, vars_, k, timeout_s)
    findings: list[Finding] = []
    for rid, why in ctx.unsupported.items():
        findings.append(
            Finding(
                "not-analysed",
                "warning",
                (rid,),
                f"{rid} is left out of the analyses: {why}",
                "nothing to change for the monitor; the analyses just cannot reason about it",
            )
        )
    for r in reqs:
        if not r.monotone and r.id in ctx.reqs:
            findings.append(
                Finding(
                    "non-monotone",
                    "warning",
                    (r.id,),
                    r.note or f"{r.id} is non-monotone (false until something happens)",
                    "if a per-tick obligation was meant, use a timing such as 'always', "
                    "'within N ticks' or 'immediately'; the analyses judge it at the end of "
                    "each trace",
                )
            )
    a = _Analyser(ctx, findings)
    seconds["encode"] = time.perf_counter() - t0
    t = time.perf_counter()
    consistent, consistency = a.consistency()
    seconds["consistency"] = time.perf_counter() - t
    t = time.perf_counter()
    realizability = a.realizability() if consistent else "not checked (inconsistent)"
    seconds["realizability"] = time.perf_counter() - t
    t = time.perf_counter()
    vacuous = a.vacuity(consistent)
    seconds["vacuity"] = time.perf_counter() - t
    t = time.perf_counter()
    if consistent:
        a.redundancy(vacuous)
    seconds["redundancy"] = time.perf_counter() - t
    seconds["total"] = time.perf_counter() - t0
    order = {s: i for i, s in enumerate(SEVERITIES)}
    findings.sort(key=lambda f: order[f.severity])
    return Analysis(
        k,
        list(reqs),
        dict(vars_),
        findings,
        consistent,
        consistency,
        realizability,
        seconds,
        ctx,
    )
