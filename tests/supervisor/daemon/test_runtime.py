"""The runtime core (no rclpy): step policies, readiness, stale inputs, bad values.

Tick-precise: time is passed in explicitly, the monitor is the real compiled
sRobot monitor from config/srobot.yaml.
"""

import json
from pathlib import Path

import pytest

from monitors.backends.load import compile_spec
from supervisor.daemon.runtime import InputSpec, Runtime, coerce
from supervisor.pipeline import project_for

ROOT = Path(__file__).resolve().parents[3]
MS = 1_000_000
# The order in which the thesis's controller publishes its burst (turnoffUVC last).
ORDER = ["classifier", "distance_to_target", "OpState", "alert", "halt", "slowdown", "turnoffUVC"]
IDLE = dict(
    classifier=0,
    distance_to_target=20,
    OpState=0,
    alert=False,
    halt=False,
    slowdown=False,
    turnoffUVC=False,
)
RED = dict(
    classifier=1,
    distance_to_target=2,
    OpState=3,
    alert=False,
    halt=True,
    slowdown=False,
    turnoffUVC=True,
)


@pytest.fixture(scope="module")
def srobot(tmp_path_factory):
    project = project_for(ROOT / "config" / "srobot.yaml", ros=False)
    spec = project.spec()
    return spec, compile_spec(spec, tmp_path_factory.mktemp("rt"))


def make(srobot, policy, **kw):
    spec, mon = srobot
    mon.reset()
    stale_ns = kw.pop("stale_ns", None)
    inputs = [InputSpec(v.name, v.type, stale_after_ns=stale_ns) for v in spec.inputs]
    return Runtime(inputs, mon, policy=policy, **kw), [r.id for r in spec.requirements]


def burst(rt, state, t0, gap_ns=200_000):
    """Publish one state as the controller does: 7 messages with small gaps."""
    results = []
    for k, name in enumerate(ORDER):
        res, _ = rt.on_message(name, state[name], t0 + k * gap_ns)
        if res is not None:
            results.append(res)
    return results


def violated(results, ids):
    return [ids[i] for r in results for i in r.violated]


def test_nothing_is_stepped_until_every_input_has_a_value(srobot):
    rt, _ = make(srobot, "on_message")
    for name in ORDER[:-1]:
        res, _ = rt.on_message(name, IDLE[name], 0)
        assert res is None
    assert rt.missing_inputs() == ["turnoffUVC"]
    res, _ = rt.on_message("turnoffUVC", False, 1)
    assert res is not None and res.tick == 0 and res.violated == []


def test_initial_values_make_the_monitor_ready(srobot):
    spec, mon = srobot
    mon.reset()
    inputs = [InputSpec(v.name, v.type, initial=IDLE[v.name]) for v in spec.inputs]
    rt = Runtime(inputs, mon, policy="on_message")
    assert rt.ready
    res, _ = rt.on_message("classifier", 0, 0)
    assert res is not None and res.violated == []


@pytest.mark.parametrize("policy", ["on_trigger", "synchronized", "periodic"])
def test_thesis_burst_has_no_false_violation(srobot, policy):
    """Fig. 68: stepping once the burst is complete sees no transient state."""
    kw = {"trigger": "turnoffUVC"} if policy == "on_trigger" else {}
    if policy == "periodic":
        kw["period_ns"] = 10 * MS
    rt, ids = make(srobot, policy, **kw)
    results = []
    t = 0
    for state in [IDLE, RED, IDLE, RED, IDLE]:
        results += burst(rt, state, t)
        t += 10 * MS
        if policy == "periodic":  # the timer fires between bursts
            res = rt.on_timer(t - MS)
            results += [res] if res else []
    assert results, "the monitor was never stepped"
    assert violated(results, ids) == []


def test_thesis_burst_on_message_shows_transient_false_violations(srobot):
    """Fig. 67: OGMA's step-per-message sees classifier=1 at 2 m before OpState=3 arrives."""
    rt, ids = make(srobot, "on_message")
    burst(rt, IDLE, 0)
    results = burst(rt, RED, 10 * MS)
    assert "state_req103" in violated(results, ids)
    # the state each tick saw was half old, half new: never a real violation
    assert results[-1].inputs == RED


def test_synchronized_steps_after_max_skew_when_an_input_is_silent(srobot):
    rt, ids = make(srobot, "synchronized", max_skew_ns=20 * MS)
    burst(rt, IDLE, 0)
    res, _ = rt.on_message("classifier", 1, 50 * MS)
    assert res is None
    assert rt.due(50 * MS) == 70 * MS
    assert rt.on_timer(60 * MS) is None
    res = rt.on_timer(70 * MS)
    assert res is not None and res.inputs["classifier"] == 1


def test_periodic_ticks_stay_on_the_grid(srobot):
    rt, _ = make(srobot, "periodic", period_ns=10 * MS)
    burst(rt, IDLE, 0)
    ticks = [r.tick for t in range(0, 100 * MS, MS) if (r := rt.on_timer(t)) is not None]
    assert ticks == list(range(10))
    # a late timer callback does not add ticks: the next tick is on the grid
    assert rt.on_timer(125 * MS) is not None
    assert rt.on_timer(129 * MS) is None
    assert rt.on_timer(130 * MS) is not None


def test_stale_input_and_recovery(srobot):
    rt, _ = make(srobot, "on_trigger", trigger="turnoffUVC")
    burst(rt, IDLE, 0)
    assert rt.check_stale(400 * MS, 500 * MS) == []
    rt.on_message("turnoffUVC", False, 400 * MS)  # everything but turnoffUVC goes silent
    events = rt.check_stale(502 * MS, 500 * MS)
    assert sorted(e.name for e in events) == sorted(ORDER[:-1])
    assert all(e.what == "input_stale" for e in events)
    assert rt.check_stale(600 * MS, 500 * MS) == []  # reported once
    _, events = rt.on_message("classifier", 0, 650 * MS)
    assert [(e.what, e.name) for e in events] == [("input_recovered", "classifier")]
    assert "classifier" not in rt.stale_inputs()


def test_per_variable_stale_limit(srobot):
    rt, _ = make(srobot, "on_trigger", trigger="turnoffUVC", stale_ns=50 * MS)
    burst(rt, IDLE, 0)
    assert len(rt.check_stale(60 * MS, 500 * MS)) == 7


@pytest.mark.parametrize(
    ("value", "vtype", "ok"),
    [
        (float("nan"), "int64", False),
        (2**64 - 1, "int64", False),  # a uint64 field beyond int64
        (2, "bool", False),
        (True, "int64", False),
        (3.0, "int64", True),
        (float("nan"), "double", True),  # NaN is a double; the formula decides
        (7, "double", True),
    ],
)
def test_coerce(value, vtype, ok):
    _, why = coerce(value, vtype)
    assert (why is None) == ok


def test_bad_values_are_reported_not_crashed_on(srobot):
    rt, _ = make(srobot, "on_trigger", trigger="turnoffUVC")
    burst(rt, IDLE, 0)
    res, events = rt.on_message("classifier", 2**64 - 1, MS)
    assert res is None and [e.what for e in events] == ["input_rejected"]
    assert rt.snapshot()["classifier"] == 0  # the last good value is kept
    assert rt.input_stats()["classifier"]["rejected"] == 1


def test_reset_requirement_leaves_no_blind_tick(srobot):
    rt, ids = make(srobot, "on_trigger", trigger="turnoffUVC")
    bad = dict(RED, OpState=2, alert=True, slowdown=True, halt=False, turnoffUVC=False)
    assert violated(burst(rt, bad, 0), ids) == ["state_req103"]
    rt.reset_requirement(ids.index("state_req103"))
    # the very next tick is judged afresh, and reported again while still violated
    assert violated(burst(rt, bad, 10 * MS), ids) == ["state_req103"]
    rt.reset_requirement(ids.index("state_req103"))
    assert violated(burst(rt, RED, 20 * MS), ids) == []


def test_recent_keeps_the_last_ticks(srobot):
    spec, mon = srobot
    mon.reset()
    rt = Runtime(
        [InputSpec(v.name, v.type) for v in spec.inputs],
        mon,
        policy="on_trigger",
        trigger="turnoffUVC",
        recent_len=3,
    )
    for k in range(5):
        burst(rt, dict(IDLE, distance_to_target=10 + k), k * 10 * MS)
    assert [r["distance_to_target"] for r in rt.recent] == [12, 13, 14]
    assert [r["tick"] for r in rt.recent] == [2, 3, 4]
    # each tick's JSON made when stepped, which the violation record joins
    # (mitigations/violationlog/writer.py Row; bytes: tests/mitigations/violationlog/test_log_render.py)
    assert [json.loads(r.json) for r in rt.recent] == [dict(r) for r in rt.recent]


def test_fields_of_one_message_are_set_together(srobot):
    """on_values: one message, several inputs, at most one step (on_message)."""
    rt, _ = make(srobot, "on_message")
    for name in ORDER[:-2]:
        rt.on_message(name, IDLE[name], 0)
    res, events = rt.on_values((("slowdown", False), ("turnoffUVC", True)), 5 * MS)
    assert res is not None and res.tick == 0 and events == []
    assert res.inputs["turnoffUVC"] is True and rt.tick == 1
    # a rejected value does not block the others; nothing accepted, no step
    res, events = rt.on_values((("classifier", 2.5), ("halt", True)), 6 * MS)
    assert res is not None and res.inputs["halt"] is True
    assert [e.what for e in events] == ["input_rejected"]
    res, events = rt.on_values((("classifier", 2.5),), 7 * MS)
    assert res is None and rt.tick == 2
