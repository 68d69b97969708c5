"""The daemon's heap and Python's cyclic garbage collector.

Start-up leaves about 100k long-lived objects (the config, the requirements'
parse trees, the compiled monitor's wrappers, rclpy's).  Left to the collector, each
full collection walks all of them: tens of ms in which the loop takes no message
and publishes no halt, whenever the collector decides (docs/BENCHMARKS.md, "The
halt path's own cost").  :func:`settle` collects once at a moment of the daemon's
choosing (before ``READY=1``, and after a reload's swap, whose old session becomes
garbage there) and moves the survivors out of the collector's generations
(``gc.freeze``), so later collections walk only what the loop made since.
"""

from __future__ import annotations

import gc


def settle() -> None:
    """Collect everything now, then exempt the survivors from later collections."""
    # Unfrozen first: what an earlier settle() froze (a replaced session among it) is
    # collected now if it has become garbage, instead of being kept for good.
    gc.unfreeze()
    gc.collect()
    gc.freeze()
