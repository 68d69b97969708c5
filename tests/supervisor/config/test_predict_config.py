"""A requirement's ``predict:`` (docs/reference/prediction.md): its keys, types and
ranges, each error one line at the offending key, and the defaults."""

from __future__ import annotations

from pathlib import Path

import pytest

from mitigations.settings import PredictConfig
from monitors.errors import UserError
from supervisor.config import load_config

HEAD = "component: sw\nstep: {policy: periodic, period_ms: 100}\n"
VAR_D = "variables:\n  d: {type: double, topic: /d, msg: std_msgs/msg/Float64}\n"
MIT = "mitigations:\n  halt: {log: {message: x}}\n  slow: {log: {message: y}}\n"


def _config(predict: str) -> str:
    return (
        HEAD
        + VAR_D
        + "requirements:\n  - id: r1\n    text: sw shall always satisfy d > 3.0\n"
        + "    on_violation: [halt]\n"
        + predict
        + MIT
    )


RAISED = {
    "not a mapping": (
        "    predict: 1500\n",
        "{f}:9: predict must be a mapping",
    ),
    "unknown key": (
        "    predict: {horizon: 1500}\n",
        "{f}:9: unknown key 'horizon' in predict of 'r1' (hint: did you mean 'horizon_ms'?)",
    ),
    "horizon not a number": (
        "    predict:\n      horizon_ms: soon\n",
        "{f}:10: predict of 'r1'.horizon_ms must be a number, got 'soon'",
    ),
    "horizon zero": (
        "    predict:\n      horizon_ms: 0\n",
        "{f}:10: predict of 'r1'.horizon_ms must be positive",
    ),
    "window too long": (
        "    predict:\n      horizon_ms: 1500\n      window_ms: 120000\n",
        "{f}:11: predict of 'r1'.window_ms must be at most 60000 "
        "(hint: the trend is a straight line over the last window of margins)",
    ),
    "confidence above 1": (
        "    predict:\n      min_confidence: 1.5\n",
        "{f}:10: predict of 'r1'.min_confidence must be above 0 and at most 1, got 1.5 "
        "(hint: the probability that the margin is gone within the horizon)",
    ),
    "confidence not finite": (
        "    predict:\n      min_confidence: .nan\n",
        # the YAML loader refuses it first, as every number of the config
        "{f}:10:23: '.nan' is not a finite number "
        "(hint: every number in the config must be finite)",
    ),
    "undefined action": (
        "    predict:\n      horizon_ms: 1500\n      actions: [slwo]\n",
        "{f}:11: predict of 'r1': actions names undefined mitigation 'slwo' "
        "(hint: did you mean 'slow'?)",
    ),
    "actions not names": (
        "    predict:\n      actions: [1, 2]\n",
        "{f}:10: predict of 'r1': actions must be a list of mitigation names",
    ),
}


@pytest.mark.parametrize("case", sorted(RAISED))
def test_a_bad_predict_is_one_line_at_its_key(tmp_path: Path, case: str) -> None:
    predict, expected = RAISED[case]
    path = tmp_path / "c.yaml"
    path.write_text(_config(predict))
    with pytest.raises(UserError) as e:
        load_config(path)
    assert str(e.value) == expected.format(f=path)


def test_predict_is_read_into_the_policy(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text(
        _config(
            "    predict: {horizon_ms: 2000, window_ms: 400, actions: [slow], "
            "min_confidence: 0.8}\n"
        )
    )
    (r,) = load_config(path).requirements
    assert r.policy_config.predict == PredictConfig(2000.0, 400.0, ("slow",), 0.8)


@pytest.mark.parametrize("written", ["    predict:\n", "    predict: {}\n"])
def test_a_bare_predict_takes_the_defaults(tmp_path: Path, written: str) -> None:
    path = tmp_path / "c.yaml"
    path.write_text(_config(written))
    (r,) = load_config(path).requirements
    assert r.policy_config.predict == PredictConfig()
    assert PredictConfig().horizon_ms == 1500.0 and PredictConfig().window_ms == 1500.0


def test_without_predict_there_is_no_prediction(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text(_config(""))
    (r,) = load_config(path).requirements
    assert r.policy_config.predict is None
