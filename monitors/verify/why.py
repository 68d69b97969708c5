"""Why a formula has its value at a tick: the subformula tree with every value, and
the facts that decide it.

The reference interpreter (monitors/verify/interpret.py) gives every subformula's
value at every tick of a trace.  From the formula's value at the tick asked, the
reason is followed down: a false ``a & b`` because of its false side, a false
``a -> b`` because ``a`` held and ``b`` did not, a false ``H p`` because of the
tick where ``p`` failed, a true ``O p`` because of the tick where ``p`` held, and
so on down to the atoms, the comparisons and Boolean inputs, which become the
sentence ("OpState was 3 at tick 1042 while turnoffUVC was false";
docs/reference/commands.md, "report" and "logs --why").
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from monitors.ir.formula import (
    BOOL_OPS,
    REL_OPS,
    BinOp,
    Const,
    Formula,
    Not,
    Past,
    Since,
    Var,
    parse_formula,
    to_fret,
    variables,
)
from monitors.verify.interpret import Value, evaluate_all

Trace = Sequence[Mapping[str, Value]]
MAX_FACTS = 6  # a sentence names at most this many facts (the rest are counted)


@dataclass(frozen=True)
class WhyNode:
    text: str  # the subformula in FRET syntax
    values: tuple[Value, ...]  # its value at each tick of the trace
    children: tuple[WhyNode, ...]
    blame: bool  # part of the reason at the tick asked
    blame_ticks: tuple[int, ...] = ()  # the ticks at which it is part of the reason


@dataclass(frozen=True)
class _Fact:
    tick: int
    text: str
    timed: bool = False  # the text names its own ticks


def why_tree(formula: Formula, trace: Trace, tick: int) -> WhyNode:
    """``formula``'s tree over ``trace``, each node with its value at every tick and
    whether it is part of the reason for the formula's value at ``tick``."""
    table = evaluate_all(formula, trace)
    blamed: dict[Formula, set[int]] = {}
    _reason(formula, tick, table, blamed, [], 0)

    def build(g: Formula) -> WhyNode:
        ticks = tuple(sorted(blamed.get(g, ())))
        return WhyNode(
            to_fret(g),
            tuple(table[g]),
            tuple(build(c) for c in _shown_children(g)),
            bool(ticks),
            ticks,
        )

    return build(formula)


def explain(formula: Formula, trace: Trace, tick: int, first_tick: int = 0) -> str:
    """One sentence: why ``formula`` has its value at ``tick`` of ``trace``.  Ticks
    are printed as ``first_tick + index`` (the monitor's tick numbers)."""
    if not 0 <= tick < len(trace):
        raise ValueError(f"tick {tick} is outside the trace (0..{len(trace) - 1})")
    table = evaluate_all(formula, trace)
    facts: list[_Fact] = []
    _reason(formula, tick, table, {}, facts, first_tick)
    held = bool(table[formula][tick])
    verdict = "holds" if held else "is violated"
    if not facts:
        return f"the requirement {verdict} at tick {first_tick + tick} whatever the inputs"
    unique = list(dict.fromkeys(facts))
    unique.sort(key=lambda f: f.tick, reverse=True)
    shown = unique[:MAX_FACTS]
    parts = []
    for f in shown:
        when = "" if f.tick == tick or f.timed else f" at tick {first_tick + f.tick}"
        parts.append(f.text + when)
    more = f" (and {len(unique) - len(shown)} more)" if len(unique) > len(shown) else ""
    timed = shown[0].tick != tick or shown[0].timed
    head = parts[0] if timed else f"{parts[0]} at tick {first_tick + tick}"
    rest = parts[1:]
    sentence = head + (" while " + ", ".join(rest) if rest else "") + more
    return sentence


def formula_for_record(record: Mapping[str, object]) -> Formula:
    """A violation record's formula over inputs: ``formula_inputs`` where the daemon
    wrote it (the requirement reads internal variables), else ``formula``."""
    text = record.get("formula_inputs") or record.get("formula")
    if not isinstance(text, str):
        raise ValueError("the record has no formula")
    return parse_formula(text)


def trace_of_record(record: Mapping[str, object]) -> tuple[list[dict[str, Value]], int]:
    """The record's ``recent`` window as a trace (the violating tick last), and the
    monitor's tick number of its first row."""
    recent = record.get("recent")
    if not isinstance(recent, list) or not recent:
        raise ValueError("the record has no recent ticks")
    rows = [{k: v for k, v in r.items() if k != "tick"} for r in recent if isinstance(r, dict)]
    first = recent[0].get("tick", 0) if isinstance(recent[0], dict) else 0
    return rows, int(first) if isinstance(first, int) else 0


def missing_inputs(formula: Formula, trace: Trace) -> list[str]:
    """Variables of ``formula`` the trace does not give."""
    have = set(trace[0]) if trace else set()
    return [n for n in variables(formula) if n not in have]


# ---------------------------------------------------------------- the reason


def _shown_children(g: Formula) -> tuple[Formula, ...]:
    """Children shown in the tree: comparisons are leaves (their operands are
    numbers, shown in the comparison's text)."""
    if isinstance(g, BinOp) and g.op not in BOOL_OPS:
        return ()
    return g.children()


def _atom(g: Formula) -> bool:
    return isinstance(g, Var | Const) or (isinstance(g, BinOp) and g.op not in BOOL_OPS)


def _reason(
    g: Formula,
    i: int,
    t: Mapping[Formula, list[Value]],
    blamed: dict[Formula, set[int]],
    facts: list[_Fact],
    base: int,
) -> None:
    """Mark why ``g`` has its value at tick ``i``; facts collect the atoms (their
    texts count ticks from ``base``)."""
    seen = blamed.setdefault(g, set())
    if i in seen:
        return
    seen.add(i)
    v = bool(t[g][i])
    if _atom(g):
        if not isinstance(g, Const):
            facts.append(_Fact(i, _describe(g, i, t)))
        return
    match g:
        case Not(a):
            _reason(a, i, t, blamed, facts, base)
        case BinOp(op, a, b):
            x, y = bool(t[a][i]), bool(t[b][i])
            if op == "&":
                sides = [a, b] if v else [s for s, w in ((a, x), (b, y)) if not w][:1]
            elif op == "|":
                sides = [s for s, w in ((a, x), (b, y)) if w][:1] if v else [a, b]
            elif op == "->":
                sides = [a, b] if not v else ([a] if not x else [b])
            else:  # xor, <->: both sides decide
                sides = [a, b]
            for s in sides:
                _reason(s, i, t, blamed, facts, base)
        case Past(op, a, lo, hi) if op in ("Y", "Z"):
            if i > 0:
                _reason(a, i - 1, t, blamed, facts, base)
            else:
                facts.append(_Fact(i, "there was no earlier tick"))
        case Past(op, a, lo, hi):
            window = _window(i, lo, hi)
            xs = t[a]
            want = op == "O"  # O: a tick where a held decides; H: one where it failed
            hits = [j for j in reversed(window) if bool(xs[j]) == want]
            if hits and v == want:
                _reason(a, hits[0], t, blamed, facts, base)
            elif window:
                word = "held at every tick" if op == "H" else "held at no tick"
                span = f"from {base + window[0]} to {base + window[-1]}"
                facts.append(_Fact(i, f"{to_fret(a)} {word} {span}", timed=True))
                for j in window:  # every tick decides: marked, one fact says it
                    _reason(a, j, t, blamed, [], base)
            else:
                facts.append(_Fact(i, f"{to_fret(g)} has no tick in its window yet"))
        case Since():
            _since_reason(g, i, t, blamed, facts, base)


def _since_reason(
    g: Since,
    i: int,
    t: Mapping[Formula, list[Value]],
    blamed: dict[Formula, set[int]],
    facts: list[_Fact],
    base: int,
) -> None:
    """``a S b`` holds because of the latest tick where ``b`` held with ``a`` since;
    ``a T b`` fails because of the latest tick where ``b`` failed with ``a`` failing
    since.  The other values are summarised."""
    a, b = g.left, g.right
    decisive = bool(t[g][i]) == (g.op == "S")
    want_b = g.op == "S"
    if decisive:
        for j in reversed(_window(i, g.lo, g.hi)):
            if bool(t[b][j]) == want_b and all(
                bool(t[a][k]) == want_b for k in range(j + 1, i + 1)
            ):
                _reason(b, j, t, blamed, facts, base)
                if j < i:
                    word = "held" if want_b else "failed"
                    span = f"from tick {base + j + 1} to {base + i}"
                    facts.append(_Fact(i, f"{to_fret(a)} {word} at every tick {span}", timed=True))
                    for k in range(j + 1, i + 1):
                        _reason(a, k, t, blamed, [], base)
                return
    window = _window(i, g.lo, g.hi)
    if g.op == "S" and window and (g.lo or 0) == 0:
        # a S b fails: b never held in the window, or a failed after its last b
        held = [j for j in reversed(window) if bool(t[b][j])]
        broke = None
        if held:
            broke = next((k for k in range(i, held[0], -1) if not bool(t[a][k])), None)
        if broke is not None:
            # b held last at held[0], a failed after it; b not since then
            _reason(a, broke, t, blamed, facts, base)
            for j in range(broke, i + 1):
                _reason(b, j, t, blamed, [], base)
            return
        if not held:
            span = f"from {base + window[0]} to {base + window[-1]}"
            facts.append(_Fact(i, f"{to_fret(b)} held at no tick {span}", timed=True))
            for j in window:
                _reason(b, j, t, blamed, [], base)
            return
    word = "since" if g.op == "S" else "trigger"
    facts.append(_Fact(i, f"{to_fret(g)} ({word}) was {str(bool(t[g][i])).lower()}"))
    # summarised: b in the window and a after any of its ticks may decide
    for j in range(0 if g.hi is None else max(0, i - g.hi), i + 1):
        _reason(a, j, t, blamed, [], base)
        _reason(b, j, t, blamed, [], base)


def _window(i: int, lo: int | None, hi: int | None) -> list[int]:
    first = 0 if hi is None else max(0, i - hi)
    return list(range(first, i - (lo or 0) + 1))


def _describe(g: Formula, i: int, t: Mapping[Formula, list[Value]]) -> str:
    """An atom at tick ``i`` in words."""
    v = t[g][i]
    if isinstance(g, Var):
        return f"{g.name} was {_value(v)}"
    assert isinstance(g, BinOp) and g.op in REL_OPS
    left, right = g.left, g.right
    if isinstance(left, Var) and isinstance(right, Const) and g.op == "=":
        if v:
            return f"{left.name} was {_value(t[left][i])}"
        return f"{left.name} was {_value(t[left][i])}, not {_value(right.value)}"
    values = [f"{n} = {_value(t[Var(n)][i])}" for n in variables(g) if Var(n) in t]
    state = "held" if v else "did not hold"
    return f"{to_fret(g)} {state}" + (f" ({', '.join(values)})" if values else "")


def _value(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)
