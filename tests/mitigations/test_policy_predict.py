"""Predictions through the policy machinery (mitigations/policy.py): debounce and
cooldown of the early actions, one open prediction, expiry, and the lead time the
violation carries.  The policy is pure, so it is stepped here margin by margin (the
core's test runs it on a gcc-built monitor: tests/supervisor/daemon/)."""

from __future__ import annotations

from mitigations.policy import Act, Effect, Forecast, Report, RequirementPolicy
from mitigations.settings import PolicyConfig, PredictConfig

MS = 1_000_000
PERIOD_MS = 20
PREDICT = PredictConfig(horizon_ms=1000, window_ms=200, actions=("slow",), min_confidence=0.9)


def _policy(**policy: object) -> RequirementPolicy:
    return RequirementPolicy(PolicyConfig(predict=PREDICT, **policy), ("halt",))  # type: ignore[arg-type]


def _walk(pol: RequirementPolicy, margins: list[float], t0_ms: int = 0) -> list[tuple[int, Effect]]:
    """Each margin is one step (its violation when <= 0); the effects with their time."""
    out: list[tuple[int, Effect]] = []
    for k, m in enumerate(margins):
        t_ms = t0_ms + k * PERIOD_MS
        tick = t_ms // PERIOD_MS
        effects = pol.on_margin(m, m <= 0, tick, t_ms * MS)
        effects += pol.on_step(m <= 0, tick, t_ms * MS, {})
        out += [(t_ms, e) for e in effects]
    return out


def _approach(from_m: float, speed: float, to_m: float) -> list[float]:
    """Margins of a straight walk, one a step, until ``to_m``."""
    out, m = [], from_m
    while m > to_m:
        out.append(round(m, 6))
        m -= speed * PERIOD_MS / 1000
    return out


def test_the_violation_carries_the_lead_of_the_prediction_before_it() -> None:
    effects = _walk(_policy(), _approach(3.0, 1.0, -0.5))
    kinds = [(type(e).__name__, getattr(e, "what", getattr(e, "stage", ""))) for _, e in effects]
    assert kinds[:3] == [("Forecast", "prediction"), ("Act", "prediction"), ("Report", "")]
    (t_pred, pred), (t_act, act), (t_viol, viol) = effects[:3]
    assert isinstance(act, Act) and act.actions == ("slow",) and t_act == t_pred
    assert isinstance(viol, Report) and viol.predicted_ms == t_viol - t_pred
    assert isinstance(pred, Forecast) and abs(pred.detail["ttv_ms"] - 1000) <= PERIOD_MS
    assert viol.policy_state["predicted_tick"] == pred.detail["tick"]


def test_debounce_steps_hold_a_prediction_back() -> None:
    once = _walk(_policy(), _approach(3.0, 1.0, 0.1))
    twice = _walk(_policy(debounce_steps=3), _approach(3.0, 1.0, 0.1))
    (t1, _), (t3, _) = once[0], twice[0]
    assert t3 - t1 == 2 * PERIOD_MS


def test_early_actions_keep_their_cooldown_and_never_hold_back_the_violation() -> None:
    pol = _policy(cooldown_ms=10_000)
    # in to 0.2, back out, in again within the cooldown
    margins = _approach(3.0, 1.0, 0.2) + [0.2] * 60 + [0.2 + 0.02 * k for k in range(100)]
    first = _walk(pol, margins)
    again = _walk(pol, _approach(2.2, 1.0, -0.1), t0_ms=len(margins) * PERIOD_MS)
    forecasts = [e for _, e in first + again if isinstance(e, Forecast)]
    assert [f.what for f in forecasts] == ["prediction", "prediction_expired", "prediction"]
    assert forecasts[2].detail["cooldown"] == "suppressed"
    acts = [e for _, e in first + again if isinstance(e, Act)]
    # one early action (the second is within the cooldown), then the violation's own
    assert [(a.stage, a.actions) for a in acts] == [
        ("prediction", ("slow",)),
        ("violation", ("halt",)),
    ]


def test_a_rising_or_flat_margin_opens_nothing() -> None:
    pol = _policy()
    assert _walk(pol, [1.0 + 0.01 * k for k in range(100)] + [2.0] * 100) == []
    assert pol.predicted_ns is None and pol.predictions == 0
