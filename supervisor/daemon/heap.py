"""The daemon's heap and Python's cyclic garbage collector.

Start-up leaves about 100k long-lived objects (the config, the requirements'
parse trees, the compiled monitor's wrappers, rclpy's).  Left to the collector, each
full collection walks all of them: tens of ms in which the loop takes no message
and publishes no halt, whenever the collector decides (docs/BENCHMARKS.md, "Inside
the running daemon").  :func:`freeze` moves them out of the collector's
generations before ``READY=1`` (``gc.freeze``, no collection: start-up leaves a few
hundred unreachable objects, not worth a full collection's time before READY), so
later collections walk only what the loop made since.  After a reload's swap the
old session is garbage: :func:`settle` unfreezes, collects it and freezes again.

The collector also starts by itself when an allocation crosses its threshold,
which on the daemon is mostly on a violation's path (the record's objects): a
young collection there (about 55 µs cold) delays the halt.  :func:`take_over`
turns that off, and the receive loop calls :func:`collect` at the end of each
turn, after the turn's halts and fsync, with the collector's own thresholds.
"""

from __future__ import annotations

import gc

# The collector's defaults (CPython 3.11): what collect() applies between turns.
_THRESHOLDS = gc.get_threshold()


def freeze() -> None:
    """Exempt every object alive now from later collections."""
    gc.freeze()


def settle() -> None:
    """Collect everything now, then exempt the survivors from later collections."""
    # Unfrozen first: what an earlier freeze froze (a replaced session among it) is
    # collected now if it has become garbage, instead of being kept for good.
    gc.unfreeze()
    gc.collect()
    gc.freeze()


def take_over() -> None:
    """From now on the collector runs only when :func:`collect` is called."""
    gc.disable()


def collect() -> int | None:
    """The collection the collector would have made by now, if any: the oldest
    generation whose count is over its threshold (generation 0 first, as CPython
    decides).  Returns the generation collected, or None."""
    counts = gc.get_count()
    if counts[0] < _THRESHOLDS[0]:
        return None
    gen = 0
    while gen + 1 < len(counts) and counts[gen + 1] >= _THRESHOLDS[gen + 1]:
        gen += 1
    gc.collect(gen)
    return gen
