"""User functions (the config's ``functions:``): calls FRET passes through, defined
once, expanded before typing, and computed by the compiled C monitor."""

from __future__ import annotations

import math
import random
import textwrap
from pathlib import Path

import pytest

from monitors.backends.load import compile_spec
from monitors.errors import UserError
from monitors.frontend.formalize import formalize
from monitors.frontend.parse import parse_requirement
from monitors.ir.formula import BinOp, Call, Const, Var, parse_formula, to_fret
from monitors.ir.functions import Function, check_definition, expand_functions, undefined
from monitors.verify.interpret import verdicts
from supervisor.config import load_config
from supervisor.pipeline import build_project

HEAD = """\
component: rover
step: {policy: periodic, period_ms: 10}
variables:
  vx: {type: double, topic: /vx, msg: std_msgs/msg/Float64}
  vy: {type: double, topic: /vy, msg: std_msgs/msg/Float64}
  n:  {type: int64, topic: /n, msg: std_msgs/msg/Int64}
"""

FUNCTIONS = """\
functions:
  mag:
    params: [x, y]
    define: sqrt(x * x + y * y)
  clamp:
    params: [v, lo, hi]
    define: min(max(v, lo), hi)
  rising:
    params: [p]
    define: p & (Y (! p))
"""

REQS = """\
requirements:
  - id: speed
    text: rover shall always satisfy mag(vx, vy) <= 2.5
  - id: count
    text: rover shall always satisfy clamp(n, 0, 10) = n
  - id: edge
    text: rover shall always satisfy rising(vx > 1.0) -> vy < 1.0
"""


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "c.yaml"
    p.write_text(textwrap.dedent(text))
    return p


def test_formalize_keeps_a_call_fret_would_pass_through():
    req = parse_requirement("rover shall always satisfy mag(vx, vy) <= 2.5")
    f = formalize(req).formula
    assert Call("mag", (Var("vx"), Var("vy"))) in _subterms(f)
    assert "mag(vx, vy)" in to_fret(f)


def _subterms(f):
    from monitors.ir.formula import subterms

    return subterms(f)


def test_expansion_substitutes_the_arguments_at_once():
    fn = Function("diff", ("a", "b"), parse_formula("a - b"))
    # b's argument mentions a: substituting one parameter at a time would be wrong.
    got = expand_functions(parse_formula("diff(b, a) > 0"), {"diff": fn})
    assert got == BinOp(">", BinOp("-", Var("b"), Var("a")), Const(0))


def test_definitions_are_checked():
    mag = Function("mag", ("x", "y"), parse_formula("sqrt(x * x + y * z)"))
    with pytest.raises(UserError, match="reads 'z', which is not one of its parameters"):
        check_definition(mag, {"mag": mag})
    f = Function("f", ("x",), parse_formula("g(x) + 1"))
    g = Function("g", ("x",), parse_formula("f(x) * 2"))
    with pytest.raises(UserError, match="cycle: f -> g -> f"):
        check_definition(f, {"f": f, "g": g})
    h = Function("h", ("x",), parse_formula("f(x, x)"))
    ok = Function("f", ("x",), parse_formula("x"))
    with pytest.raises(UserError, match=r"f\(x\) takes 1 argument, but f\(x, x\) passes 2"):
        check_definition(h, {"h": h, "f": ok})
    p = Function("p", ("x",), parse_formula("persisted(2, x)"))
    with pytest.raises(UserError, match="calls persisted/2") as e:
        check_definition(p, {"p": p})
    assert "formulas" in (e.value.hint or "")


def test_undefined_lists_every_function_once():
    f = parse_formula("mag(a, b) > det(a) & mag(b, a) < 1 & sqrt(a) > 0")
    assert undefined(f, {}) == ["mag/2", "det/1"]


def test_check_names_the_functions_a_config_cannot_compute(tmp_path):
    p = write(tmp_path, HEAD + REQS)
    project = build_project(load_config(p), ros=False)
    errors = {r.id: r.error for r in project.requirements}
    assert "requirement 'speed' uses function mag/2, which the config does not define" in (
        errors["speed"].message
    )
    assert errors["speed"].line == 9 and errors["speed"].file == str(p)
    assert "functions:" in (errors["speed"].hint or "")
    assert "clamp/3" in errors["count"].message


def test_check_cli_reports_undefined_functions(tmp_path, capsys):
    from supervisor.cli import main

    p = write(tmp_path, HEAD + REQS)
    assert main(["check", str(p)]) != 0
    out = capsys.readouterr()
    text = out.out + out.err
    assert "mag/2" in text and "Traceback" not in text


@pytest.mark.parametrize(
    ("section", "needle", "line"),
    [
        ("functions:\n  sqrt: {params: [x], define: x}\n", "built-in function", 8),
        ("functions:\n  mag: {params: [x], define: x + y}\n", "reads 'y'", 8),
        ("functions:\n  mag: {params: x, define: x}\n", "params must be a list", 8),
        ("functions:\n  mag: {params: [x, x], define: x}\n", "parameter twice", 8),
        ("functions:\n  mag: {params: [x]}\n", "needs 'define:'", 8),
        ("functions:\n  mag: {params: [x], define: x, type: double}\n", "unknown key 'type'", 8),
        ("functions:\n  mag: {params: [x], define: 'x +'}\n", "cannot parse define", 8),
        ("functions:\n  a: {params: [x], define: b(x)}\n  b: {params: [x], define: a(x)}\n",
         "cycle: a -> b -> a", 8),
        ("functions:\n  2d: {params: [x], define: x}\n", "not a usable function name", 8),
    ],
)  # fmt: skip
def test_bad_function_entries_are_located(tmp_path, section, needle, line):
    p = write(tmp_path, HEAD + section + REQS)
    with pytest.raises(UserError) as e:
        load_config(p)
    assert needle in e.value.message
    assert e.value.line == line and e.value.file == str(p)


def test_a_define_may_call_a_function(tmp_path):
    text = (
        HEAD
        + "  fast: {type: bool, define: 'mag(vx, vy) > 2.0'}\n"
        + FUNCTIONS
        + ("requirements:\n  - id: r\n    text: rover shall always satisfy !fast\n")
    )
    cfg = load_config(write(tmp_path, text))
    assert cfg.variables["fast"].define == parse_formula("sqrt(vx * vx + vy * vy) > 2.0")
    bad = (
        HEAD
        + "  fast: {type: bool, define: speed(vx) > 2.0}\n"
        + ("requirements:\n  - id: r\n    text: rover shall always satisfy !fast\n")
    )
    with pytest.raises(UserError, match="define of 'fast' uses function speed/1") as e:
        load_config(write(tmp_path, bad))
    assert e.value.line == 7


def test_functions_compile_to_c_that_agrees_with_the_definition(tmp_path):
    """The monitor built from a config with functions computes what the definitions
    say, on random traces, judged by the interpreter and by plain Python."""
    project = build_project(load_config(write(tmp_path, HEAD + FUNCTIONS + REQS)), ros=False)
    assert project.ok, project.first_error()
    spec = project.spec()
    mon = compile_spec(spec, tmp_path / "out")
    rng = random.Random(7)
    names = [v.name for v in spec.inputs]
    for _ in range(40):
        mon.reset()
        trace = [
            {"vx": rng.uniform(-3, 3), "vy": rng.uniform(-3, 3), "n": rng.randint(-5, 15)}
            for _ in range(rng.randint(1, 12))
        ]
        c_flags = [mon.tick([s[k] for k in names]) for s in trace]
        for i, r in enumerate(spec.requirements):
            expected = verdicts(spec.expanded(r), trace)
            assert [not f[i] for f in c_flags] == expected, r.id
        # and what the definitions mean, written out by hand
        speed = [math.hypot(s["vx"], s["vy"]) <= 2.5 for s in trace]
        count = [0 <= s["n"] <= 10 for s in trace]
        edge = [
            not (s["vx"] > 1.0 and (k > 0 and not trace[k - 1]["vx"] > 1.0)) or s["vy"] < 1.0
            for k, s in enumerate(trace)
        ]
        assert [not f[0] for f in c_flags] == _always(speed)
        assert [not f[1] for f in c_flags] == _always(count)
        assert [not f[2] for f in c_flags] == _always(edge)


def _always(xs: list[bool]) -> list[bool]:
    out, ok = [], True
    for x in xs:
        ok = ok and x
        out.append(ok)
    return out


def test_explain_shows_the_definitions_a_requirement_calls(tmp_path, capsys):
    from supervisor.cli import main

    only_count = REQS[: REQS.index("  - id: edge")].replace(
        "  - id: speed\n    text: rover shall always satisfy mag(vx, vy) <= 2.5\n", ""
    )
    p = write(
        tmp_path, HEAD.replace("  vx", "  # vx").replace("  vy", "  # vy") + FUNCTIONS + only_count
    )
    assert main(["explain", str(p), "count"]) == 0
    out = capsys.readouterr().out
    assert "function:  clamp(v, lo, hi) = min(max(v, lo), hi)" in out
    assert "formula:   (H (min(max(n, 0), 10) = n))" in out
