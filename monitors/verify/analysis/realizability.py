"""Realizability: can a controller meet the guarantees whatever the environment
does within the assumptions?  Splits the requirements into assumptions and
guarantees, then decides per tick (pure invariants) or as bounded games, one
per group of requirements that share variables."""

from __future__ import annotations

from monitors.ir.formula import variables
from monitors.verify.analysis.context import Context
from monitors.verify.analysis.game import Game
from monitors.verify.analysis.results import Finding
from monitors.verify.bmc import pure_invariant


def realizability(ctx: Context, findings: list[Finding]) -> str:
    """The summary line; unrealizable sets and undecided games become findings."""
    outs = {n for n in ctx.names if ctx.vars[n].role == "output"}
    ins = [n for n in ctx.names if n not in outs]
    if not outs:
        findings.append(
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
            findings.append(
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
        ctx.reqs[r].monotone and pure_invariant(ctx.reqs[r].formula) is not None for r in ctx.reqs
    )
    if pure:
        return Game(ctx, ins, outs_l, assumptions, guarantees).per_tick(findings)
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
        game = Game(
            ctx,
            [n for n in ins if n in used],
            [n for n in outs_l if n in used],
            [r for r in group if r in assumptions],
            g_ids,
        )
        results.append(game.bounded(findings))
    return _summary(results, ctx.k, len(results))


def _components(ctx: Context, ids: list[str]) -> list[list[str]]:
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
