"""heap: start-up's and a replaced session's garbage collected when the daemon
chooses, the survivors out of the collector's walks, and the young collections
made between loop turns instead of on an allocation (supervisor/daemon/heap.py)."""

from __future__ import annotations

import gc
import weakref
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from rosutil import wait_until

from supervisor.daemon import heap


@pytest.fixture(autouse=True)
def _unfrozen() -> Iterator[None]:
    yield
    gc.unfreeze()  # the rest of the test session is collected as usual
    gc.enable()


class _Node:
    def __init__(self) -> None:
        self.other: Any = self  # a reference cycle: only the collector frees it


def _walked(obj: object) -> bool:
    """Whether the collector's generations hold ``obj`` (frozen objects are in none)."""
    return any(o is obj for o in gc.get_objects())


def test_settle_collects_the_cycles_made_before_it_and_exempts_the_survivors() -> None:
    garbage = _Node()
    freed = weakref.finalize(garbage, lambda: None)
    del garbage
    survivor = {"kept": [1, 2, 3]}
    assert _walked(survivor)
    heap.settle()
    assert not freed.alive
    assert not _walked(survivor)
    assert not _walked(survivor["kept"])
    fresh = {"made": ["after"]}
    assert _walked(fresh)  # what the loop makes later is collected as usual


def test_freeze_exempts_what_is_alive_from_later_collections() -> None:
    startup = {"parse_trees": [1, 2, 3]}
    assert _walked(startup)
    heap.freeze()
    assert not _walked(startup)
    fresh = {"made": ["after"]}
    assert _walked(fresh)


def test_what_was_frozen_is_collected_by_settle_once_it_is_garbage() -> None:
    # a reload: the old session was frozen at start-up and is dropped at the swap
    old_session = _Node()
    freed = weakref.finalize(old_session, lambda: None)
    heap.freeze()
    del old_session
    gc.collect()
    assert freed.alive  # frozen: no collection walks it
    heap.settle()
    assert not freed.alive


def _young(n: int) -> list[list[int]]:
    """``n`` new objects the collector tracks, kept alive."""
    return [[i] for i in range(n)]


def test_after_take_over_only_collect_collects_and_only_past_the_threshold() -> None:
    heap.take_over()
    assert not gc.isenabled()
    gc.collect()  # every generation's count from zero
    garbage = _Node()
    freed = weakref.finalize(garbage, lambda: None)
    del garbage
    assert heap.collect() is None  # a few objects: the collector would not run yet
    assert freed.alive
    kept = _young(gc.get_threshold()[0])  # no automatic collection, however many
    assert freed.alive
    assert heap.collect() == 0
    assert not freed.alive
    assert kept


def test_collect_takes_the_older_generation_when_the_collector_would() -> None:
    heap.take_over()
    gc.collect()
    t0, t1, _ = gc.get_threshold()
    kept = []
    for _ in range(t1):
        kept.append(_young(t0))
        assert heap.collect() == 0
    kept.append(_young(t0))
    assert heap.collect() == 1  # as many young collections as the threshold: generation 1
    assert gc.get_count()[:2] == (0, 0)


# Loaded by the daemon's interpreter (sitecustomize on its PYTHONPATH): each collection
# is written with the frozen objects' count and the Python frames that started it.
_PROBE = """\
import gc, os, sys

_out = open(os.environ["GC_PROBE"], "a", buffering=1)


def _probe(phase, info):
    if phase != "start":
        return
    frames, f = [], sys._getframe(1)
    while f is not None:
        frames.append(f"{f.f_code.co_name}@{os.path.basename(f.f_code.co_filename)}")
        f = f.f_back
    _out.write(f"{gc.get_freeze_count()} {' '.join(frames)}\\n")


gc.callbacks.append(_probe)
"""

CONFIG = """\
component: base
step: {policy: periodic, period_ms: 1}
variables:
  halt: {type: bool, topic: /halt, msg: std_msgs/msg/Bool}
requirements:
  - id: always_halted
    text: base shall always satisfy halt
    on_violation: [stop]
    policy: {reset: after_mitigation}
mitigations:
  stop: {publish: {topic: /stop, msg: std_msgs/msg/Bool, value: {data: true}}}
ros: {status_ms: 20}
"""


@pytest.mark.ros
def test_the_running_daemon_collects_only_between_its_loop_turns(
    tmp_path: Path, robot_node: Any
) -> None:
    from rosutil import Daemon, wait_matched
    from std_msgs.msg import Bool

    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(_PROBE)
    probe = tmp_path / "gc.txt"
    config = tmp_path / "c.yaml"
    config.write_text(CONFIG)
    d = Daemon(tmp_path, config, env={"PYTHONPATH": str(site), "GC_PROBE": str(probe)})
    try:
        d.wait_notify("READY=1", timeout=30)
        at_ready = len(probe.read_text().splitlines())
        halt = robot_node.create_publisher(Bool, "/halt", 10)
        wait_matched([halt])
        halt.publish(Bool(data=False))  # violated at every tick: a record and a halt each

        def after_ready() -> list[list[str]]:
            return [ln.split()[1:] for ln in probe.read_text().splitlines()[at_ready:]]

        wait_until(
            "a collection while violations are recorded and halts published",
            lambda: after_ready() and sum(r["event"] == "violation" for r in d.records()) >= 50,
            60,
            d.explain,
        )
        d.terminate()
    finally:
        d.close()
    made_by = after_ready()
    # Every collection once the daemon is ready is the loop's own, between turns (or a
    # reload's); none starts from an allocation on a message's path.
    assert all(
        frames[0] in ("collect@heap.py", "settle@heap.py") and "serve@receive.py" in frames
        for frames in made_by
    ), made_by
