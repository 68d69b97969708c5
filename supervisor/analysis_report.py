"""The analyses' findings in the supervisor's words: the plain-text report.

``check`` prints ``format_analysis``; ``explain`` prints ``explain_lines`` per
requirement.  Findings are tables a safety engineer reads without knowing z3:
the requirement ids, a trace tick by tick (one column per variable, then the
reference interpreter's verdict per requirement), and what to change.  The
analyses name the limits they reached as values (``monitors.verify.analysis.Limit``);
this module names them as the user sets them: a key of the config or an option.
"""

from __future__ import annotations

import math

from monitors.verify.analysis import Analysis, Example, Finding, Limit, Remedy, Skip, VarInfo
from monitors.verify.interpret import Value

LABEL = {"error": "ERROR", "warning": "warning", "info": "info"}
BUDGET_KEY = "limits.analysis_budget_s"
# Each limit of the analyses as the user sets it (docs/reference/config.md).
SETTING = {
    Limit.TRACE_LENGTH: "analysis.k",
    Limit.SOLVER_RLIMIT: "analysis.rlimit",
    Limit.SOLVER_TIMEOUT: "analysis.timeout_s",
    Limit.TIME_BUDGET: BUDGET_KEY,
    Limit.MEMORY: "limits.analysis_memory_mb",
}


# ------------------------------------------------------------------ reasons


def remedy_text(r: Remedy) -> str:
    """What to raise, in the user's terms."""
    if r.limit is Limit.TRACE_LENGTH and r.at_least is not None:
        return f"analyse longer traces: --k {r.at_least} or more"
    return f"raise {SETTING[r.limit]}"


def fix_text(f: Finding) -> str:
    """The finding's "what to change": the limit to raise first, then the fix."""
    if f.remedy is None:
        return f.fix
    return f"{remedy_text(f.remedy)}, or {f.fix}" if f.fix else remedy_text(f.remedy)


def _shorter_or_larger(limit: Limit) -> str:
    if limit is Limit.TRACE_LENGTH:
        return "a shorter k (analysis.k, --k)"
    return f"a larger {SETTING[limit]}"


def skip_text(s: Skip) -> str:
    """Why an analysis was skipped, with what would let it run and the setting of
    the limit it reached."""
    out = s.reason
    if s.remedies:
        what = " or ".join(_shorter_or_larger(r) for r in s.remedies)
        only_k = s.remedies == (Limit.TRACE_LENGTH,)
        out += f"; {what} {'analyses shorter traces' if only_k else 'analyses it'}"
    return f"{out} ({SETTING[s.limit]})"


# ------------------------------------------------------------------ text


def _value(v: Value) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v) if not math.isnan(v) else "nan"
    return str(v)


def format_trace(
    trace: list[dict[str, Value]],
    verdicts: dict[str, list[bool]],
    variables: dict[str, VarInfo],
    indent: str = "    ",
) -> list[str]:
    """A trace as a table: tick, one column per variable (its role below the name),
    then one column per requirement with the interpreter's verdict."""
    names = list(trace[0]) if trace else []
    head = ["tick", *names]
    roles = ["", *(variables[n].role if n in variables else "" for n in names)]
    rows = [[str(t), *(_value(row[n]) for n in names)] for t, row in enumerate(trace)]
    reqs = list(verdicts)
    head += reqs
    roles += ["" for _ in reqs]
    for t, row in enumerate(rows):
        row += ["ok" if verdicts[r][t] else "VIOLATED" for r in reqs]
    width = [max(len(x[i]) for x in [head, roles, *rows]) for i in range(len(head))]
    sep = len(names) + 1  # a bar between the values and the verdicts

    def line(cells: list[str]) -> str:
        parts = [
            c.rjust(width[i]) if i <= len(names) else c.ljust(width[i]) for i, c in enumerate(cells)
        ]
        if reqs:
            return (indent + "  ".join(parts[:sep]) + " | " + "  ".join(parts[sep:])).rstrip()
        return (indent + "  ".join(parts)).rstrip()

    out = [line(head)]
    if any(roles):
        out.append(line(roles))
    out.append(line(["-" * w for w in width]))
    out.extend(line(r) for r in rows)
    return out


def format_finding(f: Finding, variables: dict[str, VarInfo]) -> list[str]:
    ids = ", ".join(f.requirements) if f.requirements else "(whole set)"
    out = [f"{LABEL[f.severity]} {f.kind}: {ids}", f"  {f.message}"]
    if f.trace:
        out.append(f"  trace: {f.trace_note}" if f.trace_note else "  trace:")
        out.extend(format_trace(f.trace, f.verdicts, variables))
    out.append(f"  what to change: {fix_text(f)}")
    return out


def _count(n: int, what: str) -> str:
    return f"{n} {what}{'' if n == 1 else 's'}"


def format_analysis(a: Analysis) -> str:
    n_a = sum(1 for r in a.requirements if r.assumption)
    n = len(a.requirements)
    out = [
        f"analysis: {_count(n, 'requirement')} ({_count(n_a, 'assumption')}, "
        f"{_count(n - n_a, 'guarantee')}), "
        f"traces of k = {a.k} ticks, {a.seconds.get('total', 0.0):.2f} s",
        f"  consistency:   {a.consistency}",
        f"  realizability: {a.realizability}",
    ]
    errors, warnings = len(a.errors), len(a.warnings)
    out.append(f"  findings:      {_count(errors, 'error')}, {_count(warnings, 'warning')}")
    out.extend(skipped_lines(a))
    for f in a.findings:
        out.append("")
        out.extend(format_finding(f, a.variables))
    return "\n".join(out)


def skipped_lines(a: Analysis) -> list[str]:
    """One line per reason the time budget skipped or cut analyses short, naming them."""
    by_why: dict[str, list[str]] = {}
    for name, why in a.skipped.items():
        by_why.setdefault(skip_text(why), []).append(name)
    return [f"  skipped:       {', '.join(ns)}: {why}" for why, ns in by_why.items()]


def format_example(ex: Example | None, what: str, variables: dict[str, VarInfo]) -> list[str]:
    if ex is None:
        return [f"  {what}: none within the analysed traces"]
    return [f"  {what}: {ex.note}", *format_trace(ex.trace, ex.verdicts, variables)]


def explain_lines(a: Analysis, rid: str) -> list[str]:
    """What ``explain`` adds per requirement: the analysis results that concern it
    and an example trace satisfying it and one violating it."""
    out = []
    found = a.concerning(rid)
    if found:
        for f in found:
            out.append(f"  analysis:  {LABEL[f.severity]} {f.kind}: {f.message}")
    elif not a.skipped:
        out.append(f"  analysis:  no findings (traces of {a.k} ticks)")
    sat, viol = a.examples(rid)
    if "examples" in a.skipped:
        out.append(f"  analysis:  skipped: {skip_text(a.skipped['examples'])}")
        return out
    out.extend(format_example(sat, "satisfied by", a.variables))
    out.extend(format_example(viol, "violated by", a.variables))
    return out
