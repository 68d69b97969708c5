"""Inputs from real robots' messages (supervisor/inputs/): field paths with array
elements and ``[]``, their checks against the message types, the config's located
errors for ages, rates, services and actions, readers against a plain reference on
random messages, service and action readers, and ages and rates in the runtime.

No DDS: rosidl's message classes are built directly, and the runtime is driven with
explicit times and a fake monitor that records what it is ticked with."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from typing import Any

import pytest
from action_msgs.msg import GoalInfo, GoalStatus, GoalStatusArray
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from hypothesis import given, settings
from hypothesis import strategies as st
from sensor_msgs.msg import LaserScan
from service_msgs.msg import ServiceEventInfo
from std_srvs.srv import SetBool, SetBool_Event, Trigger, Trigger_Event
from unique_identifier_msgs.msg import UUID

from mitigations.violationlog.testing import MemoryLog
from monitors.errors import UserError
from supervisor.config import load_config
from supervisor.config.model import Variable
from supervisor.daemon.core import Core
from supervisor.daemon.runtime import FUTURE_TOLERANCE_NS, InputSpec, Runtime
from supervisor.daemon.session import build_session
from supervisor.daemon.testing import RecordingMonitor
from supervisor.inputs.paths import EVERY, ReadError, Segment, parse_path, path_type
from supervisor.inputs.readers import SKIP, check_input, kind_of, make_reader, sporadic
from supervisor.pipeline import project_for

MS = 1_000_000


def var(name: str = "x", type: str = "double", **kw: Any) -> Variable:
    """An input variable as the config makes it (topic and msg of its source)."""
    kw.setdefault("topic", "/t")
    return Variable(name=name, type=type, role="input", line=1, **kw)


def scan_var(field: str, type: str = "double", **kw: Any) -> Variable:
    return var("scan", type, msg="sensor_msgs/msg/LaserScan", field=field, **kw)


def diag_var(field: str, type: str = "int64", **kw: Any) -> Variable:
    return var("diag", type, msg="diagnostic_msgs/msg/DiagnosticArray", field=field, **kw)


def service_var(call: str, type: str = "bool", srv: str = "Trigger", **kw: Any) -> Variable:
    return var(
        "dock",
        type,
        topic="/dock/_service_event",
        msg=f"std_srvs/srv/{srv}_Event",
        service="/dock",
        srv=f"std_srvs/srv/{srv}",
        call=call,
        **kw,
    )


def action_var(type: str, statuses: tuple[str, ...], **kw: Any) -> Variable:
    return var(
        "nav",
        type,
        topic="/navigate/_action/status",
        msg="action_msgs/msg/GoalStatusArray",
        action="/navigate",
        statuses=statuses,
        **kw,
    )


# ------------------------------------------------------------ 1. paths and checks


@pytest.mark.parametrize(
    ("text", "segments"),
    [
        ("ranges", [Segment("ranges")]),
        ("ranges[0]", [Segment("ranges", 0)]),
        ("ranges[-1]", [Segment("ranges", -1)]),
        ("twist.twist.linear.x", [Segment(n) for n in ("twist", "twist", "linear", "x")]),
        ("status[].level", [Segment("status", EVERY), Segment("level")]),
        (
            "status[].values[].key",
            [Segment("status", EVERY), Segment("values", EVERY), Segment("key")],
        ),
        (
            "status[2].values[-1].value",
            [Segment("status", 2), Segment("values", -1), Segment("value")],
        ),
    ],
)
def test_good_paths_parse_and_print_back(text, segments):
    path = parse_path(text)
    assert list(path.segments) == segments
    assert str(path) == text
    assert path.plain == all(s.index is None for s in segments)
    assert path.many == any(s.index == EVERY for s in segments)


@pytest.mark.parametrize(
    "text", ["", "ranges[", "ranges[0", "a..b", "[0]", "ranges[x]", "0abc", "a.b."]
)
def test_bad_path_syntax_is_a_user_error(text):
    with pytest.raises(UserError) as e:
        parse_path(text)
    assert "is not a field path" in e.value.message and repr(text)[1:-1] in e.value.message


@pytest.mark.parametrize(
    ("klass", "text", "leaf", "many"),
    [
        (LaserScan, "ranges[0]", "float", False),
        (LaserScan, "ranges[-1]", "float", False),
        (LaserScan, "ranges", "sequence<float>", False),
        (LaserScan, "header.stamp", "builtin_interfaces/Time", False),
        (LaserScan, "header.stamp.sec", "int32", False),
        (DiagnosticArray, "status[].level", "octet", True),
        (DiagnosticArray, "status[0].level", "octet", False),
        (DiagnosticArray, "status[].values[].key", "string", True),
        (DiagnosticArray, "status[].values", "sequence<diagnostic_msgs/KeyValue>", True),
        (GoalStatusArray, "status_list[].status", "int8", True),
    ],
)
def test_path_types(klass, text, leaf, many):
    pt = path_type(klass, parse_path(text))
    assert (pt.leaf, pt.many) == (leaf, many)


@pytest.mark.parametrize(
    ("variable", "needles"),
    [
        # an unknown field, at the top and inside a nested message
        (scan_var("rangez[0]"), ["no field 'rangez'", "LaserScan"]),
        (scan_var("header.stampz"), ["'header'", "no field 'stampz'"]),
        # an index on a scalar
        (scan_var("range_min[0]"), ["'range_min[0]'", "not an array"]),
        # a path through a primitive
        (scan_var("range_min.x"), ["'range_min'", "not a message with fields"]),
        (diag_var("status[].level.x"), ["'status[].level'", "not a message with fields"]),
        # [] (or a whole array) without reduce
        (diag_var("status[].level"), ["'status[].level'", "one value is needed"]),
        (scan_var("ranges"), ["'ranges'", "one value is needed"]),
        # reduce on a scalar
        (scan_var("range_min", reduce="min"), ["'range_min'", "not an array"]),
        (diag_var("status[0].level", reduce="max"), ["'status[0].level'", "not an array"]),
        # a type that cannot feed the variable's type
        (scan_var("header.frame_id"), ["'header.frame_id'", "string", "cannot feed a double"]),
        (scan_var("ranges[0]", type="int64"), ["'ranges[0]'", "float", "cannot feed a int64"]),
        (scan_var("ranges[0]", type="bool"), ["'ranges[0]'", "cannot feed a bool"]),
        (
            scan_var("ranges", type="int64", reduce="mean"),
            ["'ranges'", "mean of float", "cannot feed a int64"],
        ),
        (diag_var("status[].name", reduce="max"), ["'status[].name'", "array of numbers"]),
        (diag_var("status[].level", type="bool", reduce="max"), ["status[].level", "bool"]),
        # a bad stamp path for age_of
        (
            var("age", msg="sensor_msgs/msg/LaserScan", age_of="scan", stamp="header.frame_id"),
            ["'header.frame_id'", "not a time stamp"],
        ),
        (
            var("age", msg="sensor_msgs/msg/LaserScan", age_of="scan", stamp="header.stampz"),
            ["no field 'stampz'"],
        ),
        (
            var("age", msg="std_msgs/msg/Float64", age_of="speed"),  # no header
            ["no field 'header'", "Float64"],
        ),
        (
            var(
                "age", msg="diagnostic_msgs/msg/DiagnosticArray", age_of="d", stamp="status[].name"
            ),
            ["'status[].name'", "not a time stamp"],
        ),
        # a service's field is looked up in its request or response
        (service_var("response", field="successs", initial=False), ["no field 'successs'"]),
        (
            service_var("response", field="message", initial=False),
            ["'message'", "string", "cannot feed a bool"],
        ),
        # an action's goal states feed no double
        (action_var("double", ("executing",)), ["not a double"]),
    ],
)
def test_bad_inputs_are_user_errors_naming_the_field(variable, needles):
    with pytest.raises(UserError) as e:
        check_input(variable)
    for needle in needles:
        assert needle in e.value.message, (needle, e.value.message)


@pytest.mark.parametrize(
    ("variable", "kind", "reads", "reduction", "c_type"),
    [
        (scan_var("ranges[0]"), "value", "ranges[0]", "", "double"),
        (scan_var("ranges[-1]"), "value", "ranges[-1]", "", "double"),
        (scan_var("ranges", reduce="min"), "value", "ranges", "min", "double"),
        (scan_var("ranges", type="int64", reduce="count"), "value", "ranges", "count", "int64_t"),
        (diag_var("status[].level", reduce="max"), "value", "status[].level", "max", "int64_t"),
        (diag_var("status[].values", reduce="len"), "value", "status[].values", "len", "int64_t"),
        (
            var("age", msg="sensor_msgs/msg/LaserScan", age_of="scan"),
            "age", "header.stamp", "", "double",
        ),
        (var("hz", msg="sensor_msgs/msg/LaserScan", rate_of="scan"), "rate", "", "", "double"),
        (service_var("response", field="success", initial=False), "value", "response.success", "", "bool"),
        (service_var("request", event=True), "event", "request", "", "bool"),
        (
            service_var("request", srv="SetBool", field="data", initial=False),
            "value", "request.data", "", "bool",
        ),
        (
            action_var("bool", ("accepted", "executing")),
            "value", "status_list[].status", "any accepted|executing", "bool",
        ),
        (action_var("int64", ("executing",)), "value", "status_list[].status", "count executing", "int64_t"),
        (
            action_var("bool", ("aborted",), event=True),
            "event", "status_list[].status", "entered aborted", "bool",
        ),
    ],
)  # fmt: skip
def test_check_says_what_each_variable_reads(variable, kind, reads, reduction, c_type):
    d = check_input(variable)
    assert (d.kind, d.path, d.reduction, d.c_type) == (kind, reads, reduction, c_type)
    assert d.topic == variable.topic and d.message == variable.msg


# The config: one input of each source, a line each so that a key's line is its own.
CONFIG = """\
component: base
step: {policy: periodic, period_ms: 10, stale_after_ms: 100}
variables:
  obstacle:
    type: double
    topic: /scan
    msg: sensor_msgs/msg/LaserScan
    field: ranges[0]
  scan_age:
    type: double
    age_of: obstacle
  scan_hz:
    type: double
    rate_of: obstacle
    window_ms: 100
  docked:
    type: bool
    service: /dock
    srv: std_srvs/srv/Trigger
    call: response
    field: success
    initial: false
  nav_active:
    type: bool
    action: /navigate
    status: [accepted, executing]
  near:
    type: bool
    define: obstacle < 0.5
requirements:
  - id: fresh
    text: base shall always satisfy scan_age < 300 & scan_hz > 5
  - id: stop
    text: base shall always satisfy (near & nav_active) -> docked
"""


def write(tmp_path: Path, text: str, name: str = "c.yaml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def line_of(text: str, needle: str, after: str | None = None) -> int:
    """The 1-based line of the first line containing ``needle`` (after the line
    containing ``after``)."""
    lines = text.splitlines()
    start = 0 if after is None else next(i for i, x in enumerate(lines) if after in x)
    return next(i for i in range(start, len(lines)) if needle in lines[i]) + 1


def test_the_config_of_every_source_loads_and_checks(tmp_path):
    project = project_for(write(tmp_path, CONFIG))
    assert project.ok, project.first_error()
    cfg = project.config
    v = {x.name: x for x in cfg.inputs}
    assert (v["scan_age"].topic, v["scan_age"].msg) == ("/scan", "sensor_msgs/msg/LaserScan")
    assert (v["scan_hz"].topic, v["scan_hz"].window_ms) == ("/scan", 100.0)
    assert (v["docked"].topic, v["docked"].msg) == (
        "/dock/_service_event",
        "std_srvs/srv/Trigger_Event",
    )
    assert v["nav_active"].topic == "/navigate/_action/status"
    assert v["nav_active"].msg == "action_msgs/msg/GoalStatusArray"
    assert v["nav_active"].initial is False  # no goal before the first status
    assert [kind_of(x) for x in cfg.inputs] == ["value", "age", "rate", "value", "value"]
    assert [sporadic(x) for x in cfg.inputs] == [False, True, True, True, True]


def _config_error(tmp_path: Path, text: str) -> UserError:
    path = write(tmp_path, text)
    with pytest.raises(UserError) as e:
        load_config(path)
    err = e.value
    assert err.file == str(path) and str(err).startswith(f"{path}:{err.line}: "), str(err)
    return err


# (edit of CONFIG, the text of the error); the offending key is the edited line
LOCATED = [
    pytest.param(
        ("    age_of: obstacle", "    age_of: obstacel"),
        "age_of 'obstacel' is not an input variable with a topic",
        id="age_of-unknown",
    ),
    pytest.param(
        ("    age_of: obstacle", "    age_of: near"),
        "age_of 'near' is not an input variable with a topic",
        id="age_of-define",
    ),
    pytest.param(
        ("    age_of: obstacle", "    age_of: scan_hz"),
        # scan_hz comes after scan_age: not resolved yet, so said as no input with a topic
        "variable 'scan_age': age_of 'scan_hz'",
        id="age_of-derived",
    ),
    pytest.param(
        ("    rate_of: obstacle", "    rate_of: nobody"),
        "rate_of 'nobody' is not an input variable with a topic",
        id="rate_of-unknown",
    ),
    pytest.param(
        ("    rate_of: obstacle", "    rate_of: scan_age"),
        "rate_of 'scan_age', which is itself an age or a rate",
        id="rate_of-derived",
    ),
]


@pytest.mark.parametrize(("edit", "needle"), LOCATED)
def test_age_and_rate_of_no_input_are_located_at_the_variable(tmp_path, edit, needle):
    """Written as one flow mapping, the variable's line is the key's line."""
    flow = CONFIG.replace(
        "  scan_age:\n    type: double\n    age_of: obstacle\n",
        "  scan_age: {type: double, age_of: obstacle}\n",
    ).replace(
        "  scan_hz:\n    type: double\n    rate_of: obstacle\n    window_ms: 100\n",
        "  scan_hz: {type: double, rate_of: obstacle, window_ms: 100}\n",
    )
    old, new = edit
    old, new = old.strip(), new.strip()
    text = flow.replace(old, new)
    assert text != flow
    err = _config_error(tmp_path, text)
    assert needle in err.message
    assert err.line == line_of(text, new)


@pytest.mark.parametrize(("edit", "needle"), LOCATED)
def test_age_and_rate_of_no_input_are_located_at_their_key(tmp_path, edit, needle):
    text = CONFIG.replace(*edit)
    assert text != CONFIG
    err = _config_error(tmp_path, text)
    assert needle in err.message
    assert err.line == line_of(text, edit[1].strip())


@pytest.mark.parametrize(
    ("edit", "needle", "key", "after"),
    [
        pytest.param(
            ("    call: response\n", ""), "call must be request or response",
            "service: /dock", None, id="service-without-call",
        ),
        pytest.param(
            ("    call: response\n", "    call: reply\n"), "call must be request or response",
            "call: reply", None, id="service-bad-call",
        ),
        pytest.param(
            ("    srv: std_srvs/srv/Trigger\n", ""), "needs srv",
            "service: /dock", None, id="service-without-srv",
        ),
        pytest.param(
            ("    initial: false\n", ""), "no value before the first response: give it initial",
            "service: /dock", None, id="service-field-without-initial",
        ),
        pytest.param(
            ("    field: success\n    initial: false\n", ""), "reads no field of the response",
            "service: /dock", None, id="service-neither-field-nor-event",
        ),
        pytest.param(
            ("  nav_active:\n    type: bool", "  nav_active:\n    type: double"),
            "not a double", "type: double", "nav_active:", id="action-double",
        ),
        pytest.param(
            ("    status: [accepted, executing]\n", ""), "needs status",
            "action: /navigate", None, id="action-without-status",
        ),
        pytest.param(
            ("status: [accepted, executing]", "status: [accepted, running]"),
            "unknown goal state 'running'", "status: [accepted, running]", None,
            id="action-unknown-state",
        ),
        pytest.param(
            ("  nav_active:\n    type: bool", "  nav_active:\n    type: int64\n    event: true"),
            "an event is bool", "event: true", "nav_active:", id="action-int64-event",
        ),
        pytest.param(
            ("    age_of: obstacle\n", "    age_of: obstacle\n    topic: /scan\n"),
            "has both topic and age_of", "age_of: obstacle", None, id="two-sources-topic-age",
        ),
        pytest.param(
            ("    rate_of: obstacle\n", "    rate_of: obstacle\n    action: /navigate\n"),
            "has both action and rate_of", "rate_of: obstacle", None, id="two-sources-action-rate",
        ),
        pytest.param(
            ("    field: ranges[0]\n", "    field: ranges[0]\n    window_ms: 50\n"),
            "window_ms does not go with topic", "window_ms: 50", None, id="window_ms-beside-topic",
        ),
        pytest.param(
            ("    status: [accepted, executing]\n", "    status: [accepted, executing]\n    field: x\n"),
            "field does not go with action", "field: x", None, id="field-beside-action",
        ),
        pytest.param(
            ("    age_of: obstacle\n", "    age_of: obstacle\n    window_ms: 50\n"),
            "window_ms does not go with age_of", "window_ms: 50", None, id="window_ms-beside-age",
        ),
        pytest.param(
            ("    window_ms: 100\n", "    window_ms: 100\n    stamp: header.stamp\n"),
            "stamp does not go with rate_of", "stamp: header.stamp", None, id="stamp-beside-rate",
        ),
        pytest.param(
            ("    call: response\n", "    call: response\n    msg: std_srvs/srv/Trigger_Event\n"),
            "msg does not go with service", "msg: std_srvs", None, id="msg-beside-service",
        ),
        pytest.param(
            ("    window_ms: 100", "    window_ms: -5"), "window_ms must be positive",
            "window_ms: -5", None, id="window_ms-negative",
        ),
        pytest.param(
            ("    window_ms: 100", "    window_ms: 0"), "window_ms must be positive",
            "window_ms: 0", None, id="window_ms-zero",
        ),
        pytest.param(
            ("    window_ms: 100", "    window_ms: 3600001"), "window_ms must be at most",
            "window_ms: 3600001", None, id="window_ms-over-an-hour",
        ),
        pytest.param(
            ("  scan_age:\n    type: double", "  scan_age:\n    type: int64"),
            "age_of is in milliseconds, a double", "type: int64", "scan_age:", id="age-int64",
        ),
        pytest.param(
            ("  scan_hz:\n    type: double", "  scan_hz:\n    type: bool"),
            "rate_of is in messages per second", "type: bool", "scan_hz:", id="rate-bool",
        ),
        pytest.param(
            ("    age_of: obstacle\n", "    age_of: obstacle\n    stamp: header..stamp\n"),
            "is not a field path", "stamp: header..stamp", None, id="stamp-no-path",
        ),
        pytest.param(
            ("    field: ranges[0]\n", "    field: ranges[0\n"),
            "is not a field path", "field: ranges[0", None, id="field-no-path",
        ),
    ],
)  # fmt: skip
def test_config_errors_are_located_at_the_offending_key(tmp_path, edit, needle, key, after):
    text = CONFIG.replace(*edit)
    assert text != CONFIG
    err = _config_error(tmp_path, text)
    assert needle in err.message, err.message
    assert err.line == line_of(text, key, after), (str(err), text)


@pytest.mark.parametrize(
    ("edit", "name", "needles"),
    [
        (("field: ranges[0]", "field: rangez[0]"), "obstacle", ["no field 'rangez'"]),
        (
            ("field: ranges[0]", "field: range_min[0]"),
            "obstacle",
            ["'range_min[0]'", "not an array"],
        ),
        (("field: ranges[0]", "field: ranges"), "obstacle", ["'ranges'", "one value is needed"]),
        (("field: success", "field: message"), "docked", ["'message'", "cannot feed a bool"]),
        (
            ("    age_of: obstacle\n", "    age_of: obstacle\n    stamp: header.frame_id\n"),
            "scan_age",
            ["'header.frame_id'", "not a time stamp"],
        ),
    ],
)
def test_check_locates_type_errors_at_the_variable(tmp_path, edit, name, needles):
    text = CONFIG.replace(*edit)
    assert text != CONFIG
    path = write(tmp_path, text)
    err = project_for(path).first_error()
    assert err is not None
    assert err.message.startswith(f"variable '{name}': "), err.message
    for needle in needles:
        assert needle in err.message, err.message
    assert err.file == str(path) and err.line == line_of(text, f"  {name}:")


# ------------------------------------------------------------ 2. readers on random data

BOUNDS = (0.1, 30.0)
float32s = st.floats(width=32, allow_nan=True, allow_infinity=True)
readings = st.one_of(
    float32s,
    st.sampled_from([math.nan, math.inf, -math.inf, 0.0, 0.05, 0.1, 30.0, 31.0, -1.0]),
    st.floats(0.125, 30.0, width=32),
)


def make_scan(ranges: list[float], bounds: tuple[float, float] = BOUNDS) -> LaserScan:
    msg = LaserScan()
    msg.range_min, msg.range_max = bounds
    msg.ranges = ranges
    return msg


def plain_reduce(values: list[float], how: str, bounds: tuple[float, float] | None) -> Any:
    """What reduce: says, written out for lists (the docs' words, not the product's code)."""
    if how == "len":
        return len(values)
    kept = []
    for x in values:
        if x != x:
            continue
        if bounds is not None and not (
            x not in (math.inf, -math.inf) and bounds[0] <= x <= bounds[1]
        ):
            continue
        kept.append(x)
    if how == "count":
        return len(kept)
    if not kept:
        return {"min": math.inf, "max": -math.inf, "mean": math.nan, "sum": 0.0}[how]
    if how == "min":
        best = kept[0]
        for x in kept:
            best = x if x < best else best
        return best
    if how == "max":
        best = kept[0]
        for x in kept:
            best = x if x > best else best
        return best
    total = 0.0
    for x in kept:
        total += x
    return total if how == "sum" else total / len(kept)


def same(got: Any, want: Any, approx: bool = False) -> bool:
    if isinstance(want, float) and math.isnan(want):
        return isinstance(got, float) and math.isnan(got)
    if approx and isinstance(want, float) and math.isfinite(want):
        # float32 sums (numpy's pairwise order) against a double sum in list order
        return got == pytest.approx(want, rel=1e-5, abs=1e-4)
    return got == want and type(got) is type(want)


@settings(max_examples=300, deadline=None)
@given(
    ranges=st.lists(readings, max_size=40),
    bounds=st.sampled_from([BOUNDS, (0.0, 10.0), (1.0, 1.0)]),
    index=st.integers(-45, 45),
)
def test_laserscan_readers_equal_a_plain_reference(ranges, bounds, index):
    msg = make_scan(ranges, bounds)
    # a LaserScan holds float32: the values and bounds as the message holds them
    ranges = list(msg.ranges)
    bounds = (msg.range_min, msg.range_max)
    read = make_reader(scan_var(f"ranges[{index}]"))
    if -len(ranges) <= index < len(ranges):
        want = ranges[index]
        got = read(msg)
        assert got == want or (math.isnan(want) and math.isnan(got))
    else:
        with pytest.raises(ReadError) as e:
            read(msg)
        assert f"has {len(ranges)} elements" in str(e.value) and "ranges" in str(e.value)
    for how in ("min", "max", "mean", "sum", "count", "len"):
        vtype = "int64" if how in ("count", "len") else "double"
        v = scan_var("ranges", type=vtype, reduce=how)
        check_input(v)
        got = make_reader(v)(msg)
        want = plain_reduce(ranges, how, bounds)
        assert same(got, want, approx=how in ("sum", "mean")), (how, ranges, bounds, got, want)


def make_diagnostics(statuses: list[tuple[int, list[tuple[str, str]]]]) -> DiagnosticArray:
    msg = DiagnosticArray()
    msg.status = [
        DiagnosticStatus(
            level=bytes([level]),
            name=f"s{k}",
            values=[KeyValue(key=key, value=value) for key, value in pairs],
        )
        for k, (level, pairs) in enumerate(statuses)
    ]
    return msg


names = st.text(alphabet="abcxyz_", max_size=6)
diagnostics = st.lists(
    st.tuples(st.integers(0, 3), st.lists(st.tuples(names, names), max_size=4)), max_size=6
)


@settings(max_examples=200, deadline=None)
@given(statuses=diagnostics, index=st.integers(-8, 8))
def test_diagnostic_readers_equal_a_plain_reference(statuses, index):
    msg = make_diagnostics(statuses)
    levels = [level for level, _ in statuses]
    # status[].level: the max of the levels, how many there are
    want = {"max": max(levels) if levels else -math.inf, "count": len(levels), "len": len(levels)}
    for how, expected in want.items():
        v = diag_var("status[].level", reduce=how)
        check_input(v)
        got = make_reader(v)(msg)
        assert got == expected and type(got) is type(expected), (how, statuses, got)
    # status[N].level: one status's level, or no value past the end
    v = diag_var(f"status[{index}].level")
    check_input(v)
    if -len(statuses) <= index < len(statuses):
        assert make_reader(v)(msg) == bytes([statuses[index][0]])
    else:
        with pytest.raises(ReadError):
            make_reader(v)(msg)
    # status[].values: every status's key-value pairs, as one array
    pairs = sum((len(p) for _, p in statuses), 0)
    v = diag_var("status[].values", reduce="len")
    check_input(v)
    assert make_reader(v)(msg) == pairs
    # status[].values[].key: one key per pair, every status's
    from supervisor.inputs.paths import reader

    keys = [key for _, p in statuses for key, _ in p]
    assert reader(parse_path("status[].values[].key"))(msg) == keys


def test_reduce_over_every_key_counts_keys_not_characters():
    msg = make_diagnostics([(0, [("abc", "1"), ("de", "2")]), (1, []), (2, [("f", "3")])])
    for how in ("len", "count"):
        v = diag_var("status[].values[].key", reduce=how)
        check_input(v)
        assert make_reader(v)(msg) == 3, how


# ------------------------------------------------------------ 3. services and actions


def trigger_event(event_type: int, success: bool | None = True, contents: bool = True) -> Any:
    msg = Trigger_Event()
    msg.info = ServiceEventInfo(event_type=event_type, sequence_number=7)
    if contents:
        msg.request = [Trigger.Request()]
        if event_type >= 2:
            msg.response = [Trigger.Response(success=bool(success), message="docked")]
    return msg


REQUEST_SENT, REQUEST_RECEIVED, RESPONSE_SENT, RESPONSE_RECEIVED = 0, 1, 2, 3


def test_service_readers_take_their_direction_only():
    docked = make_reader(service_var("response", field="success", initial=False))
    called = make_reader(service_var("request", event=True))
    answered = make_reader(service_var("response", event=True))
    for k in (REQUEST_SENT, REQUEST_RECEIVED):
        assert docked(trigger_event(k)) is SKIP
        assert called(trigger_event(k)) is True
        assert answered(trigger_event(k)) is SKIP
    for k in (RESPONSE_SENT, RESPONSE_RECEIVED):
        assert docked(trigger_event(k, success=True)) is True
        assert docked(trigger_event(k, success=False)) is False
        assert called(trigger_event(k)) is SKIP
        assert answered(trigger_event(k)) is True


def test_a_request_field_is_read_from_requests_only():
    v = service_var("request", srv="SetBool", field="data", initial=False)
    check_input(v)
    read = make_reader(v)
    for k, data in ((REQUEST_SENT, True), (REQUEST_RECEIVED, False)):
        msg = SetBool_Event(info=ServiceEventInfo(event_type=k))
        msg.request = [SetBool.Request(data=data)]
        assert read(msg) is data
    msg = SetBool_Event(info=ServiceEventInfo(event_type=RESPONSE_SENT))
    msg.request = [SetBool.Request(data=True)]
    msg.response = [SetBool.Response(success=True)]
    assert read(msg) is SKIP


def test_a_metadata_only_event_has_no_field_but_is_an_event():
    docked = make_reader(service_var("response", field="success", initial=False))
    with pytest.raises(ReadError) as e:
        docked(trigger_event(RESPONSE_SENT, contents=False))
    assert "no contents" in str(e.value) and "response" in str(e.value)
    # its own direction's part is what must be there
    half = trigger_event(RESPONSE_RECEIVED)
    half.request = []
    assert docked(half) is True
    # an event needs no contents
    answered = make_reader(service_var("response", event=True))
    assert answered(trigger_event(RESPONSE_SENT, contents=False)) is True
    # the other direction's metadata-only event is skipped, not an error
    assert docked(trigger_event(REQUEST_SENT, contents=False)) is SKIP


def goal(n: int, status: str) -> GoalStatus:
    codes = {"accepted": 1, "executing": 2, "canceling": 3, "succeeded": 4, "canceled": 5,
             "aborted": 6}  # fmt: skip
    uuid = UUID(uuid=[n] * 8 + [255 - n] * 8)
    return GoalStatus(goal_info=GoalInfo(goal_id=uuid), status=codes[status])


def statuses(*goals: tuple[int, str]) -> GoalStatusArray:
    return GoalStatusArray(status_list=[goal(n, s) for n, s in goals])


# (message, active: any accepted|executing, executing: count, aborted: entered)
TIMELINE = [
    (statuses((1, "accepted")), True, 0, SKIP),
    (statuses((1, "executing")), True, 1, SKIP),
    (statuses((1, "aborted")), False, 0, True),
    # goal 1 stays aborted while the server keeps it: no new event
    (statuses((1, "aborted"), (2, "accepted")), True, 0, SKIP),
    (statuses((1, "aborted"), (2, "executing")), True, 1, SKIP),
    (statuses((1, "aborted"), (2, "executing"), (3, "executing")), True, 2, SKIP),
    # two goals abort in one message: one event
    (statuses((1, "aborted"), (2, "aborted"), (3, "aborted")), False, 0, True),
    (statuses((2, "aborted"), (3, "aborted")), False, 0, SKIP),
    (statuses((2, "aborted"), (3, "succeeded")), False, 0, SKIP),
    (statuses(), False, 0, SKIP),
    # a goal id not in the previous message that is aborted: entered
    (statuses((2, "aborted")), False, 0, True),
    (statuses((2, "aborted"), (4, "canceling")), False, 0, SKIP),
    (statuses((2, "aborted"), (4, "aborted")), False, 0, True),
]


def test_action_goal_states_over_a_sequence_of_status_messages():
    active = action_var("bool", ("accepted", "executing"))
    executing = action_var("int64", ("executing",))
    aborted = action_var("bool", ("aborted",), event=True)
    for v in (active, executing, aborted):
        check_input(v)
    readers = [make_reader(v) for v in (active, executing, aborted)]
    for k, (msg, *want) in enumerate(TIMELINE):
        got = [r(msg) for r in readers]
        assert got[0] is want[0] and got[1] == want[1] and type(got[1]) is int, k
        assert got[2] is want[2], (k, got)
    # each variable has a reader of its own: a new one has seen nothing
    fresh = make_reader(aborted)
    assert fresh(statuses((1, "aborted"))) is True


# ------------------------------------------------------------ 4. ages and rates in the runtime


def test_an_age_is_the_tick_time_minus_the_stamp_and_grows_between_messages():
    mon = RecordingMonitor(2)
    spec = [
        InputSpec("obstacle", "double"),
        InputSpec("age", "double", kind="age", sporadic=True),
    ]
    rt = Runtime(spec, mon, policy="periodic", period_ns=10 * MS)
    t0 = 1_000 * MS
    assert rt.on_timer(t0) is None  # no value yet: nothing is ticked
    # scans at +3 ms (stamped 2 ms before), +25 ms (stamped 20 ms before, a late driver)
    # and +41 ms carrying the same stamp as the one before (a frozen driver)
    stamps = {3: t0 + 1 * MS, 25: t0 + 5 * MS, 41: t0 + 5 * MS}
    expected, stamp = [], None
    for ms in range(1, 80):
        t = t0 + ms * MS
        if ms in stamps:
            _, events = rt.on_values((("obstacle", 1.0), ("age", stamps[ms])), t)
            assert events == []
            stamp = stamps[ms]
        if ms % 10 == 0:
            res = rt.on_timer(t)
            assert res is not None
            expected.append((t - stamp) / 1e6)
            assert res.inputs["age"] == expected[-1]
    assert [v[1] for v in mon.ticks] == expected
    assert expected == [9.0, 19.0, 25.0, 35.0, 45.0, 55.0, 65.0]
    assert rt.input_stats()["age"]["messages"] == 3 and rt.input_stats()["age"]["future"] == 0


def test_a_stamp_ahead_of_its_receipt_gives_a_negative_age_and_is_said():
    mon = RecordingMonitor(2)
    spec = [InputSpec("age", "double", kind="age", sporadic=True)]
    rt = Runtime(spec, mon, policy="on_message")
    t = 5_000 * MS
    # exactly the tolerance ahead: no event
    res, events = rt.on_message("age", t + FUTURE_TOLERANCE_NS, t)
    assert events == [] and res is not None and res.inputs["age"] == -1.0
    res, events = rt.on_message("age", t + 10 * MS + FUTURE_TOLERANCE_NS + 1, t + 10 * MS)
    assert [(e.what, e.name, e.t_ns) for e in events] == [
        ("input_future_stamp", "age", t + 10 * MS)
    ]
    assert "after its receipt" in events[0].detail
    assert res is not None and res.inputs["age"] == pytest.approx(-1.000001)
    res, events = rt.on_message("age", t + 70 * MS, t + 20 * MS)
    assert [e.what for e in events] == ["input_future_stamp"] and res.inputs["age"] == -50.0
    assert "50.0 ms" in events[0].detail
    assert rt.input_stats()["age"]["future"] == 2
    assert [v[0] for v in mon.ticks] == [-1.0, pytest.approx(-1.000001), -50.0]


def rate_runtime(window_ms: int, initial: float | None = None) -> tuple[Runtime, RecordingMonitor]:
    mon = RecordingMonitor(2)
    spec = [
        InputSpec("flag", "bool", initial=False),
        InputSpec(
            "hz", "double", initial=initial, kind="rate", sporadic=True, window_ns=window_ms * MS
        ),
    ]
    return Runtime(spec, mon, policy="periodic", period_ns=10 * MS), mon


def plain_rate(arrivals: list[int], t: int, window: int) -> float:
    n = len([a for a in arrivals if t - window < a <= t])
    return n * 1e9 / window


@pytest.mark.parametrize("initial", [None, 7.0])
def test_a_rate_counts_the_messages_of_its_window(initial):
    window = 100 * MS
    rt, mon = rate_runtime(100, initial)
    t0 = 2_000 * MS
    # arrivals: a burst, one exactly on a tick, then silence, then one per 30 ms
    arrivals_ms = [5, 6, 7, 30, 50, 99, 100, 100, 170, 300, 330, 360, 390]
    arrivals = [t0 + a * MS for a in arrivals_ms]
    got: list[tuple[int, float]] = []
    k = 0
    for ms in range(0, 500, 10):
        t = t0 + ms * MS
        # a message received at a tick's time comes after that tick (a timer runs
        # at its deadline before later work): feed it after the tick
        while k < len(arrivals) and arrivals[k] < t:
            rt.on_message("hz", None, arrivals[k])
            k += 1
        res = rt.on_timer(t)
        if res is not None:
            got.append((ms, res.inputs["hz"]))
    want = []
    for ms in range(0, 500, 10):
        t = t0 + ms * MS
        if ms < 110:  # known a whole window after its first message (t0 + 5 ms)
            if initial is not None:
                want.append((ms, initial))
            continue
        seen = [a for a in arrivals if a < t]  # those fed before the tick
        want.append((ms, plain_rate(seen, t, window)))
    assert got == want
    assert [v[1] for v in mon.ticks] == [r for _, r in want]
    # the window is (t - window, t]: at +200 ms the two arrivals at +100 ms are out
    assert dict(got)[110] == 5 * 10.0 and dict(got)[120] == 5 * 10.0
    assert dict(got)[200] == 1 * 10.0
    assert dict(got)[280] == 0.0  # silent for a whole window: rate 0


def test_a_rate_is_not_ready_before_a_whole_window():
    rt, mon = rate_runtime(50)
    t0 = 10 * MS
    rt.on_timer(t0)
    for k in range(1, 7):  # a message every 10 ms; known 50 ms after the first
        rt.on_message("hz", None, t0 + k * 10 * MS - 1)
        res = rt.on_timer(t0 + k * 10 * MS)
        if k < 6:
            assert res is None and rt.missing_inputs() == ["hz"], k
    assert res is not None and res.inputs["hz"] == 5 * 1e9 / (50 * MS)
    assert len(mon.ticks) == 1


SPORADIC = """\
component: base
step: {policy: periodic, period_ms: 10, stale_after_ms: 100}
variables:
  obstacle: {type: double, topic: /scan, msg: sensor_msgs/msg/LaserScan, field: "ranges[0]"}
  scan_age: {type: double, age_of: obstacle}
  scan_hz: {type: double, rate_of: obstacle, window_ms: 100, initial: 0.0}
  docked: {type: bool, service: /dock, srv: std_srvs/srv/Trigger, call: response, field: success, initial: false}
  called: {type: bool, service: /dock, srv: std_srvs/srv/Trigger, call: request, event: true}
  nav_active: {type: bool, action: /navigate, status: [accepted, executing]}
  nav_aborted: {type: bool, action: /navigate, status: aborted, event: true}
  nav_own: {type: bool, action: /navigate, status: executing, stale_after_ms: 300}
requirements:
  - id: fresh
    text: base shall always satisfy scan_age < 300 & scan_hz >= 0 & obstacle > 0
  - id: dock
    text: base shall always satisfy (nav_active | nav_aborted | nav_own | called) -> docked
on_stale: [note]
mitigations:
  note: {log: {message: stale}}
"""


@pytest.fixture(scope="module")
def sporadic_project(tmp_path_factory: pytest.TempPathFactory) -> Any:
    d = tmp_path_factory.mktemp("inputs")
    p = project_for(write(d, SPORADIC), ros=False)
    assert p.ok, p.first_error()
    return p


def test_sporadic_inputs_are_stale_by_their_own_limit_only(sporadic_project):
    session = build_session(sporadic_project, RecordingMonitor(2))
    rt = session.runtime
    kinds = {s.name: (s.kind, s.sporadic) for s in rt.inputs}
    assert kinds == {
        "obstacle": ("value", False),
        "scan_age": ("age", True),
        "scan_hz": ("rate", True),
        "docked": ("value", True),
        "called": ("event", True),
        "nav_active": ("value", True),
        "nav_aborted": ("event", True),
        "nav_own": ("value", True),
    }
    default = 100 * MS
    t = 1_000 * MS
    rt.on_timer(t)
    rt.on_values((("obstacle", 1.0), ("scan_age", t), ("scan_hz", None)), t + MS)
    rt.on_message("docked", True, t + MS)
    rt.on_message("called", True, t + MS)
    rt.on_message("nav_active", True, t + MS)
    rt.on_message("nav_aborted", True, t + MS)
    rt.on_message("nav_own", True, t + MS)
    # the step's stale_after_ms: only the plain value goes stale
    events = rt.check_stale(t + MS + default + 1, default)
    assert [(e.what, e.name) for e in events] == [("input_stale", "obstacle")]
    assert rt.stale_after("scan_age", default) is None
    assert rt.stale_after("docked", default) is None
    assert rt.stale_after("nav_own", default) == 300 * MS
    # long silence: still only the ones with a limit of their own
    assert rt.check_stale(t + 250 * MS, default) == []
    events = rt.check_stale(t + MS + 300 * MS + 1, default)
    assert [(e.what, e.name) for e in events] == [("input_stale", "nav_own")]
    assert sorted(rt.stale_inputs()) == ["nav_own", "obstacle"]
    assert rt.stale_due(default) is None  # nothing else will ever go stale
    # the scan's next message: the value recovers, nav_own stays stale
    rt.on_values((("obstacle", 1.0), ("scan_age", t + 500 * MS), ("scan_hz", None)), t + 501 * MS)
    assert sorted(rt.stale_inputs()) == ["nav_own"]


def test_the_core_says_future_stamps_and_no_staleness_of_sporadic_inputs(sporadic_project):
    mon = RecordingMonitor(2)
    log = MemoryLog()
    acts: list[str] = []
    session = build_session(sporadic_project, mon)
    core = Core(session, log, lambda req: acts.append(req.requirement), warn=lambda _text: None)
    t = 1_000 * MS
    core.start(t)
    core.fields((("obstacle", 1.0), ("scan_age", t + 3 * MS), ("scan_hz", None)), t + MS)
    core.fields((("nav_active", False), ("nav_own", False)), t + 2 * MS)
    core.fields((("docked", True),), t + 3 * MS)
    # one future stamp, then silence; the plain value goes stale by the step's limit
    core.advance(t + 400 * MS)
    said = [(r["what"], r.get("input"), r.get("count")) for r in log.of("supervisor")]
    assert ("input_future_stamp", "scan_age", 1) in said
    assert [i for what, i, _ in said if what == "input_stale"] == ["obstacle", "nav_own"]
    assert acts == ["on_stale:obstacle", "on_stale:nav_own"]
    # ages at each tick: from the tick at +10 ms on, (tick - stamp) / 1e6
    ages = [v[1] for v in mon.ticks]
    assert ages[0] == (t + 10 * MS - (t + 3 * MS)) / 1e6 == 7.0
    assert ages[1:4] == [17.0, 27.0, 37.0]
    # the first tick (at +0) came before any message: 40 ticks from +10 to +400
    assert len(mon.ticks) == 40


def test_the_max_of_no_status_is_rejected_by_an_int64_input():
    """The reader says the worst level of an empty DiagnosticArray is -inf (nothing
    seen); an int64 cannot hold it: the daemon rejects it and keeps the last level."""
    v = diag_var("status[].level", reduce="max")
    read = make_reader(v)
    rt = Runtime([InputSpec("diag", "int64")], RecordingMonitor(2), policy="on_message")
    res, events = rt.on_message("diag", read(make_diagnostics([(2, [])])), 0)
    assert res is not None and res.inputs["diag"] == 2
    worst = read(make_diagnostics([]))
    assert worst == -math.inf
    res, events = rt.on_message("diag", worst, MS)
    assert res is None and [(e.what, e.name) for e in events] == [("input_rejected", "diag")]
    assert rt.snapshot()["diag"] == 2


def test_a_byte_field_feeds_an_int64_as_its_number():
    # rclpy gives byte/octet/char fields as one-byte bytes (DiagnosticStatus.level)
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    from supervisor.daemon.runtime import coerce

    msg = DiagnosticArray(status=[DiagnosticStatus(level=b"\x02")])
    v = diag_var("status[0].level")
    check_input(v)
    raw = make_reader(v)(msg)
    assert raw == b"\x02" and coerce(raw, "int64") == (2, None)
    assert coerce(b"\x02\x03", "int64")[1] is not None  # not one byte: not a number
