"""The formalizer against FRET 3.0's own past-time formulas, and its monotonicity flags.

Equality is semantic: both formulas are evaluated with the reference
interpreter on random traces and must agree at every tick.
"""

from __future__ import annotations

import json
import random
import re
from fractions import Fraction
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from monitors.errors import UserError
from monitors.frontend.formalize import describe, formalize, ticks
from monitors.frontend.parse import Duration, parse_requirement
from monitors.ir.formula import (
    ARITH_OPS,
    REL_OPS,
    BinOp,
    Const,
    Formula,
    Neg,
    Not,
    Past,
    Since,
    Var,
    max_bound,
    parse_formula,
    subterms,
    to_fret,
    variables,
)
from monitors.verify.interpret import verdicts

EXAMPLES = Path(__file__).resolve().parents[2] / "data" / "fret-examples.jsonl"
ALL = [json.loads(line) for line in EXAMPLES.read_text().splitlines() if line.strip()]
# FRET's formula for 1.5 seconds has malformed bounds; negative durations and
# probability bounds we refuse (tests/monitors/frontend/test_parse.py).
NOT_COMPARED = {"unit_after_1.5_seconds", "err_negative_duration", "var_probability2"}
OK = [d for d in ALL if d["ok"] and d["id"] not in NOT_COMPARED]
UNIT_PERIOD = {  # one unit per tick, so our tick counts equal FRET's numbers
    "tick": None,
    "hour": 3_600_000.0,
    "minute": 60_000.0,
    "second": 1000.0,
    "millisecond": 1.0,
    "microsecond": 0.001,
}


# ---------------------------------------------------------------- traces


def rename(f: Formula, fn) -> Formula:
    match f:
        case Var(n):
            return Var(fn(n))
        case Not(a):
            return Not(rename(a, fn))
        case Neg(a):
            return Neg(rename(a, fn))
        case BinOp(op, a, b):
            return BinOp(op, rename(a, fn), rename(b, fn))
        case Past(op, a, lo, hi):
            return Past(op, rename(a, fn), lo, hi)
        case Since(op, a, b, lo, hi):
            return Since(op, rename(a, fn), rename(b, fn), lo, hi)
    return f


def fret_pt(pt: str) -> Formula:
    """FRET's formula with its renamed identifiers mapped back (robot_DOT_speed)."""
    return rename(parse_formula(pt), lambda n: n.replace("_DOT_", "."))


def _numeric_vars(fs: list[Formula]) -> set[str]:
    out: set[str] = set()
    for f in fs:
        for g in subterms(f):
            if isinstance(g, BinOp) and g.op in REL_OPS + ARITH_OPS:
                out |= {c.name for c in (g.left, g.right) if isinstance(c, Var)}
            if isinstance(g, Neg) and isinstance(g.arg, Var):
                out.add(g.arg.name)
    return out


def _domain(fs: list[Formula]) -> tuple[list[int | float], list[int | float]]:
    """Small ints, and values around every numeric literal (so relations flip)."""
    near: set[int | float] = set()
    for f in fs:
        for g in subterms(f):
            if isinstance(g, Const) and not isinstance(g.value, bool):
                c = g.value
                step = 1 if isinstance(c, int) else 0.5
                near |= {c - step, c, c + step}
    return sorted(set(range(-2, 13)) | near), sorted(near) or list(range(-2, 13))


def random_traces(
    *fs: Formula,
    n: int,
    rng: random.Random,
    max_len: int = 40,
    min_len: int = 1,
    stays: tuple[float, ...] = (0.0, 0.5, 0.8, 0.95, 1.0),
) -> list[list[dict]]:
    names = sorted({g.name for f in fs for g in subterms(f) if isinstance(g, Var)})
    numeric = _numeric_vars(list(fs))
    dom, near = _domain(list(fs))
    out = []
    for _ in range(n):
        length = rng.randint(min_len, max_len)
        cols = {}
        for v in names:
            # Per trace and variable: how often it is true and how sticky it is,
            # so that modes and conditions open and close in runs.
            stay = rng.choice(stays)
            if v in numeric:
                src = near if rng.random() < 0.7 else dom
                pool = rng.sample(src, k=min(len(src), rng.choice((2, 3, 6))))
                draw = lambda pool=pool: rng.choice(pool)  # noqa: E731
            else:
                p = rng.choice((0.05, 0.2, 0.5, 0.8, 0.95))
                draw = lambda p=p: rng.random() < p  # noqa: E731
            col = [draw()]
            for _ in range(length - 1):
                col.append(col[-1] if rng.random() < stay else draw())
            cols[v] = col
        out.append([{v: cols[v][i] for v in names} for i in range(length)])
    return out


def period_for(req) -> float | None:
    return UNIT_PERIOD[req.timing.duration.unit] if req.timing.duration else None


# ---------------------------------------------------------------- FRET's examples


def example_traces(ex: dict, *fs: Formula) -> list[list[dict]]:
    """200 traces, mostly short (fast); when a time bound is longer than that,
    some traces are long enough for the bound to matter."""
    rng = random.Random(ex["id"])
    bound = max(max_bound(f) for f in fs)
    if bound <= 20:
        return random_traces(*fs, n=200, rng=rng, max_len=25)
    short = random_traces(*fs, n=180, rng=rng, max_len=25)
    # Long and nearly constant, so an obligation can stay unmet for the whole bound.
    long = random_traces(
        *fs, n=20, rng=rng, min_len=bound, max_len=bound + 12, stays=(0.99, 1.0, 1.0)
    )
    return short + long


# Examples FRET's formula cannot be violated on: `upon false` never triggers.
VALID = {"expr_cond_18"}


@pytest.mark.slow
@pytest.mark.parametrize("ex", OK, ids=[d["id"] for d in OK])
def test_agrees_with_fret(ex):
    req = parse_requirement(ex["fretish"])
    ours = formalize(req, period_ms=period_for(req)).formula
    theirs = fret_pt(ex["pt"])
    traces = example_traces(ex, ours, theirs)
    # One evaluation of `ours <-> theirs` shares the common subformulas.
    both = BinOp("<->", ours, theirs)
    for trace in traces:
        if not all(verdicts(both, trace)):
            a, b = verdicts(ours, trace), verdicts(theirs, trace)
            pytest.fail(f"{ex['id']}: ours {a} FRET {b} on {trace}\nours: {ours}")
    # The traces must be able to tell formulas apart: FRET's is violated on some.
    violated = sum(not all(verdicts(theirs, t)) for t in traces[:60] + traces[180:])
    assert violated > 0 or ex["id"] in VALID, "traces never violate FRET's formula"


def test_fractional_seconds_need_a_matching_period():
    req = parse_requirement("upon trigger sw shall after 1.5 seconds satisfy resp")
    fret_like = "((H ((O[0,3] (trigger & (Z (! trigger)))) -> ((H (! trigger)) | (! resp)))) & (H ((O[4,4] ((trigger & (Z (! trigger))) & (! resp))) -> (O[0,3] ((Z FALSE) | resp)))))"
    ours = formalize(req, period_ms=500).formula
    both = BinOp("<->", ours, parse_formula(fret_like))
    for trace in random_traces(ours, n=100, rng=random.Random(1)):
        assert all(verdicts(both, trace))
    with pytest.raises(UserError) as e:
        formalize(req, period_ms=400, file="reqs.yaml", line=12)
    assert str(e.value).startswith("reqs.yaml:12: ")
    suggested = re.findall(r"(\d+(?:\.\d+)?) ms", e.value.hint or "")
    assert suggested, e.value.hint
    for p in suggested:  # every period named in the hint really works
        assert ticks(req.timing.duration, float(p)) * float(p) == 1500


def test_units_convert_with_the_period():
    assert ticks(Duration(Fraction(2), "second"), 100) == 20
    assert ticks(Duration(Fraction(250), "microsecond"), 0.05) == 5
    assert ticks(Duration(Fraction(1), "minute"), 10) == 6000
    assert ticks(Duration(Fraction(7), "tick"), None) == 7
    req = parse_requirement("upon p sw shall within 2 seconds satisfy q")
    f20 = formalize(req, period_ms=100).formula
    assert "O[20,20]" in str(f20) and "O[0,19]" in str(f20)


def test_units_without_a_period_are_an_error():
    req = parse_requirement("sw shall within 2 seconds satisfy q")
    with pytest.raises(UserError, match="needs the tick length") as e:
        formalize(req, file="c.yaml", line=3)
    assert e.value.hint and "period_ms" in e.value.hint
    formalize(parse_requirement("sw shall within 2 ticks satisfy q"))  # ticks need no period


def test_within_zero_ticks_is_fret_s_formula():
    req = parse_requirement("upon trigger sw shall within 0 ticks satisfy resp")
    ours = formalize(req).formula
    both = BinOp(
        "<->", ours, parse_formula(next(d for d in ALL if d["id"] == "unit_within_0_ticks")["pt"])
    )
    for trace in random_traces(ours, n=100, rng=random.Random(0)):
        assert all(verdicts(both, trace))


# FRET's SemanticsAnalyzer joins the qualifiers left to right, one at a time:
# `(previous | next)` after 'or', `(previous & next)` otherwise, each negated when
# it is 'unless' or 'is false' (but not both).  FRET's formula for a regular
# condition C with 'within 3 ticks' (unit_within_3_ticks) with C put in.
FRET_CONDITIONS = [
    ("when a or when b and when c", "((a | b) & c)"),
    ("when a and when b or when c", "((a & b) | c)"),
    ("upon a or if b, unless c", "((a | b) & (! c))"),
    ("when a, or when b is FALSE, and when c", "((a | (! b)) & c)"),
    ("unless a is false or when b and when c or upon d", "(((a | b) & c) | d)"),
    ("and when a or when b & c", "(a | (b & c))"),
]


@pytest.mark.parametrize("cond,fret", FRET_CONDITIONS)
def test_conditions_combine_left_to_right_like_fret(cond, fret):
    req = parse_requirement(f"{cond} sw shall within 3 ticks satisfy r")
    ours = formalize(req).formula
    c = fret
    theirs = parse_formula(
        f"(H ((O[3,3] (({c} & (Z (! {c}))) & (! r))) -> (O[0,2] ((Z FALSE) | r))))"
    )
    both = BinOp("<->", ours, theirs)
    traces = random_traces(ours, theirs, n=300, rng=random.Random(cond))
    for trace in traces:
        assert all(verdicts(both, trace)), (cond, trace)
    assert any(not all(verdicts(theirs, t)) for t in traces)


# FRET's persisted and occurred count only ticks since the start of the scope's
# interval: its templates say $Left$, filled with the scope's SMVptExtleft from
# FRET's semantics.json; in the scope's mode they have no such bound (FRET's
# "NoBounds" forms).  Each case puts a function into one of FRET's examples, in
# the sentence and, expanded as FRET expands it, in FRET's formula.
IN_CRUISE = "(cruise & ((! (Y TRUE)) | (Y (! cruise))))"
AFTER_TAKEOFF = "(((! takeoff) & (Y takeoff)) & (Y (H (! ((! takeoff) & (Y takeoff))))))"
NOT_IN_CRUISE = "((! cruise) & ((! (Y TRUE)) | (Y cruise)))"
SCOPED_FUNCTIONS = [
    ("var_commas", "p", "persisted(3, hot)", f"((H[0,3] hot) & (H[0,2] (! {IN_CRUISE})))"),
    ("var_commas", "q", "occurred(1, 3, f)", f"((! {IN_CRUISE}) S[1,3] f)"),
    (
        "grid_160_after_regular_always",
        "emergency",
        "occurred(2, f)",
        f"(((! {AFTER_TAKEOFF}) S f) & (O[0,2] f))",
    ),
    (
        "grid_120_onlyIn_regular_immediately",
        "q",
        "persisted(2, hot)",
        f"((H[0,2] hot) & (H[0,1] (! {NOT_IN_CRUISE})))",
    ),
    ("grid_042_in_null_within", "landing", "persisted(2, hot)", "(H[0,2] hot)"),
]


@pytest.mark.parametrize("ex_id,word,call,fret", SCOPED_FUNCTIONS)
def test_functions_count_from_the_scope_start_like_fret(ex_id, word, call, fret):
    ex = next(d for d in ALL if d["id"] == ex_id)
    text = re.sub(rf"\b{word}\b", call, ex["fretish"])
    if word == "landing":  # FRET takes a mode name after 'during', an expression after 'while'
        text = text.replace("during", "while")
    ours = formalize(parse_requirement(text)).formula
    theirs = fret_pt(re.sub(rf"\b{word}\b", fret, ex["pt"]))
    both = BinOp("<->", ours, theirs)
    traces = random_traces(ours, theirs, n=300, rng=random.Random(ex_id + word), max_len=30)
    for trace in traces:
        assert all(verdicts(both, trace)), (text, trace)
    assert any(not all(verdicts(theirs, t)) for t in traces)


def fret_prev_occ(left: str, p: str, q: str) -> str:
    """FRET's prevOcc(p, q) template (xform.js, pastTemporalConditions), written out."""
    quiet = f"((! {left}) & (! {p}))"
    return f"({left} | (Y (({quiet} S {p}) -> ({quiet} S ({p} & {q})))))"


def fret_prev_occ_in_mode(p: str, q: str) -> str:
    """Its unbounded form, used in the scope's mode (pastTemporalConditionsNoBounds)."""
    return f"(Y ((! {p}) S ({p} & {q})))"


PREV = "at the previous occurrence of a, b"
# (example, word replaced, its replacement in the sentence, FRET's formula for it)
PREVIOUS_OCCURRENCES = [
    ("var_commas", "q", PREV, fret_prev_occ(IN_CRUISE, "a", "b")),
    ("var_commas", "q", "prevOcc(a, b)", fret_prev_occ(IN_CRUISE, "a", "b")),
    ("grid_160_after_regular_always", "emergency", PREV, fret_prev_occ(AFTER_TAKEOFF, "a", "b")),
    ("grid_120_onlyIn_regular_immediately", "q", PREV, fret_prev_occ(NOT_IN_CRUISE, "a", "b")),
    ("grid_120_onlyIn_regular_immediately", "q", f"({PREV}) & c", None),
    ("grid_042_in_null_within", "landing", PREV, fret_prev_occ_in_mode("a", "b")),
    # No scope: FRET's $Left$ is the first tick, (! (Y TRUE)).
    ("var_period", "q", PREV, fret_prev_occ("(! (Y TRUE))", "a", "b")),
]


@pytest.mark.parametrize("ex_id,word,text_for,fret", PREVIOUS_OCCURRENCES)
def test_previous_occurrence_like_fret(ex_id, word, text_for, fret):
    ex = next(d for d in ALL if d["id"] == ex_id)
    if fret is None:  # an operand in parentheses, the rest of the response beside it
        fret = f"({fret_prev_occ(NOT_IN_CRUISE, 'a', 'b')} & c)"
    text = re.sub(rf"\b{word}\b", text_for, ex["fretish"])
    if word == "landing":  # FRET takes a mode name after 'during', an expression after 'while'
        text = text.replace("during", "while")
    ours = formalize(parse_requirement(text)).formula
    theirs = fret_pt(re.sub(rf"\b{word}\b", fret, ex["pt"]))
    both = BinOp("<->", ours, theirs)
    traces = random_traces(ours, theirs, n=300, rng=random.Random(ex_id + text_for), max_len=30)
    for trace in traces:
        assert all(verdicts(both, trace)), (text, trace)
    assert any(not all(verdicts(theirs, t)) for t in traces)


@pytest.mark.parametrize(
    "ex_id,word,wrong",
    [
        # Counting from the trace's start instead of the scope's (no $Left$).
        ("var_commas", "q", fret_prev_occ("FALSE", "a", "b")),
        # In the mode, the bounded template without a start is not FRET's form.
        ("grid_042_in_null_within", "landing", fret_prev_occ("FALSE", "a", "b")),
    ],
)
def test_previous_occurrence_needs_the_scope_start(ex_id, word, wrong):
    # Neither shortcut is FRET's formula: the random traces tell them apart.
    ex = next(d for d in ALL if d["id"] == ex_id)
    text = re.sub(rf"\b{word}\b", PREV, ex["fretish"]).replace("during", "while")
    ours = formalize(parse_requirement(text)).formula
    other = fret_pt(re.sub(rf"\b{word}\b", wrong, ex["pt"]))
    both = BinOp("<->", ours, other)
    traces = random_traces(ours, other, n=300, rng=random.Random(ex_id), max_len=30)
    assert any(not all(verdicts(both, t)) for t in traces)


# FRET's formulas, printed by FRET, for the forms real projects write: persisted and
# occurred with three arguments, abs/min/max in a sentence, a comma after the response
# (tests/data/fret/README.md says how they were made and which sentence FRET was given).
FORMS = [
    json.loads(line)
    for line in (EXAMPLES.parent / "fret" / "forms.jsonl").read_text().splitlines()
    if line.strip()
]


@pytest.mark.parametrize("ex", FORMS, ids=[d["id"] for d in FORMS])
def test_forms_real_projects_write_agree_with_fret(ex):
    ours = formalize(parse_requirement(ex["fretish"])).formula
    theirs = fret_pt(ex["pt"])
    both = BinOp("<->", ours, theirs)
    traces = random_traces(ours, theirs, n=200, rng=random.Random(ex["id"]), max_len=25)
    for trace in traces:
        if not all(verdicts(both, trace)):
            a, b = verdicts(ours, trace), verdicts(theirs, trace)
            pytest.fail(f"{ex['id']}: ours {a} FRET {b} on {trace}\nours: {ours}")
    assert any(not all(verdicts(theirs, t)) for t in traces), "traces never violate FRET's"


def test_forms_cover_every_scope_and_the_edge_windows():
    # The table above is worth what it covers: each scope for both functions, and
    # the windows whose ends are the edge ticks.
    ids = {d["id"] for d in FORMS}
    for scope in SCOPES:
        assert {f"persisted3_{scope}_resp", f"occurred3_{scope}_resp"} <= ids, scope
    for m, n in [(0, 0), (0, 2), (2, 2), (1, 1), (3, 5)]:
        assert {f"persisted3_edge_{m}_{n}", f"occurred3_edge_{m}_{n}_null"} <= ids
    assert {"abs_roll_hold_AP-003B", "abs_eb", "min_max_cond", "trailing_comma"} <= ids


# ---------------------------------------------------------------- the whole grid

SCOPES = {
    "null": "",
    "in": "in mode m ",
    "notin": "when not in m ",
    "onlyIn": "only in m mode ",
    "after": "after m ",
    "before": "before m ",
    "onlyAfter": "only after m ",
    "onlyBefore": "only before mode m ",
}
CONDS = {"none": "", "regular": "upon c ", "holding": "whenever c "}
TIMINGS = {
    "immediately": "immediately ",
    "next": "at the next timepoint ",
    "eventually": "eventually ",
    "always": "always ",
    "never": "never ",
    "within": "within 2 ticks ",
    "for": "for 2 ticks ",
    "after": "after 1 tick ",
    "until": "until s ",
    "before": "before s ",
    "finally": "finally ",
    "null": "",
}
GRID = [(s, c, t) for s in SCOPES for c in CONDS for t in TIMINGS]


def grid_req(s: str, c: str, t: str):
    return parse_requirement(f"{SCOPES[s]}{CONDS[c]}sw shall {TIMINGS[t]}satisfy p")


@pytest.mark.parametrize("combo", GRID, ids=["-".join(g) for g in GRID])
def test_grid_parses_and_formalizes(combo):
    s, c, t = combo
    req = grid_req(s, c, t)
    assert (req.scope.kind if req.scope else "null") == s
    assert (req.condition.kind if req.condition else "none") == c
    assert req.timing.kind == t
    f = formalize(req)
    assert f.monotone == (f.note is None)
    assert describe(req)


def _goes_false_then_true(v: list[bool]) -> bool:
    return any(not v[i] and v[j] for i in range(len(v)) for j in range(i + 1, len(v)))


bits = st.lists(st.booleans(), min_size=1, max_size=12)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.sampled_from([g for g in GRID if formalize(grid_req(*g)).monotone]),
    st.lists(st.tuples(*[st.booleans()] * 4), min_size=1, max_size=14),
)
def test_monotone_once_false_stays_false(combo, rows):
    f = formalize(grid_req(*combo)).formula
    trace = [dict(zip("mcsp", r, strict=True)) for r in rows]
    v = verdicts(f, trace)
    assert not _goes_false_then_true(v), (combo, trace, v)


NON_MONOTONE = [g for g in GRID if not formalize(grid_req(*g)).monotone]


@pytest.mark.slow
@pytest.mark.parametrize("combo", NON_MONOTONE, ids=["-".join(g) for g in NON_MONOTONE])
def test_non_monotone_has_a_false_then_true_trace(combo):
    fz = formalize(grid_req(*combo))
    assert fz.note and fz.note.startswith("non-monotone")
    rng = random.Random(str(combo))
    for trace in random_traces(fz.formula, n=3000, rng=rng, max_len=10):
        if _goes_false_then_true(verdicts(fz.formula, trace)):
            return
    pytest.fail(f"no trace shows {combo} going false then true")


def test_non_monotone_kinds():
    flags = {g: formalize(grid_req(*g)).monotone for g in GRID}
    for s in SCOPES:
        for c in CONDS:
            # "only" scopes negate the timing: eventually/none become "always not"
            # and always/never become "eventually"
            only = s.startswith("only")
            assert flags[(s, c, "eventually")] == only
            assert flags[(s, c, "null")] == only
            assert flags[(s, c, "always")] == flags[(s, c, "never")] == (not only)
            assert not flags[(s, c, "finally")]
            assert flags[(s, c, "within")] and flags[(s, c, "until")]
    for s in ("onlyIn", "onlyAfter", "onlyBefore"):
        assert not flags[(s, "regular", "always")] and not flags[(s, "holding", "never")]


# ---------------------------------------------------------------- describe


def test_describe_mentions_ticks_and_units():
    req = parse_requirement("in mode cruise upon p the sw shall within 2 seconds satisfy q")
    text = describe(req, period_ms=100)
    assert "20 ticks" in text and "2 seconds" in text and "cruise" in text and "p" in text
    assert "becomes true" in text
    held = describe(parse_requirement("whenever p sw shall always satisfy q"))
    assert "every tick at which p holds" in held
    # FRET's $Left$ is named; in the mode itself the functions have no such bound.
    req = parse_requirement("while persisted(2, h) sw shall always satisfy occurred(3, f)")
    text = describe(req)
    assert "(H[0,2] h) holds" in text and "(! interval_start) S[0,3] f" in text


MONOTONE = [g for g in GRID if formalize(grid_req(*g)).monotone]


@pytest.mark.slow
@pytest.mark.parametrize("combo", MONOTONE, ids=["-".join(g) for g in MONOTONE])
def test_monotone_sweep(combo):
    """Every combination flagged monotone, on sticky random traces that open
    and close the scope and trigger the condition (hypothesis above samples)."""
    f = formalize(grid_req(*combo)).formula
    for trace in random_traces(f, n=60, rng=random.Random(str(combo)), max_len=14):
        v = verdicts(f, trace)
        assert not _goes_false_then_true(v), (combo, trace, v)


def test_describe_shows_the_previous_occurrence_as_fret_writes_it():
    text = describe(parse_requirement(f"in m upon {PREV} sw shall always satisfy r"))
    assert "(interval_start | (Y ((((! interval_start) & (! a)) S a) ->" in text
    assert "TRUE" not in text
    # In the mode itself: FRET's unbounded form.
    text = describe(parse_requirement(f"while {PREV} sw shall always satisfy r"))
    assert "in which (Y ((! a) S (a & b))) holds" in text


# Quoted names and keyword-like ones (docs/reference/fretish.md, "Names"): the
# sentence keeps the user's name, formula text spells it as FRET does.
QUOTED = {"flight mode": "fm", "T": "t1", "left wheel": "lw", "MODE": "m1"}


def test_quoted_names_formalize_like_plain_ones():
    quoted = (
        'in "flight mode" mode, when "T" & "left wheel" > 3, '
        'sw shall within 2 ticks satisfy !"MODE"'
    )
    plain = "in fm mode, when t1 & lw > 3, sw shall within 2 ticks satisfy !m1"
    ours = formalize(parse_requirement(quoted)).formula
    back = {v: k for k, v in QUOTED.items()}
    same = rename(formalize(parse_requirement(plain)).formula, lambda n: back.get(n, n))
    text = to_fret(ours)
    assert "_DQT_left_SPC_wheel_DQT_" in text and "_DQT_T_DQT_" in text
    assert "_DQT_flight_SPC_mode_DQT_" in text and "_DQT_MODE_DQT_" in text
    assert parse_formula(text) == ours  # the formula text reads back as the same names
    assert set(variables(ours)) == set(QUOTED)
    both = BinOp("<->", ours, same)
    traces = random_traces(ours, same, n=300, rng=random.Random(7), max_len=25)
    for trace in traces:
        assert all(verdicts(both, trace)), trace
    assert any(not all(verdicts(ours, t)) for t in traces)
