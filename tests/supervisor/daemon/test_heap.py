"""heap.settle: start-up's and a replaced session's garbage collected when the daemon
chooses, the survivors out of the collector's walks (supervisor/daemon/heap.py)."""

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


def test_what_one_settle_froze_is_collected_by_the_next_once_it_is_garbage() -> None:
    # a reload: the old session survived start-up's settle() and is dropped at the swap
    old_session = _Node()
    freed = weakref.finalize(old_session, lambda: None)
    heap.settle()
    del old_session
    gc.collect()
    assert freed.alive  # frozen: no collection walks it
    heap.settle()
    assert not freed.alive
