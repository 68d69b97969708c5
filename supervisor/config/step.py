"""The ``step:`` section: when the monitor is stepped (see supervisor.daemon.runtime)."""

from __future__ import annotations

import math
import re

from supervisor.config.fields import (
    as_mapping,
    check_keys,
    error_at,
    number,
    suggest,
    to_number,
)
from supervisor.config.model import StepConfig, Variable
from supervisor.config.yamlload import LineDict

STEP_POLICIES = ("periodic", "on_message", "on_trigger", "synchronized")
STEP_KEYS = {
    "policy", "trigger", "period_ms", "stale_after_ms", "max_skew_ms", "prefix", "recent",
    "margins",
}  # fmt: skip


def load_step(doc: LineDict) -> StepConfig:
    raw = doc.get("step")
    if raw is None:  # the default policy, periodic, has no default period
        raise error_at(
            "no 'step:' section: the monitor needs step.period_ms or another step.policy",
            doc,
            None,
            "e.g. step: {policy: periodic, period_ms: 100}",
        )
    s = as_mapping(raw, doc, "step", "step")
    check_keys(s, STEP_KEYS, "step")
    policy = str(s.get("policy", "periodic"))
    if policy not in STEP_POLICIES:
        raise error_at(
            f"unknown step policy '{policy}'", s, "policy", "one of: " + ", ".join(STEP_POLICIES)
        )
    step = StepConfig(
        policy=policy,
        trigger=str(s["trigger"]) if s.get("trigger") else None,
        period_ms=number(s, "period_ms", "step"),
        stale_after_ms=number(s, "stale_after_ms", "step"),
        max_skew_ms=number(s, "max_skew_ms", "step"),
        prefix=str(s.get("prefix") or ""),
        line=s.line,
    )
    if "margins" in s:
        step.margins = _margins(s)
    if policy == "periodic" and step.period_ms is None:
        raise error_at("step.policy periodic needs step.period_ms", s, "policy")
    if step.prefix and not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", step.prefix):
        raise error_at(f"step.prefix '{step.prefix}' is not a C identifier", s, "prefix")
    return step


def _margins(s: LineDict) -> float | None:
    """``step.margins``: false (off), true (a boolean atom's margin is infinite) or
    a number > 0 (a boolean atom's margin)."""
    v = s["margins"]
    if isinstance(v, bool):
        return math.inf if v else None
    x = to_number(v, s, "margins", "step.margins") if isinstance(v, int | float) else 0.0
    if not x > 0:
        raise error_at(f"step.margins must be true, false or a number > 0, got '{v}'", s, "margins")
    return x


def check_trigger(step: StepConfig, variables: dict[str, Variable], doc: LineDict) -> None:
    """``on_trigger`` needs a trigger, and the trigger must be a topic variable."""
    if step.policy != "on_trigger":
        return
    if not step.trigger:
        raise error_at(
            "step.policy on_trigger needs step.trigger: the variable whose message ends a tick",
            doc,
            "step",
        )
    if step.trigger not in variables or variables[step.trigger].define is not None:
        raise error_at(
            f"step.trigger '{step.trigger}' is not a topic variable",
            doc,
            "step",
            suggest(step.trigger, variables),
        )
