"""The thesis's sRobot monitor, compiled from config/srobot.yaml, on hand traces."""

import random
from pathlib import Path

import pytest

from monitors.backends.load import compile_spec
from monitors.verify.interpret import verdicts
from supervisor.pipeline import project_for

ROOT = Path(__file__).resolve().parents[2]
INPUTS = ["classifier", "distance_to_target", "OpState", "alert", "halt", "slowdown", "turnoffUVC"]
# Outputs of a correct safety controller in each OpState (thesis Tables 7, 8).
OUTPUTS = {
    0: dict(alert=False, halt=False, slowdown=False, turnoffUVC=False),
    1: dict(alert=True, halt=False, slowdown=False, turnoffUVC=False),
    2: dict(alert=True, halt=False, slowdown=True, turnoffUVC=False),
    3: dict(alert=False, halt=True, slowdown=False, turnoffUVC=True),
}


@pytest.fixture(scope="module")
def srobot(tmp_path_factory):
    project = project_for(ROOT / "config" / "srobot.yaml", ros=False)
    assert project.ok, project.first_error()
    spec = project.spec()
    assert [v.name for v in spec.inputs] == INPUTS
    return spec, compile_spec(spec, tmp_path_factory.mktemp("srobot"))


def row(classifier, distance, state, **override):
    values = dict(
        classifier=classifier, distance_to_target=distance, OpState=state, **OUTPUTS[state]
    )
    values.update(override)
    return values


def fired(spec, mon, values):
    flags = mon.tick([values[n] for n in INPUTS])
    return {r.id for r, f in zip(spec.requirements, flags, strict=True) if f}


def test_trained_worker_in_red_zone_with_slowdown_state(srobot):
    spec, mon = srobot
    mon.reset()
    # classifier=1 (trained), distance 2 m (red zone), but the controller chose OpState 2
    assert fired(spec, mon, row(1, 2, 2)) == {"state_req103"}


def test_correct_controller_is_silent(srobot):
    spec, mon = srobot
    mon.reset()
    for values in [
        row(0, 0, 0),
        row(1, 9, 1),
        row(1, 5, 2),
        row(1, 2, 3),
        row(2, 9, 2),
        row(2, 5, 3),
        row(2, 1, 3),
    ]:
        assert fired(spec, mon, values) == set(), values


def test_uv_fault_in_stop_state(srobot):
    spec, mon = srobot
    mon.reset()
    # the thesis's field-test fault: OpState 3 but the UV light stays on
    assert fired(spec, mon, row(2, 1, 3, turnoffUVC=False)) == {"operationalstate_3"}


def test_unknown_class_breaks_the_assumption_only(srobot):
    spec, mon = srobot
    mon.reset()
    assert fired(spec, mon, row(3, 5, 0)) == {"classifier_assumption"}


def test_always_latches_until_the_requirement_is_reset(srobot):
    spec, mon = srobot
    mon.reset()
    assert fired(spec, mon, row(1, 2, 2)) == {"state_req103"}
    assert fired(spec, mon, row(1, 2, 3)) == {"state_req103"}  # H latches: the thesis's problem
    mon.reset_requirement("state_req103")
    assert fired(spec, mon, row(1, 2, 3)) == set()  # judged afresh
    assert fired(spec, mon, row(1, 2, 2)) == {"state_req103"}  # and the very next violation is seen


def test_matches_interpreter_on_random_srobot_traces(srobot):
    spec, mon = srobot
    rng = random.Random(7)
    for _ in range(20):
        mon.reset()
        trace = []
        for _ in range(rng.randint(1, 60)):
            state = rng.choice([0, 1, 2, 3])
            values = row(rng.choice([0, 1, 2, 3]), rng.randint(-1, 10), state)
            if rng.random() < 0.2:
                values[rng.choice(["alert", "halt", "slowdown", "turnoffUVC"])] ^= True
            trace.append(values)
        got = [mon.tick([v[n] for n in INPUTS]) for v in trace]
        for i, req in enumerate(spec.requirements):
            want = [not ok for ok in verdicts(spec.expanded(req), trace)]
            assert [bool(flags[i]) for flags in got] == want, req.id
