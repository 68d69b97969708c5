"""heap: start-up's and a replaced session's garbage collected when the daemon
chooses, the survivors out of the collector's walks, and the young collections
made between loop turns instead of on an allocation (supervisor/daemon/heap.py)."""

from __future__ import annotations

import gc
import weakref
from collections.abc import Iterator
from typing import Any

import pytest

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
