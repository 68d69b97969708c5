"""The shipped monitor double (supervisor.daemon.testing): the runtime steps it as
it steps a compiled monitor, and what it flags is the step's verdict."""

from __future__ import annotations

import pytest

from supervisor.daemon.runtime import InputSpec, Runtime
from supervisor.daemon.testing import RecordingMonitor

MS = 1_000_000


def test_the_runtime_steps_it_and_takes_its_flags() -> None:
    # requirement 0: x stays below 3; requirement 1 never fires
    mon = RecordingMonitor(2, lambda values: [int(values[0] >= 3), 0])
    rt = Runtime([InputSpec("x", "int64")], mon, policy="on_message")
    verdicts = []
    for t, x in enumerate([1, 2, 5, 2]):
        result, _events = rt.on_values([("x", x)], (t + 1) * MS)
        assert result is not None
        verdicts.append(result.violated)
    assert mon.ticks == [[1], [2], [5], [2]]
    assert verdicts == [[], [], [0], []]
    rt.reset_requirement(0)
    rt.reset_all()
    assert mon.resets == [0, None]


def test_a_wrong_number_of_flags_is_said() -> None:
    mon = RecordingMonitor(2, lambda values: [0])
    with pytest.raises(ValueError, match="1 flags for 2 requirements"):
        mon.tick([0])


def test_the_interpreted_monitor_judges_real_formulas_and_resets_per_requirement() -> None:
    from monitors.ir.formula import parse_formula
    from monitors.ir.spec import MonitorSpec, RequirementSpec, VarDecl
    from supervisor.daemon.testing import InterpretedMonitor

    spec = MonitorSpec(
        component="T",
        inputs=[VarDecl("p", "bool"), VarDecl("x", "int64")],
        requirements=[
            RequirementSpec("always_p", parse_formula("H p")),  # latches once p was false
            RequirementSpec("small", parse_formula("x < 3")),
        ],
    )
    mon = InterpretedMonitor(spec)
    rt = Runtime([InputSpec("p", "bool"), InputSpec("x", "int64")], mon, policy="on_message")
    seen = []
    for t, (p, x) in enumerate([(True, 1), (False, 5), (True, 1), (True, 1)]):
        rt.on_message("p", p, (2 * t + 1) * MS)
        result, _ = rt.on_values([("x", x)], (2 * t + 2) * MS)
        assert result is not None
        seen.append(result.violated)
    assert seen == [[], [0, 1], [0], [0]]  # H p stays violated, x < 3 does not
    rt.reset_requirement(0)  # H p judged afresh: p holds since the reset
    result, _ = rt.on_values([("x", 1)], 20 * MS)
    assert result is not None and result.violated == []
