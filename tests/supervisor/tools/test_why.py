"""Why a formula has its value (monitors/verify/why.py): the sentences, and on
random formulas and traces the property that makes the tree an explanation: the
inputs it blames decide the verdict (every other input may change, the verdict
at that tick stays)."""

from __future__ import annotations

import random

import pytest

from monitors.ir.formula import BinOp, Formula, Not, Past, Since, Var, parse_formula
from monitors.verify.interpret import evaluate
from monitors.verify.why import (
    WhyNode,
    explain,
    formula_for_record,
    missing_inputs,
    trace_of_record,
    why_tree,
)

NAMES = ("a", "b", "c")


def test_the_sentence_names_the_values_that_broke_it():
    f = parse_formula("H ((classifier = 1 & ! dgt_3) -> (OpState = 3 & turnoffUVC))")
    ok = dict(classifier=1, dgt_3=True, OpState=0, turnoffUVC=False)
    bad = dict(classifier=1, dgt_3=False, OpState=3, turnoffUVC=False)
    text = explain(f, [ok, ok, ok, bad], 3, first_tick=1039)
    assert text == "classifier was 1 at tick 1042 while dgt_3 was false, turnoffUVC was false"


def test_a_window_and_a_since_are_explained_by_their_ticks():
    o = parse_formula("H (O[0,2] alert)")
    trace = [{"alert": v} for v in (True, False, False, False)]
    assert explain(o, trace, 3, first_tick=10) == "alert held at no tick from 11 to 13"
    s = parse_formula("H (go -> (! stop S armed))")
    trace = [
        dict(go=False, stop=False, armed=True),
        dict(go=False, stop=True, armed=False),
        dict(go=True, stop=False, armed=False),
    ]
    assert (
        explain(s, trace, 2, first_tick=100)
        == "go was true at tick 102 while stop was true at tick 101"
    )
    assert "no earlier tick" in explain(parse_formula("Y p"), [{"p": True}], 0)


def test_records_give_the_formula_over_inputs_and_the_window():
    record = {
        "formula": "(H dgt_3)",
        "formula_inputs": "(H (distance > 3))",
        "recent": [{"tick": 7, "distance": 5}, {"tick": 8, "distance": 2}],
    }
    f = formula_for_record(record)
    trace, first = trace_of_record(record)
    assert first == 7 and missing_inputs(f, trace) == []
    assert explain(f, trace, 1, first) == "(distance > 3) did not hold (distance = 2) at tick 8"
    assert missing_inputs(parse_formula("H dgt_3"), trace) == ["dgt_3"]


def random_formula(rng: random.Random, depth: int) -> Formula:
    if depth == 0 or rng.random() < 0.2:
        return Var(rng.choice(NAMES))
    kind = rng.randrange(8)
    sub = lambda: random_formula(rng, depth - 1)  # noqa: E731
    if kind == 0:
        return Not(sub())
    if kind in (1, 2):
        return BinOp(rng.choice(["&", "|", "->", "<->", "xor"]), sub(), sub())
    if kind == 3:
        return Past(rng.choice(["Y", "Z"]), sub())
    if kind in (4, 5):
        lo = rng.choice([None, 0, 1])
        hi = rng.choice([None, 2, 4]) if lo is not None else None
        return Past(rng.choice(["H", "O"]), sub(), lo, hi)
    lo = rng.choice([None, 0, 1])
    hi = rng.choice([None, 3]) if lo is not None else None
    return Since(rng.choice(["S", "T"]), sub(), sub(), lo, hi)


def blamed_inputs(node: WhyNode) -> set[tuple[str, int]]:
    out = set()
    if node.text in NAMES:
        out |= {(node.text, k) for k in node.blame_ticks}
    for c in node.children:
        out |= blamed_inputs(c)
    return out


@pytest.mark.parametrize("seed", range(40))
def test_the_blamed_inputs_decide_the_verdict(seed):
    rng = random.Random(seed)
    for _ in range(25):
        f = random_formula(rng, 4)
        n = rng.randint(1, 7)
        trace = [{x: rng.random() < 0.5 for x in NAMES} for _ in range(n)]
        tick = rng.randrange(n)
        value = evaluate(f, trace)[tick]
        keep = blamed_inputs(why_tree(f, trace, tick))
        for _ in range(10):
            other = [
                {x: trace[k][x] if (x, k) in keep else rng.random() < 0.5 for x in NAMES}
                for k in range(n)
            ]
            assert evaluate(f, other)[tick] == value, (str(f), trace, tick, keep)
        explain(f, trace, tick)  # a sentence for every case, never an error


def test_a_violation_record_is_explained_from_its_own_fields(tmp_path):
    """The daemon's core writes formula_inputs for a requirement that reads an
    internal variable; its recent window then explains the violation."""
    from mitigations.violationlog.testing import MemoryLog
    from monitors.backends.load import compile_spec
    from supervisor.daemon.core import Core
    from supervisor.daemon.session import build_session
    from supervisor.pipeline import project_for

    (tmp_path / "c.yaml").write_text(
        "component: R\n"
        "step: {policy: on_message}\n"
        "variables:\n"
        "  distance: {type: int64, topic: /d, msg: std_msgs/msg/Int64}\n"
        "  halted: {type: bool, topic: /h, msg: std_msgs/msg/Bool}\n"
        "  near: {type: bool, define: distance < 3}\n"
        "requirements:\n"
        "  - id: stop_near\n"
        "    text: R shall always satisfy near -> halted\n"
    )
    project = project_for(tmp_path / "c.yaml", ros=False)
    session = build_session(project, compile_spec(project.spec(), tmp_path / "b"))
    log = MemoryLog()
    core = Core(session, log, lambda _r: None, warn=lambda _t: None)
    core.start(0)
    core.fields([("halted", False)], 1)
    for k, d in enumerate((9, 7, 5, 2)):
        core.fields([("distance", d)], 10 + k)
    record = log.of("violation")[0]
    assert record["formula"] == "(H (near -> halted))"
    assert record["formula_inputs"] == "(H ((distance < 3) -> halted))"
    f = formula_for_record(record)
    trace, first = trace_of_record(record)
    assert explain(f, trace, len(trace) - 1, first) == (
        f"(distance < 3) held (distance = 2) at tick {record['tick']} while halted was false"
    )


def test_logs_why_explains_each_violation_of_a_log(tmp_path, capsys):
    """A log written by replay (the daemon's core) over a trace; ``logs --why``
    explains its violations from their recent windows."""
    import json

    from supervisor.cli import main
    from supervisor.tools.replay.session import replay_files

    (tmp_path / "c.yaml").write_text(
        "component: R\n"
        "step: {policy: on_trigger, trigger: halted}\n"
        "variables:\n"
        "  distance: {type: int64, topic: /d, msg: std_msgs/msg/Int64}\n"
        "  halted: {type: bool, topic: /h, msg: std_msgs/msg/Bool}\n"
        "requirements:\n"
        "  - id: stop_near\n"
        "    text: R shall always satisfy distance < 3 -> halted\n"
        "    on_violation: [note]\n"
        "    policy: {reset: after_mitigation}\n"
        "mitigations:\n"
        "  note: {log: {message: violated}}\n"
    )
    rows = [(9, False), (2, True), (2, False), (8, False), (1, False)]
    lines = []
    for k, (d, h) in enumerate(rows):
        t = 10**9 + k * 10**7
        lines += [
            {"t_ns": t, "name": "distance", "value": d},
            {"t_ns": t + 1, "name": "halted", "value": h},
        ]
    (tmp_path / "t.jsonl").write_text("\n".join(json.dumps(x) for x in lines) + "\n")
    log = tmp_path / "log.jsonl"
    replay_files(tmp_path / "c.yaml", [tmp_path / "t.jsonl"], log, None)
    assert main(["logs", "--why", str(log)]) == 0
    out = capsys.readouterr().out.splitlines()
    whys = [line.strip() for line in out if line.startswith("  why:")]
    assert whys == [
        "why: (distance < 3) held (distance = 2) at tick 2 while halted was false",
        "why: (distance < 3) held (distance = 1) at tick 4 while halted was false",
    ]
    assert main(["logs", "--why", "--json", str(log)]) == 0
    objs = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [o["tick"] for o in objs] == [2, 4] and all(o["problem"] is None for o in objs)
