"""FRETISH parser: every phrasing, FRET's error examples, error positions."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from fractions import Fraction
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from monitors.errors import UserError
from monitors.frontend.formalize import formalize
from monitors.frontend.parse import BOUNDED, INTERVAL_START, Duration, parse_requirement
from monitors.ir.formula import (
    FTP,
    MAX_DEPTH,
    BinOp,
    Call,
    Const,
    FormulaSyntaxError,
    Neg,
    Not,
    Past,
    Pre,
    Since,
    Var,
    depth,
    parse_formula,
    subterms,
)

EXAMPLES = Path(__file__).resolve().parents[2] / "data" / "fret-examples.jsonl"
ALL = [json.loads(line) for line in EXAMPLES.read_text().splitlines() if line.strip()]
# FRET rejects these; we accept them on purpose (see monitors/parse.py's docstring).
EXTENSIONS = {"condform_always_00", "condform_always_03", "condform_11"}
# FRET refuses abs, min and max in a sentence (NuSMV keywords); we accept them
# (docs/reference/fretish.md, "Deliberate differences from FRET").
ACCEPTED_FUNCTIONS = {"expr_cond_15"}
ERRORS = [d for d in ALL if not d["ok"] and d["id"] not in EXTENSIONS | ACCEPTED_FUNCTIONS]
LOCATED = re.compile(r"^<input>:1:\d+: \S.*$")


def P(text: str, **kw):  # noqa: N802
    return parse_requirement(text, **kw)


def err(text: str, **kw) -> UserError:
    with pytest.raises(UserError) as e:
        parse_requirement(text, **kw)
    return e.value


# ---------------------------------------------------------------- FRET's examples


# Accepted by FRET, refused by us on purpose (tests below): a negative duration,
# and a probability bound, which a monitor of one run cannot judge.
REFUSED = {"err_negative_duration", "var_probability2"}


@pytest.mark.parametrize(
    "ex", [d for d in ALL if d["ok"] and d["id"] not in REFUSED], ids=lambda d: d["id"]
)
def test_every_fret_ok_example_parses(ex):
    req = P(ex["fretish"])
    assert req.scope is None or req.scope.kind == ex["scope_type"]
    assert (req.condition.kind if req.condition else "null") == ex["condition"]
    assert req.timing.kind == ex["timing"]


@pytest.mark.parametrize("ex", ERRORS, ids=lambda d: d["id"])
def test_every_fret_error_example_is_rejected_in_one_line(ex):
    e = err(ex["fretish"])
    text = str(e)
    assert "\n" not in text and "Traceback" not in text
    assert LOCATED.match(text), text


def test_negative_duration_is_rejected():
    e = err("sw shall within -3 ticks satisfy q")
    assert "negative duration" in e.message and e.col == 17


@pytest.mark.parametrize("id_", sorted(EXTENSIONS))
def test_documented_extension_lowercase_is_true_false(id_):
    ex = next(d for d in ALL if d["id"] == id_)
    req = P(ex["fretish"])
    expr = req.condition.expr
    # `upon p is true` is p; `unless p is false` is p; `whenever a is false` is !a
    assert expr in (Var("p"), Not(Var("a")))


# ---------------------------------------------------------------- scopes

SCOPE_PHRASES = [
    ("in M", "in"),
    ("in mode M", "in"),
    ("in M mode", "in"),
    ("during M", "in"),
    ("when in M", "in"),
    ("if in M", "in"),
    ("when in mode M", "in"),
    ("not in M", "notin"),
    ("unless in M", "notin"),
    ("except in M", "notin"),
    ("except during M", "notin"),
    ("except if in M", "notin"),
    ("except when in mode M", "notin"),
    ("when not in M", "notin"),
    ("if not in M mode", "notin"),
    ("only in M", "onlyIn"),
    ("only during M", "onlyIn"),
    ("only if in M", "onlyIn"),
    ("only when in mode M", "onlyIn"),
    ("after M", "after"),
    ("after mode M", "after"),
    ("before M", "before"),
    ("before M mode", "before"),
    ("only after M", "onlyAfter"),
    ("only before mode M", "onlyBefore"),
    ("In Mode M,", "in"),
]


@pytest.mark.parametrize(("phrase", "kind"), SCOPE_PHRASES)
def test_scope_phrases(phrase, kind):
    req = P(f"{phrase} sw shall always satisfy q")
    assert req.scope is not None and req.scope.kind == kind
    assert req.scope.mode == Var("M")


@pytest.mark.parametrize(
    ("phrase", "kind"), [("while", "in"), ("except while", "notin"), ("only while", "onlyIn")]
)
def test_while_takes_a_condition(phrase, kind):
    req = P(f"{phrase} speed > 2 & armed sw shall always satisfy q")
    assert req.scope.kind == kind
    assert req.scope.mode == BinOp("&", BinOp(">", Var("speed"), Const(2)), Var("armed"))


@pytest.mark.parametrize("mode", ["beforehand", "hereafter", "afterglow", "onlyone", "inmode"])
def test_mode_names_containing_scope_words(mode):
    req = P(f"in mode {mode} sw shall always satisfy q")
    assert req.scope.kind == "in" and req.scope.mode == Var(mode)
    req = P(f"after {mode} sw shall always satisfy q")
    assert req.scope.kind == "after" and req.scope.mode == Var(mode)


# ---------------------------------------------------------------- conditions


def test_regular_and_holding():
    assert P("upon p sw shall always satisfy q").condition.kind == "regular"
    for w in ("when", "if", "where", "upon"):
        c = P(f"{w} p sw shall always satisfy q").condition
        assert c.kind == "regular" and c.expr == Var("p")
    c = P("whenever p sw shall always satisfy q").condition
    assert c.kind == "holding" and c.expr == Var("p")
    c = P("unless p sw shall always satisfy q").condition
    assert c.kind == "regular" and c.expr == Not(Var("p"))


def test_qualifiers_combine():
    c = P("In mode cruise, upon p, the sw shall, within 2 ticks, satisfy q").condition
    assert c.expr == Var("p")
    c = P("upon a or when b sw shall always satisfy q").condition
    assert c.expr == BinOp("|", Var("a"), Var("b")) and c.kind == "regular"
    c = P("when a, if b sw shall always satisfy q").condition
    assert c.expr == BinOp("&", Var("a"), Var("b"))
    c = P("whenever a and when b sw shall always satisfy q").condition
    assert c.kind == "regular" and c.expr == BinOp("&", Var("a"), Var("b"))
    c = P("whenever a or whenever b sw shall always satisfy q").condition
    assert c.kind == "holding"
    c = P("when a and when b or when c sw shall always satisfy q").condition
    assert c.expr == BinOp("|", BinOp("&", Var("a"), Var("b")), Var("c"))
    # Left to right like FRET, not 'and' before 'or' (semantics: test_formalize).
    c = P("when a or when b and when c sw shall always satisfy q").condition
    assert c.expr == BinOp("&", BinOp("|", Var("a"), Var("b")), Var("c"))
    c = P("when a or if b, unless c sw shall always satisfy q").condition
    assert c.expr == BinOp("&", BinOp("|", Var("a"), Var("b")), Not(Var("c")))


def test_polarity():
    assert P("upon p is TRUE sw shall always satisfy q").condition.expr == Var("p")
    assert P("upon p is FALSE sw shall always satisfy q").condition.expr == Not(Var("p"))
    assert P("unless p is FALSE sw shall always satisfy q").condition.expr == Var("p")
    assert P("whenever a is False sw shall always satisfy q").condition.expr == Not(Var("a"))


# ---------------------------------------------------------------- component, timing

TIMINGS = [
    ("immediately", "immediately"),
    ("initially", "immediately"),
    ("at the first timepoint", "immediately"),
    ("at the same timepoint", "immediately"),
    ("at the next timepoint", "next"),
    ("eventually", "eventually"),
    ("always", "always"),
    ("never", "never"),
    ("finally", "finally"),
    ("at the last timepoint", "finally"),
    ("", "null"),
]


@pytest.mark.parametrize(("phrase", "kind"), TIMINGS)
def test_timing_words(phrase, kind):
    assert P(f"the sw shall {phrase} satisfy q").timing.kind == kind


UNITS = [
    ("tick", "tick"),
    ("ticks", "tick"),
    ("hour", "hour"),
    ("hours", "hour"),
    ("minute", "minute"),
    ("minutes", "minute"),
    ("second", "second"),
    ("seconds", "second"),
    ("sec", "second"),
    ("secs", "second"),
    ("millisecond", "millisecond"),
    ("milliseconds", "millisecond"),
    ("millisec", "millisecond"),
    ("ms", "millisecond"),
    ("microsecond", "microsecond"),
    ("microseconds", "microsecond"),
    ("microsec", "microsecond"),
    ("microsecs", "microsecond"),
]


@pytest.mark.parametrize(("word", "unit"), UNITS)
@pytest.mark.parametrize("kind", ["within", "for", "after"])
def test_durations(word, unit, kind):
    t = P(f"sw shall {kind} 2.5 {word} satisfy q").timing
    assert t.kind == kind and t.duration == Duration(Fraction(5, 2), unit)


def test_until_before_stop_conditions():
    t = P("sw shall until stop_cmd | y < 0 satisfy q").timing
    assert t.kind == "until" and t.stop == BinOp(
        "|", Var("stop_cmd"), BinOp("<", Var("y"), Const(0))
    )
    t = P("sw shall before y < 0 satisfy q").timing
    assert t.kind == "before" and t.stop == BinOp("<", Var("y"), Const(0))


@pytest.mark.parametrize("kind", ["within", "for", "after"])
def test_duration_without_unit_is_an_error(kind):
    e = err(f"sw shall {kind} 3 satisfy resp")
    assert "no time unit" in e.message and e.hint and "ticks" in e.hint


def test_component_and_period():
    req = P("The left_wheel.controller shall always satisfy q.")
    assert req.component == "left_wheel.controller" and req.response == Var("q")
    # FRET's names may be quoted; a quoted sentence alone is still free-form text.
    assert P('the "flight sw" shall always satisfy q').component == "flight sw"
    assert P('in m, shall "flight sw" always satisfy q').component == "flight sw"
    assert "free-form" in err('"flight sw".').message


SCOPE_PHRASES = [
    "",
    "in mode m ",
    "when not in m ",
    "unless in m, ",
    "except during m ",
    "only in m mode ",
    "only while m ",
    "after m ",
    "before m ",
    "only after m ",
    "only before mode m ",
]


@pytest.mark.parametrize("scope", SCOPE_PHRASES)
@pytest.mark.parametrize("cond", ["", "upon c ", "whenever c, "])
def test_component_after_shall(scope, cond):
    # FRET's grammar: `component SHALL | SHALL component`, in every scope.
    for timing in ("", "always ", "within 2 ticks ", "until s "):
        before = P(f"{scope}{cond}the sw shall {timing}satisfy p")
        after = P(f"{scope}{cond}shall the sw {timing}satisfy p")
        assert after.component == before.component == "sw"
        assert (after.scope, after.condition, after.timing, after.response) == (
            before.scope,
            before.condition,
            before.timing,
            before.response,
        )
        assert formalize(after).formula == formalize(before).formula
    assert P(f"{scope}{cond}shall sw, always, satisfy p").timing.kind == "always"


@pytest.mark.parametrize("timing", ["always", "within 2 ticks", "until s", "eventually"])
def test_missing_component_after_shall_is_named(timing):
    # Without this check the timing word would silently become the component.
    e = err(f"in m, shall {timing} satisfy p")
    assert "not a component name: the component is missing" in e.message and e.col == 13
    assert P(f"in m, shall the always_on {timing} satisfy p").component == "always_on"


def test_probability_is_refused_not_dropped():
    # FRET's ptLTL drops the bound; monitoring it would silently strengthen the
    # requirement to "on every run".
    e = err("The sw shall with probability >= 0.9 always satisfy q.")
    assert "cannot be monitored" in e.message and "PRISM" in e.message and e.col == 14
    assert e.hint and "remove 'with probability" in e.hint
    e = err("shall sw with probability <= 0.5 eventually satisfy q")
    assert "cannot be monitored" in e.message
    # FRET's commas around the probability; its query form.
    e = err("sw shall, with probability > 0.5, always satisfy q")
    assert "cannot be monitored" in e.message and e.col == 11
    assert "cannot be monitored" in err("sw shall with probability > 0.5, satisfy q").message
    e = err("whenever p the sw shall with what probability eventually satisfy q")
    assert "'with what probability'" in e.message and e.col == 25
    e = err("sw shall with probability > 1.5 always satisfy q")
    assert "illegal probability" in e.message and e.col == 29
    # FRET's checkReqt also refuses strict bounds no run can meet.
    assert "illegal probability" in err("sw shall with probability > 1 always satisfy q").message
    assert "illegal probability" in err("sw shall with probability < 0 always satisfy q").message


@pytest.mark.parametrize(
    "text,col,why",
    [
        ("sw shall always satisfy at the next occurrence of p, q", 25, "looks into the future"),
        ("upon at the next occurrence of p, q sw shall always satisfy r", 6, "looks into"),
    ],
)
def test_next_occurrence_is_named_in_the_error(text, col, why):
    e = err(text)
    assert "occurrence of P, Q' cannot be monitored" in e.message and why in e.message
    assert e.col == col and e.line == 1


def test_previous_occurrence_is_an_expression():
    # FRET's prevOcc(p, q), with the scope's start left for formalize to put in.
    prev = resp("at the previous occurrence of p, q")
    assert INTERVAL_START in subterms(prev) and BOUNDED in subterms(prev)
    assert resp("prevOcc(p, q)") == prev
    assert resp("AT  the Previous\noccurrence OF p, q") == prev
    # The second expression runs to the end, as after `then` (FRET's precedence).
    assert resp("at the previous occurrence of p, q & r") == resp(
        "at the previous occurrence of p, (q & r)"
    )
    assert resp("(at the previous occurrence of p, q) & r") == BinOp("&", prev, Var("r"))
    # In a condition and as the mode of a scope.
    parse_requirement("upon at the previous occurrence of p, q sw shall always satisfy r")
    parse_requirement("while at the previous occurrence of p, q sw shall always satisfy r")
    # `at`, `the` and `previous` stay names.
    assert resp("at & the & previous") == BinOp(
        "&", BinOp("&", Var("at"), Var("the")), Var("previous")
    )


def test_previous_occurrence_as_an_operand_says_to_parenthesize():
    e = err("sw shall always satisfy x & at the Previous occurrence of p, q")
    assert "whole expression" in e.message and e.col == 29 and "parentheses" in (e.hint or "")
    with pytest.raises(FormulaSyntaxError, match="FRETISH sentence"):
        parse_formula("at the previous occurrence of p, q")


@pytest.mark.parametrize(
    "scope", ["only when not in m,", "only if not in m", "only not in m", "only unless in m"]
)
def test_only_not_in_is_explained(scope):
    # FRET's grammar has no `only` form of the not-in scope.
    e = err(f"{scope} sw shall always satisfy p")
    assert "no 'only when not in' scope" in e.message and e.col == 1
    assert e.hint and "never satisfy" in e.hint


# ---------------------------------------------------------------- expressions


def resp(expr: str):
    return P(f"sw shall always satisfy {expr}").response


@pytest.mark.parametrize(
    ("fretish", "pt"),
    [
        ("p & q | r", "(p & q) | r"),
        ("p | q & r", "p | (q & r)"),
        ("!p & q", "(! p) & q"),
        ("~p", "! p"),
        ("! x > 3", "! (x > 3)"),
        ("p -> q -> r", "(p -> q) -> r"),
        ("p => q", "p -> q"),
        ("p <=> q", "p <-> q"),
        ("a xor b xor c", "(a xor b) xor c"),
        ("if p then q", "p -> q"),
        ("if p then q & r", "p -> (q & r)"),
        ("x + y * 2 >= 10", "(x + (y * 2)) >= 10"),
        ("x - y - 1 = 0", "((x - y) - 1) = 0"),
        ("x-y>0", "(x - y) > 0"),
        ("x mod 4 = 1", "(x mod 4) = 1"),
        ("x / 2 != 3", "(x / 2) != 3"),
        ("x ^ 2 <= 9", "(x ^ 2) <= 9"),
        ("-x < 3", "(- x) < 3"),
        ("x > -3", "x > -3"),
        ("t <= 37.5", "t <= 37.5"),
        ("a >= 1.5e2", "a >= 1.5e2"),
        ("TRUE", "TRUE"),
        ("false | p", "FALSE | p"),
        ("((((p))))", "p"),
        ("FTP -> init", "(Z FALSE) -> init"),
    ],
)
def test_expressions(fretish, pt):
    assert resp(fretish) == parse_formula(pt)


def test_dotted_names_keep_the_dot():
    assert resp("robot.speed > 3") == BinOp(">", Var("robot.speed"), Const(3))


def test_temporal_functions():
    # Counted from the start of the scope's interval, which formalize puts in.
    assert resp("persisted(3, hot)") == BinOp(
        "&", Past("H", Var("hot"), 0, 3), Past("H", Not(INTERVAL_START), 0, 2)
    )
    assert resp("occurred(1, 4, f)") == Since("S", Not(INTERVAL_START), Var("f"), 1, 4)
    assert resp("occurred(4, f)") == Since("S", Not(INTERVAL_START), Var("f"), 0, 4)
    # Other calls are kept, as FRET keeps them, for the config's functions to define.
    assert resp("foo(3, x)") == Call("foo", (Const(3), Var("x")))
    assert resp("preReal(0.0, x) < x") == BinOp("<", Pre("preReal", Const(0.0), Var("x")), Var("x"))
    for future in ("persists(3, hot)", "occurs(3, hot)", "nextOcc(p, q)"):
        assert "future-time" in err(f"sw shall always satisfy {future}").message
    assert (
        "persisted takes 2 or 3 arguments" in err("sw shall always satisfy persisted(hot)").message
    )
    assert "preInt takes 2 arguments" in err("sw shall always satisfy preInt(x) > 1").message
    assert "tick count" in err("sw shall always satisfy persisted(x, hot)").message
    assert resp("-(x)") == Neg(Var("x"))
    assert resp("FTP") == FTP


@pytest.mark.parametrize("word", "O H S Y Z X F G U V T A E abs max min mode next".split())
def test_reserved_words(word):
    e = err(f"sw shall always satisfy {word} > 1")
    assert "reserved" in e.message and word in e.message and e.col == 25
    assert e.hint and '"T"' in e.hint  # quoted, FRET takes it


def test_three_argument_persisted_and_occurred():
    # FRET's templates (xform.js): p held from m to n ticks ago, and n ticks have
    # passed in the scope's interval; p occurred from m to n ticks ago, within it.
    assert resp("persisted(1, 3, hot)") == BinOp(
        "&", Past("H", Var("hot"), 1, 3), Past("H", Not(INTERVAL_START), 0, 2)
    )
    assert resp("persisted(0, 3, hot)") == resp("persisted(3, hot)")
    assert resp("persisted(0, 0, hot)") == Var("hot")
    assert resp("persisted(2, 2, hot)") == BinOp(
        "&", Past("H", Var("hot"), 2, 2), Past("H", Not(INTERVAL_START), 0, 1)
    )
    assert resp("occurred(2, 2, f)") == Since("S", Not(INTERVAL_START), Var("f"), 2, 2)


@pytest.mark.parametrize("fn", ["persisted", "occurred"])
def test_a_window_written_far_end_first_is_refused_in_one_line(fn):
    # FRET prints H[3,1] / S[3,1] for it: an empty window, never what was meant.
    e = err(f"sw shall always satisfy x -> {fn}(3, 1, hot)")
    assert e.col == 30 and "3" in e.message and "1" in e.message and "\n" not in str(e)
    assert e.hint and f"{fn}(1, 3, " in e.hint
    assert "tick count" in err(f"sw shall always satisfy {fn}(1, n, hot)").message
    assert "2 or 3 arguments" in err(f"sw shall always satisfy {fn}(1, 2, 3, hot)").message


@pytest.mark.parametrize(
    "text,formula",
    [
        ("abs(roll_angle) < 6.0", "abs(roll_angle) < 6.0"),
        ("abs(check_1_1 - 1.0) < eps6", "abs(check_1_1 - 1.0) < eps6"),
        ("min(a, b) > max(c, 2)", "min(a, b) > max(c, 2)"),
        ("absReal(x) = abs(x)", "abs(x) = abs(x)"),
    ],
)
def test_abs_min_max_are_functions_in_a_sentence(text, formula):
    assert resp(text) == parse_formula(formula)
    # the same in a condition and a scope's mode
    req = P(f"while abs(v) < 2.0 upon {text} sw shall always satisfy q")
    assert req.condition.expr == parse_formula(formula)


def test_abs_min_max_stay_reserved_as_names_and_check_their_arguments():
    assert "reserved" in err("sw shall always satisfy abs > 1").message
    assert "reserved" in err("sw shall always satisfy x -> min").message
    e = err("sw shall always satisfy abs(x, y) > 1")
    assert "abs" in e.message and e.col == 25


@pytest.mark.parametrize("end", [",", " ,", ", .", ",.", "."])
def test_a_comma_or_a_dot_may_follow_the_response(end):
    plain = "in cruise mode upon p sw shall within 2 ticks satisfy q & r"
    assert replace(P(plain + end), text=plain) == P(plain)
    prev = "sw shall always satisfy at the previous occurrence of p, q"
    assert P(prev + end).response == P(prev).response


@pytest.mark.parametrize(
    "text,col,words",
    [
        ("sw shall always satisfy q,,", 27, "','"),
        ("sw shall always satisfy q, r", 28, "'r'"),
        ("sw shall always satisfy q. r", 28, "'r'"),
    ],
)
def test_after_the_trailing_comma_nothing_else(text, col, words):
    e = err(text)
    assert e.col == col and words in e.message and "\n" not in str(e)


@pytest.mark.parametrize("word", ["T", "Z", "A", "MODE", "mode", "next", "left wheel", "a-b"])
def test_quoted_names(word):
    # FRET's quoted names (docs/reference/fretish.md, "Names"): variables and modes.
    r = P(f'in "{word}" mode, when "{word}" > 1, sw shall always satisfy "{word}"')
    assert r.scope.mode == Var(word) and r.response == Var(word)
    assert r.condition.expr == BinOp(">", Var(word), Const(1))


@pytest.mark.parametrize(
    ("name", "why"),
    [("", "empty"), ("_DQT_x_DQT_", "_DQT_"), ("x_SPC ", "renaming"), ("a\\", "printable")],
)
def test_quoted_names_formula_text_cannot_hold(name, why):
    e = err(f'sw shall always satisfy "{name}"')
    assert "cannot be used as a name" in e.message and why in e.message and e.col == 25


# ---------------------------------------------------------------- errors


def test_messages():
    assert err("the sw shall always q").message == "expected 'satisfy' near 'q'"
    assert err("the sw will always satisfy q").message == "expected 'shall' near 'will'"
    assert "expected an expression" in err("the sw shall always satisfy").message
    e = err('"The robot should be safe at all times"')
    assert e.message == "free-form text is not FRETISH; FRET does not formalize it"
    e = err("the sw shall satisfy q within 3 ticks")
    assert "must come before 'satisfy'" in e.message and e.col == 24
    assert "'@'" in err("sw shall always satisfy p @ q").message
    assert err("").message == "empty requirement"


@pytest.mark.parametrize(
    "text", ["sw shall always satisfy a and b", "while m or n, sw shall always satisfy p"]
)
def test_words_for_operators_get_a_hint(text):
    e = err(text)
    assert e.hint and "&" in e.hint and "|" in e.hint


def test_error_position_in_a_file():
    # The sentence starts at line 7, column 11 of reqs.yaml; 'q' is its 21st character.
    e = err("the sw shall always q", file="reqs.yaml", line=7, col=11)
    assert str(e) == "reqs.yaml:7:31: expected 'satisfy' near 'q'"
    e = err("sw shall always satisfy O > 3", file="reqs.yaml", line=7, col=11)
    assert str(e).startswith("reqs.yaml:7:35: 'O' is reserved")
    # A multi-line sentence: the column is the bad token's column on its own line.
    e = err("the sw shall always\n  satisfy q r", file="reqs.yaml", line=7, col=11)
    assert str(e).startswith("reqs.yaml:8:13: ")


def test_trailing_period_and_commas():
    assert P("the sw shall always satisfy q.").response == Var("q")
    assert P("in mode m, upon p, sw shall, always, satisfy q").timing.kind == "always"


WORDS = sorted({w for d in ALL for w in d["fretish"].split()})


@settings(max_examples=300, deadline=None)
@given(st.lists(st.sampled_from(WORDS), min_size=0, max_size=14), st.sampled_from(ALL))
def test_any_word_salad_is_a_requirement_or_a_located_error(words, ex):
    # Real sentences with words inserted or replaced: never a traceback.
    parts = ex["fretish"].split()
    for i, w in enumerate(words):
        if i % 2 or not parts:
            parts.insert((i * 7) % (len(parts) + 1), w)
        else:
            parts[(i * 5) % len(parts)] = w
    text = " ".join(parts)
    try:
        req = parse_requirement(text, file="f", line=2, col=3)
    except UserError as e:
        assert re.match(r"^f:\d+:\d+: ", str(e)) and "\n" not in str(e), str(e)
        return
    try:
        formalize(req, period_ms=1.0)
    except UserError as e:
        assert str(e).startswith("<input>")


# ---------------------------------------------------------------- nesting limit
# Every formula walker recurses; the parsers refuse more than MAX_DEPTH nested
# operators up front, at the offending token (docs/reference/config.md, Limits).


@pytest.mark.parametrize(
    "expr",
    [
        "!" * 5000 + "p",
        " & ".join(["p"] * 5000),
        "-" * 5000 + "x > 0",
        "if p then " * 3000 + "p",
        "persisted(1, " * 3000 + "p" + ")" * 3000,
    ],
    ids=["not", "and", "minus", "ifthen", "call"],
)
def test_deep_nesting_is_one_located_error(expr):
    e = err(f"sw shall always satisfy {expr}", file="c.yaml", line=7, col=11)
    assert e.file == "c.yaml" and e.line == 7 and e.col is not None
    assert f"nested more than {MAX_DEPTH} operators deep" in e.message


def test_nesting_up_to_the_limit_parses_and_parentheses_are_free():
    r = P("sw shall always satisfy " + "!" * (MAX_DEPTH - 1) + "(p)")
    assert depth(r.response) == MAX_DEPTH
    r = P("sw shall always satisfy " + "(" * 5000 + "p" + ")" * 5000)
    assert r.response == Var("p")


@pytest.mark.parametrize("text", ["!" * 5000 + "p", " & ".join(["p"] * 5000), "Y " * 5000 + "p"])
def test_deep_formula_text_is_a_syntax_error(text):
    with pytest.raises(FormulaSyntaxError, match="nested more than"):
        parse_formula(text)
    assert parse_formula("(" * 5000 + "p" + ")" * 5000) == Var("p")


@pytest.mark.parametrize("where", ["satisfy x > NUM", "within NUM ticks satisfy p"])
def test_a_number_of_thousands_of_digits_is_one_located_error(where):
    text = "sw shall " + ("always " if "satisfy x" in where else "") + where
    e = err(text.replace("NUM", "1" * 5000), file="c.yaml", line=3, col=11)
    assert e.line == 3 and "is too long" in e.message
    with pytest.raises(FormulaSyntaxError, match="too long"):
        parse_formula("x > " + "1" * 5000)
    with pytest.raises(FormulaSyntaxError, match="too long"):
        parse_formula("O[0," + "1" * 5000 + "] p")
