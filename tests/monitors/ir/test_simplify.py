"""The simplifier never changes a formula's verdicts (judged by the interpreter)."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from monitors.ir.formula import FALSE, FTP, TRUE, BinOp, Not, Past, Since, Var, parse_formula
from monitors.ir.simplify import simplify
from monitors.verify.interpret import verdicts

leaves = st.one_of(st.sampled_from(["a", "b"]).map(Var), st.sampled_from([TRUE, FALSE, FTP]))


def _extend(children):
    bounds = st.integers(0, 3).flatmap(lambda lo: st.tuples(st.just(lo), st.integers(lo, lo + 3)))
    return st.one_of(
        children.map(Not),
        st.tuples(st.sampled_from(["&", "|", "->"]), children, children).map(lambda t: BinOp(*t)),
        st.tuples(st.sampled_from(["Y", "Z", "H", "O"]), children).map(lambda t: Past(*t)),
        st.tuples(st.sampled_from(["H", "O"]), children, bounds).map(
            lambda t: Past(t[0], t[1], *t[2])
        ),
        st.tuples(st.sampled_from(["S", "T"]), children, children).map(lambda t: Since(*t)),
        # the shapes FRET's construction produces: x S (x & left)
        children.map(lambda x: Since("S", x, BinOp("&", x, FTP))),
        children.map(lambda x: Since("S", x, FTP)),
    )


@pytest.mark.slow
@settings(max_examples=400)
@given(st.recursive(leaves, _extend, max_leaves=10), st.data())
def test_simplify_preserves_verdicts(f, data):
    g = simplify(f)
    for _ in range(5):
        n = data.draw(st.integers(1, 12))
        trace = [{"a": data.draw(st.booleans()), "b": data.draw(st.booleans())} for _ in range(n)]
        assert verdicts(f, trace) == verdicts(g, trace), (str(f), str(g))


def test_always_reads_as_historically():
    assert str(simplify(parse_formula("p S (p & (Z FALSE))"))) == "(H p)"
    assert str(simplify(parse_formula("(O (Z FALSE)) -> (H (M -> p))"))) == "(H (M -> p))"
