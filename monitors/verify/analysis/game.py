"""The realizability game of one group of requirements: decided per tick for
pure invariants, else bounded (causal and clairvoyant), with the smallest set
of guarantees a defeating input sequence breaks."""

from __future__ import annotations

import z3

from monitors.ir.formula import variables
from monitors.verify.analysis.arena import (
    Arena,
    NoAbstraction,
    abstract_arena,
    concrete_arena,
    quiet_value,
)
from monitors.verify.analysis.context import Context
from monitors.verify.analysis.exists_forall import exists_forall
from monitors.verify.analysis.results import Finding, Limit, Remedy
from monitors.verify.analysis.wording import and_list, first_false, ticks
from monitors.verify.bmc import Row, fresh_row, pure_invariant, tick_encoding


class Game:
    """The controller (outputs) against the environment (inputs).

    The environment picks inputs allowed by the assumptions and input ranges; the
    controller must then keep every guarantee and output range.  Strictly: at
    each tick t, if the assumptions held up to t, the guarantees hold at t."""

    def __init__(
        self,
        ctx: Context,
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
        self._arena: Arena | None = None

    @property
    def arena(self) -> Arena:
        if self._arena is None:
            try:
                self._arena = abstract_arena(
                    self.ctx,
                    self.ins,
                    self.outs,
                    self.assumptions + self.guarantees,
                    f"g{id(self)}_",
                )
            except NoAbstraction:
                self._arena = concrete_arena(self.ctx, self.ins, self.outs)
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
        status, model = exists_forall(ctx, z3.And(env, z3.Not(win)), ivars, ovars)
        if status == "unsat":
            return (
                "realizable, proved for all time: every requirement is a per-tick invariant, "
                "and for every input allowed by the assumptions and ranges there are outputs "
                "satisfying all guarantees"
            )
        if status == "unknown":
            self._unknown(findings, "per-tick")
            return f"unknown ({ctx.stop_text()})"
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
        return exists_forall(self.ctx, z3.And(self.env_ok(n), z3.Not(win)), ivars, ovars)

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
        s = self.ctx.new_solver()
        s.add(body)
        r = self.ctx.run(s)
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
                f"unrealizable: an input sequence of {ticks(n)} defeats every controller",
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
                    f"inputs exists was not decided ({ctx.stop_text()})",
                    "lower the time bounds / k",
                    remedy=self._remedy(),
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
                f"{and_list(core)} cannot be met by a controller that only knows past and present "
                f"inputs: for every input sequence there are suitable outputs, but choosing "
                f"them needs inputs that arrive later (the environment wins within {ticks(n)})",
                "make the obligation react to inputs instead of anticipating them (e.g. "
                "'upon' + 'within' instead of requiring an output before the input it depends on)",
            )
        )
        return "unrealizable", f"unrealizable by a causal controller within {ticks(n)}"

    def _causal_core(self, n: int) -> list[str]:
        if len(self.guarantees) > 12:
            return list(self.guarantees)  # deletion costs one game per guarantee
        core = list(self.guarantees)
        for g in list(core):
            trial = Game(
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
                f"realizability ({what}) not decided: {self.ctx.stop_text()} "
                "(double arithmetic is the usual cause)",
                "give the double variables ranges",
                remedy=self._remedy(),
            )
        )

    def _remedy(self) -> Remedy:
        """The limit to raise: the one that stopped z3 (its resource limit when z3
        stopped for neither, as more steps may still decide it)."""
        return Remedy(self.ctx.stopped_by or Limit.SOLVER_RLIMIT)

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
        return ctx.fresh_lit("pin", lambda: z3.And(fix) if fix else z3.BoolVal(True))

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
                quiet = quiet_value(ctx.vars[m])
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
                t = first_false(vrd[victim]) if ctx.reqs[victim].monotone else n - 1
                note = (
                    f"the inputs ({', '.join(self.ins)}) are allowed by the assumptions; "
                    f"outputs meeting the other guarantees violate {victim} at tick {t}"
                )
                break
        only_inputs = [r for r in reqs if not set(variables(ctx.reqs[r].formula)) & set(self.outs)]
        hint = (
            f"{and_list(only_inputs)} read(s) no output: the robot cannot make it true; make it "
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
                f"outputs satisfy {and_list(core)} "
                + (f"on ticks 0..{last}" if last else "at tick 0"),
                hint,
                trace,
                note,
                vrd,
            )
        )
