"""The reference interpreter's judgement of a planned injection: it must confirm
everything z3 claimed on every sequence the supervisor may step on, or nothing
is published; then the values are tidied and the notes say what else breaks."""

from __future__ import annotations

import math

from monitors.ir.formula import Const, subterms, variables
from monitors.verify.bmc import evaluate_z3
from monitors.verify.interpret import verdicts
from supervisor.tools.inject.errors import InjectError
from supervisor.tools.inject.fields import fits
from supervisor.tools.inject.injection import Injection, Trace
from supervisor.tools.inject.report import and_list
from supervisor.tools.inject.target import Target


def recheck(target: Target, inj: Injection) -> None:
    """The reference interpreter must confirm everything z3 claimed, on every
    observed sequence; otherwise nothing may be published."""
    problem = judge(target, inj, inj.trace)
    if problem is not None:
        raise InjectError(
            f"internal error: z3 and the reference interpreter disagree on the trace "
            f"for {inj.req}: {problem}; nothing was published (please report) {inj.trace}"
        )
    _tidy(target, inj)
    # the encoder must agree with the judge on the final trace too
    states, _ = target.observed(inj.trace, target.saturation, target.saturation)
    for r, q in target.reqs.items():
        if evaluate_z3(q.formula, states, target.types) != verdicts(q.formula, states):
            raise InjectError(
                f"internal error: z3 and the reference interpreter disagree on {r} "
                f"for the trace of {inj.req}; nothing was published (please report)"
            )
    inj.tick_violations = _flagged(target, inj)


def judge(target: Target, inj: Injection, trace: Trace) -> str | None:
    """What is wrong with ``trace`` as the injection ``inj`` describes it (REQ
    violated at the last tick, held before if ``early``, the others and ranges
    not listed as broken held throughout), according to the interpreter."""
    rid, tail = inj.req, target.saturation
    for warm in target.variants():
        states, labels = target.observed(trace, warm, tail)
        first, last = target.span(labels, inj.k - 1)
        mine = verdicts(target.reqs[rid].formula, states)
        if mine[last]:
            return f"{rid} holds at the injected tick (warm-up {warm})"
        if inj.early and not all(mine[:first]):
            return f"{rid} is violated before the injected tick (warm-up {warm})"
        for o, q in target.reqs.items():
            if o != rid and o not in inj.broken and not all(verdicts(q.formula, states)):
                return f"{o} is violated (warm-up {warm})"
    if inj.early and not all(verdicts(target.reqs[rid].formula, [trace[0]] * tail)):
        return f"{rid} is violated on the nominal state"
    for n, f in target.ranges.items():
        if n not in inj.broken_ranges and not all(verdicts(f, trace)):
            return f"the range of {n} is broken"
    return None


def _flagged(target: Target, inj: Injection) -> list[list[str]]:
    """Per published tick, the requirements the supervisor may flag there (any
    warm-up variant; a monitor stays false after a violation: its first tick)."""
    flagged: list[set[str]] = [set() for _ in inj.trace]
    for warm in target.variants():
        states, labels = target.observed(inj.trace, warm, target.saturation)
        for r, q in target.reqs.items():
            vs = verdicts(q.formula, states)
            i = next((i for i, ok in enumerate(vs) if not ok), None)
            if i is not None and labels[i] >= 0:
                flagged[labels[i]].add(r)
    return [[r for r in target.reqs if r in f] for f in flagged]


def _tidy(target: Target, inj: Injection) -> None:
    """Move each changed number to the nicest value that keeps every property
    (the interpreter judges): the closest to the previous tick, preferring the
    constants the requirements compare with and their neighbours, so a value
    reads as the threshold it crosses (8 for '> 7') instead of whatever z3 chose.
    Cheaper than asking z3 to minimise distances over 64-bit vectors."""
    consts: set[int | float] = {0}
    for q in target.reqs.values():
        for g in subterms(q.formula):
            if isinstance(g, Const) and not isinstance(g.value, bool):
                v = g.value
                if isinstance(v, float) and not math.isfinite(v):
                    continue
                consts |= {v - 1, v, v + 1}
    trace = inj.trace
    for t in range(1, len(trace)):
        for n in target.inputs:
            cur, prev = trace[t][n], trace[t - 1][n]
            if target.types[n] == "bool" or cur == prev:
                continue
            run = t  # the ticks from t that hold the same value move together
            while run + 1 < len(trace) and trace[run + 1][n] == cur:
                run += 1
            rng = target.cfg.variables[n].range
            cands = set(consts) | ({rng[0], rng[1]} if rng else set())
            if target.types[n] == "int64":
                cands = {int(c) for c in cands if float(c).is_integer()}
            else:
                cands = {float(c) for c in cands}
            for c in sorted(cands, key=lambda c: (abs(c - prev), c)):
                if abs(c - prev) >= abs(cur - prev):
                    break  # no nicer value left
                if not fits(target.domains.get(n), c):
                    continue
                trial = [dict(row) for row in trace]
                for i in range(t, run + 1):
                    trial[i][n] = c
                if judge(target, inj, trial) is None:
                    trace = trial
                    break
    inj.trace = trace


def explain(target: Target, inj: Injection, nominal_exists: bool) -> None:
    """Notes for the reader: what else breaks and why, and when the outcome depends
    on more than the trace."""
    mine = set(variables(target.reqs[inj.req].formula))
    for o in inj.broken:
        shared = sorted(mine & set(variables(target.reqs[o].formula)))
        why = f" (they share {', '.join(shared)})" if shared else ""
        inj.notes.append(f"violating {inj.req} also violates {o}{why}")
    for n in inj.broken_ranges:
        rng = target.cfg.variables[n].range
        assert rng is not None
        inj.notes.append(
            f"violating {inj.req} needs {n} outside its range [{rng[0]:g}, {rng[1]:g}]: "
            "ranges are not monitored, so the supervisor should log "
            f"{and_list(inj.expected)} only"
        )
    if not inj.early:
        inj.notes.append(
            f"{inj.req} cannot hold before the injected tick here: it may be logged earlier"
        )
    for o, why in target.unsupported.items():
        inj.notes.append(f"{o} is not checked (z3 cannot encode it: {why})")
    if not nominal_exists:
        inj.notes.append(
            "no state satisfies every requirement (see check): this trace starts "
            "from a state of its own, so --all cannot start each injection alike"
        )
    # periodic ticks are sampled a variable number of times: say when that matters
    if target.schedule.policy == "periodic":
        for rep in (1, 3):
            states, labels = target.observed(inj.trace, 1, target.saturation, rep)
            last = target.span(labels, inj.k - 1)[1]
            bad = [
                o
                for o in target.reqs
                if o not in inj.expected and not all(verdicts(target.reqs[o].formula, states))
            ]
            if verdicts(target.reqs[inj.req].formula, states)[last] or bad:
                inj.notes.append(
                    f"timing-sensitive: if the supervisor samples each tick {rep} time(s) "
                    "instead of 2 the outcome differs (time bounds in periods)"
                )
                break
