"""Where a violation's time goes inside the daemon, stage by stage.

The latency experiment times a violation from the robot's publish to the halt
received by another process; this part opens that box.  It runs the daemon's own
pieces in one process, as ``run`` wires them (the monitoring core, the violation
log with its fsync, the engine with the inline publish of the halt on a real rclpy
publisher), feeds the latency experiment's violating and nominal states
alternately, and stamps each stage with ``time.perf_counter_ns`` by wrapping the
functions that mark its ends.  DDS delivery (into the daemon, out to the robot)
is what the echo baseline measures; it is not in here.
"""

from __future__ import annotations

import os
import statistics
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from supervisor.tools.bench.plan import SROBOT_VIOLATING, Plan

if TYPE_CHECKING:
    from supervisor.config.model import Config

# The stages in order, each from the previous mark to its own.
STAGES = (
    ("step", "the values set, the C monitor stepped, the halt path planned (log.md)"),
    ("render", "the violation record built, rendered as JSON and hash-chained, written"),
    ("fsync", "the record on disk (os.fsync)"),
    ("to_publish", "from the fsync's end to the halt publish (log bookkeeping, engine)"),
    ("publish", "rclpy publish of the halt"),
)
# logging.durability after_publish (the default, docs/reference/log.md#durability):
# the halt follows the record's write, the fsync comes after it, off the halt's path.
STAGES_AFTER_PUBLISH = (
    ("step", "the values set, the C monitor stepped, the halt path planned (log.md)"),
    ("render", "the violation record built, rendered as JSON, hash-chained and written"),
    ("to_publish", "from the write's end to the halt publish (log bookkeeping, engine)"),
    ("publish", "rclpy publish of the halt"),
)
AFTER_HALT = ("then_fsync", "after the halt: its mitigation record, then the fsync's end")


def breakdown(
    plan: Plan, work: Path, trials: int, idle_ms: float = 0.0, durability: str = "before_action"
) -> dict[str, Any]:
    """Per stage, the median and p99 in µs over ``trials`` violations; ``idle_ms``:
    the process sleeps that long before each violation, as the daemon waits for
    messages between two violations (its caches and the CPU go cold meanwhile);
    ``durability``: logging.durability, with the daemon's loop's flush() after each
    message under after_publish."""
    import rclpy
    from rclpy.context import Context

    import mitigations.violationlog.writer as writer
    from mitigations.engine import Engine
    from mitigations.violationlog.writer import ViolationLog
    from supervisor.daemon.core import Core
    from supervisor.daemon.process import prepare_session

    work.mkdir(parents=True, exist_ok=True)
    config = plan.write_config(work / "config.yaml", work / "violations.jsonl", latency=True)
    session = prepare_session(config, work / "build")
    cfg = session.config
    log = ViolationLog(
        work / "violations.jsonl", cfg.component, cfg.sha256, echo=False, durability=durability
    )
    after = durability == "after_publish"
    if after:
        log.defer_thread = threading.get_ident()  # as the daemon's loop (receive.py)
    stages = STAGES_AFTER_PUBLISH if after else STAGES
    ctx = Context()
    rclpy.init(context=ctx, domain_id=_private_domain())
    node = rclpy.create_node("bench_breakdown", context=ctx)
    marks = _Marks()
    samples: dict[str, list[float]] = {name: [] for name, _ in (*stages, AFTER_HALT)}
    engine = Engine(_timed_actions(cfg, node, marks), log)
    real_fsync = writer.os.fsync
    core = Core(session, log, engine.submit)
    real_violation = log.violation
    log.violation = marks.around(  # type: ignore[method-assign]
        real_violation, "recorded_start", "recorded_end"
    )
    # the core writes a violation from its requirement's template (writer.ViolationTemplate)
    log.violation_from = marks.around(  # type: ignore[method-assign]
        log.violation_from, "recorded_start", "recorded_end"
    )
    # and on the halt path, from the step's row (docs/reference/log.md#the-halt-path)
    log.violation_row = marks.around(  # type: ignore[method-assign]
        log.violation_row, "recorded_start", "recorded_end"
    )
    try:
        writer.os.fsync = marks.around(real_fsync, "fsync_start", "fsync_end")  # type: ignore[attr-defined]
        values = [(name, plan.nominal[name]) for name in plan.nominal]
        bad = [(n, SROBOT_VIOLATING.get(n, x)) for n, x in values]
        t = time.monotonic_ns()
        core.start(t)
        warmup = 20
        for i in range(trials + warmup):
            t += 1_000_000
            core.fields(values, t)  # nominal: the policy re-arms
            log.flush()
            t += 1_000_000
            if idle_ms:
                time.sleep(idle_ms / 1e3)
            marks.at.clear()
            marks.mark("start")
            core.fields(bad, t)
            log.flush()  # the loop's, after the message: under after_publish, the fsync
            if "publish_end" not in marks.at or i < warmup:
                continue
            order, chain = _order(after, stages)
            stamps = [marks.at[k] for k in order]
            for (name, _), a, b in zip(chain, stamps, stamps[1:], strict=False):
                samples[name].append((b - a) / 1e3)
    finally:
        writer.os.fsync = real_fsync  # type: ignore[attr-defined]
        engine.close()
        log.close()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
        if session.cleanup is not None:
            session.cleanup()
    return _summary(samples, stages, after, idle_ms, durability)


class _Marks:
    """``perf_counter_ns`` by stage boundary, within one violation."""

    def __init__(self) -> None:
        self.at: dict[str, int] = {}

    def mark(self, name: str) -> None:
        # the first time only: the mitigation record's own fsync comes after the halt
        if name not in self.at:
            self.at[name] = time.perf_counter_ns()

    def around(
        self, f: Callable[..., Any], before: str | None, after: str | None
    ) -> Callable[..., Any]:
        """``f``, marking ``before`` as it is called and ``after`` as it returns."""

        def timed(*a: Any, **k: Any) -> Any:
            if before:
                self.mark(before)
            try:
                return f(*a, **k)
            finally:
                if after:
                    self.mark(after)

        return timed


def _timed_actions(cfg: Config, node: Any, marks: _Marks) -> dict[str, Any]:
    """The config's actions as the daemon builds and wraps them (loss.py), each
    publish marking ``publish_start`` and ``publish_end``."""
    from mitigations.actions import build_action
    from mitigations.actions.publish import PublishAction
    from supervisor.daemon.loss import OwnWrites, RecordingPublisher

    publishers: dict[Any, Any] = {}
    actions = {n: build_action(m, node, publishers) for n, m in cfg.mitigations.items()}
    own = OwnWrites()
    for action in actions.values():
        if isinstance(action, PublishAction):  # as the daemon wraps it (loss.py)
            action.publisher = RecordingPublisher(action.publisher, action.topic, own)
            action.publisher.publish = marks.around(  # type: ignore[method-assign]
                action.publisher.publish, "publish_start", "publish_end"
            )
    return actions


def _order(
    after: bool, stages: tuple[tuple[str, str], ...]
) -> tuple[list[str], tuple[tuple[str, str], ...]]:
    """The marks in the order they bound the stages, and the stages they bound."""
    if after:
        order = ["start", "recorded_start", "recorded_end", "publish_start"]
        order += ["publish_end", "fsync_end"]
        return order, (*stages, AFTER_HALT)
    order = ["start", "recorded_start", "fsync_start", "fsync_end"]
    order += ["publish_start", "publish_end"]
    return order, stages


def _summary(
    samples: dict[str, list[float]],
    stages: tuple[tuple[str, str], ...],
    after: bool,
    idle_ms: float,
    durability: str,
) -> dict[str, Any]:
    """Each stage's percentiles, the time after the halt under after_publish, the total."""
    out: dict[str, Any] = {"trials": len(samples["step"]), "idle_ms": idle_ms, "stages_us": {}}
    out["durability"] = durability
    total = []
    for name, what in stages:
        v = sorted(samples[name])
        out["stages_us"][name] = {"what": what, **_stats(v)}
    for parts in zip(*(samples[n] for n, _ in stages), strict=True):
        total.append(sum(parts))  # detection to the halt: the stages after it left out
    if after:
        out["after_halt_us"] = {"what": AFTER_HALT[1], **_stats(sorted(samples[AFTER_HALT[0]]))}
    out["total_us"] = _stats(sorted(total))
    return out


def _stats(v: list[float]) -> dict[str, float | None]:
    if not v:
        return {"p50": None, "p99": None, "max": None}
    return {
        "p50": round(statistics.median(v), 1),
        "p99": round(v[min(len(v) - 1, -(-len(v) * 99 // 100) - 1)], 1),
        "max": round(v[-1], 1),
    }


def _private_domain() -> int:
    # the publisher needs no peer: a domain of its own keeps it off others' graphs
    return 150 + os.getpid() % 60
