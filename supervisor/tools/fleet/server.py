"""The local engine's fork server (engine.py, ``LocalEngine``): a process started
clean that imports what a task needs once (``PRELOAD``) and forks the pool's workers.

Apart from engine.py so that ``fleet replay`` starts it before importing pyarrow and
listing the archive: its interpreter and imports (0.4-0.7 s) then run beside this
process's own start-up, not after it, a serial part of every run
(docs/BENCHMARKS.md, "Fleet").
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.forkserver as forkserver
from multiprocessing.context import BaseContext

# imported once by the fork server, so every worker it forks has them, and what a
# worker's first config and bag would build, built (warm.py)
PRELOAD = ("supervisor.tools.fleet.warm",)


def serve() -> BaseContext:
    """The fork server started, if it is not running; its context, for a pool."""
    context = multiprocessing.get_context("forkserver")
    # read when the server starts: replaces its default, __main__, which would run
    # this command's module again in the server
    context.set_forkserver_preload(list(PRELOAD))
    forkserver.ensure_running()
    return context


def stop() -> None:
    """The fork server stopped, and waited for: no process outlives the run, and its
    CPU (its workers', which it reaps) is counted in this process's children's."""
    # the standard library has no public call for it (multiprocessing.forkserver)
    halt = getattr(getattr(forkserver, "_forkserver", None), "_stop", None)
    if halt is not None:
        halt()
