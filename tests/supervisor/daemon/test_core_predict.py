"""Predictions in the monitoring core (docs/reference/prediction.md): a real gcc-built
monitor with margins, the shared Core, the policy machinery.  A person walks toward
the lamp while it is on (the sRobot's "distance >= 3 m while UV on")."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from projects import project_of

from mitigations.violationlog.testing import MemoryLog
from monitors.backends.load import compile_spec
from monitors.ir.formula import to_fret
from supervisor.daemon.core import Core
from supervisor.daemon.session import build_session

MS = 1_000_000
PERIOD_MS = 20

CONFIG = """\
component: lamp
step: {policy: periodic, period_ms: 20}
variables:
  distance: {type: double, topic: /distance, msg: std_msgs/msg/Float64}
  uv_on: {type: bool, topic: /uv, msg: std_msgs/msg/Bool}
requirements:
  - id: keep_away
    text: lamp shall always satisfy uv_on -> distance >= 3.0
    on_violation: [halt]
    policy: {reset: after_mitigation, cooldown_ms: 200}
    predict: {horizon_ms: 1500, window_ms: 500, actions: [slow], min_confidence: 0.9}
mitigations:
  halt: {log: {message: halt}}
  slow: {log: {message: slow}}
"""


@pytest.fixture(scope="module")
def project(tmp_path_factory: pytest.TempPathFactory) -> Any:
    return project_of(tmp_path_factory.mktemp("predict"), CONFIG)


def _run(
    request: pytest.FixtureRequest, project: Any, distance_at: Any, end_ms: int
) -> list[tuple[Any, ...]]:
    """The core's records and action requests, in order, for a person at
    ``distance_at(t_ms)`` metres, one message each 20 ms, the lamp on throughout."""
    p, d = project
    monitor = compile_spec(p.spec(), Path(d) / f"build{id(distance_at)}")
    out: list[tuple[Any, ...]] = []
    log = MemoryLog(lambda r: out.append(("record", r)))
    session = build_session(p, monitor)
    assert session.cleanup is not None
    request.addfinalizer(session.cleanup)
    core = Core(
        session,
        log,
        lambda req: out.append(("act", req.actions, req.stage, req.detected_ns)),
        warn=lambda _text: None,
    )
    core.start(0)
    core.message("uv_on", True, 0)
    for t_ms in range(0, end_ms, PERIOD_MS):
        core.message("distance", float(distance_at(t_ms)), t_ms * MS + 1)
    core.advance(end_ms * MS)
    return out


def _records(out: list[tuple[Any, ...]], event: str) -> list[dict[str, Any]]:
    return [x[1] for x in out if x[0] == "record" and x[1]["event"] == event]


def test_an_approach_is_predicted_before_the_violation_and_acted_on_early(request, project) -> None:
    # 8 m away, walking in at 1 m/s: 3 m is crossed at 5 s.
    out = _run(request, project, lambda t: 8.0 - t / 1000.0, 6000)
    (pred,) = _records(out, "prediction")
    viol, *later = _records(out, "violation")  # reset after_mitigation: one a tick after
    assert all("predicted_ms" not in v for v in later)  # the prediction was used up
    assert not _records(out, "prediction_expired")
    # A straight walk: the time to violation is exact, within a tick.
    t_pred_ms = pred["tick"] * PERIOD_MS
    assert abs(pred["ttv_ms"] - (5000 - t_pred_ms)) <= PERIOD_MS
    assert pred["ttv_ms"] <= 1500 and pred["confidence"] >= 0.9
    assert pred["slope"] == pytest.approx(-1.0, rel=1e-6)
    assert pred["margin"] > 0 and pred["inputs"]["uv_on"] is True
    # The record, then the early action, then the violation with its lead time.
    i_pred = out.index(("record", pred))
    early = [x for x in out if x[0] == "act" and x[2] == "prediction"]
    assert early == [("act", ("slow",), "prediction", early[0][3])]
    assert i_pred < out.index(early[0]) < out.index(("record", viol))
    assert viol["predicted_ms"] == pytest.approx((viol["tick"] - pred["tick"]) * PERIOD_MS)
    assert viol["predicted_ms"] >= 1400
    assert viol["policy_state"]["predicted_tick"] == pred["tick"]


def test_a_prediction_not_followed_by_a_violation_expires(request, project) -> None:
    # In at 1 m/s, then standing at 3.4 m: never closer than 3 m.
    out = _run(request, project, lambda t: max(8.0 - t / 1000.0, 3.4), 8000)
    preds = _records(out, "prediction")
    assert len(preds) == 1
    assert not _records(out, "violation")
    (expired,) = _records(out, "prediction_expired")
    assert expired["predicted_tick"] == preds[0]["tick"]
    assert 1500 < expired["after_ms"] <= 1500 + PERIOD_MS  # the first step past it
    assert out.index(("record", preds[0])) < out.index(("record", expired))


def test_standing_or_walking_away_predicts_nothing(request, project) -> None:
    for walk in (lambda t: 6.0, lambda t: 4.0 + t / 1000.0):
        out = _run(request, project, walk, 4000)
        assert not _records(out, "prediction")
        assert not [x for x in out if x[0] == "act"]


def test_the_prediction_fits_the_invariant_not_its_running_minimum(request, project) -> None:
    p, _ = project
    spec = p.prediction_spec()
    assert spec.margins and not p.spec().margins  # the boolean monitor is unchanged
    assert to_fret(spec.requirements[0].formula) == "(uv_on -> (distance >= 3.0))"

    # A near miss (in to 3.2 m and away), then a walk all the way in: H's margin would
    # stay at 0.2 m after the near miss and warn 200 ms ahead; the invariant's margin
    # follows the walk back out and in, and warns as early as the first time.
    def walk(t: int) -> float:
        if t < 9600:
            return max(8.0 - t / 1000.0, 3.2) if t < 6000 else 3.2 + (t - 6000) / 1000.0
        return 6.8 - (t - 9600) / 1000.0

    out = _run(request, project, walk, 15000)
    viol = _records(out, "violation")[0]
    assert viol["tick"] * PERIOD_MS == pytest.approx(9600 + 3800 + PERIOD_MS, abs=PERIOD_MS)
    assert viol["predicted_ms"] >= 1400
