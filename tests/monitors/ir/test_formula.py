"""Formula AST: FRET-syntax printer and parser round-trip; FRET's odd outputs."""

import json
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from monitors.ir.formula import (
    FALSE,
    FTP,
    TRUE,
    BinOp,
    Const,
    FormulaSyntaxError,
    Not,
    Past,
    Since,
    Var,
    max_bound,
    parse_formula,
    to_fret,
    variables,
)

EXAMPLES = Path(__file__).resolve().parents[2] / "data" / "fret-examples.jsonl"


def test_precedence_matches_fret_output():
    f = parse_formula("H (p & q -> r | ! s)")
    assert f == Past(
        "H", BinOp("->", BinOp("&", Var("p"), Var("q")), BinOp("|", Var("r"), Not(Var("s"))))
    )


def test_metric_bounds_and_ftp():
    assert parse_formula("O[0,3] FTP") == Past("O", FTP, 0, 3)
    assert parse_formula("(Y TRUE) S[1,4] fault") == Since("S", Past("Y", TRUE), Var("fault"), 1, 4)
    assert max_bound(parse_formula("H[0,3] a & O[2,9] b")) == 9


def test_empty_window_that_fret_prints_for_within_0():
    assert parse_formula("O[0,-1] p") == FALSE
    assert parse_formula("H[0,-1] p") == TRUE


def test_fret_malformed_fractional_bounds_are_rejected():
    with pytest.raises(FormulaSyntaxError, match="malformed time bounds"):
        parse_formula("O[<=1.5] p")


def test_older_fret_bounds_are_read():
    # Older FRET versions print SALT-style bounds: [<=n] is [0,n], [<n] [0,n-1], [=n] [n,n].
    assert parse_formula("O[<=3] p") == Past("O", Var("p"), 0, 3)
    assert parse_formula("H[<3] p") == Past("H", Var("p"), 0, 2)
    assert parse_formula("O[=2] p") == Past("O", Var("p"), 2, 2)
    assert parse_formula("(Y TRUE) S[<=4] p") == Since("S", Past("Y", TRUE), Var("p"), 0, 4)
    assert parse_formula("O[<0] p") == FALSE


@pytest.mark.parametrize(
    "text",
    [
        "! x = 4",
        "! a & b -> c | d xor e",
        "-x ^ 2 * 3 + 1 >= 2 mod 3",
        "if a then b -> c",
        "~ a => b <=> c",
    ],
)
def test_one_expression_grammar_for_fretish_and_formula_text(text):
    # The same text reads the same in a FRETISH sentence and in FRET's formula text.
    from monitors.frontend.parse import parse_requirement

    req = parse_requirement(f"the sw shall immediately satisfy {text}")
    assert parse_formula(text) == req.response


def test_numbers_and_words():
    f = parse_formula("x mod 4 = 1 & altitude >= 1.5e2 & v * 2 < -3")
    assert variables(f) == ["x", "altitude", "v"]
    assert f.left.right.right == Const(150.0)
    assert f.right.right == Const(-3)


def test_reserved_names_are_not_variables():
    with pytest.raises(FormulaSyntaxError):
        parse_formula("H > 3")


def test_every_fret_example_round_trips():
    for line in EXAMPLES.read_text().splitlines():
        row = json.loads(line)
        if not row["ok"] or "<=1.5" in row["pt"]:
            continue
        f = parse_formula(row["pt"])
        assert parse_formula(to_fret(f)) == f, row["id"]


names = st.sampled_from(["a", "b", "c"])
leaves = st.one_of(names.map(Var), st.sampled_from([TRUE, FALSE]))


def _extend(children):
    bounds = st.integers(0, 5).flatmap(lambda lo: st.tuples(st.just(lo), st.integers(lo, lo + 5)))
    return st.one_of(
        children.map(Not),
        st.tuples(st.sampled_from(["&", "|", "xor", "->", "<->"]), children, children).map(
            lambda t: BinOp(*t)
        ),
        st.tuples(st.sampled_from(["Y", "Z", "H", "O"]), children).map(lambda t: Past(*t)),
        st.tuples(st.sampled_from(["H", "O"]), children, bounds).map(
            lambda t: Past(t[0], t[1], *t[2])
        ),
        st.tuples(st.sampled_from(["S", "T"]), children, children).map(lambda t: Since(*t)),
        st.tuples(st.sampled_from(["S", "T"]), children, children, bounds).map(
            lambda t: Since(t[0], t[1], t[2], *t[3])
        ),
    )


@given(st.recursive(leaves, _extend, max_leaves=12))
def test_print_parse_round_trip(f):
    assert parse_formula(to_fret(f)) == f


def test_temporal_operators_in_formula_text_bind_as_documented():
    # docs/reference/fretish.md, "Expressions": Y Z H O bind like !, S and T like ->.
    a, b, c = Var("a"), Var("b"), Var("c")
    assert parse_formula("H a & b") == BinOp("&", Past("H", a), b)
    assert parse_formula("! Y a | b") == BinOp("|", Not(Past("Y", a)), b)
    assert parse_formula("a -> b S c") == Since("S", BinOp("->", a, b), c)
    assert parse_formula("a & b T[0,2] c") == Since("T", BinOp("&", a, b), c, 0, 2)
