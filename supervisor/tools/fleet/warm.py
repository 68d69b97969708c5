"""What a ``fleet replay`` worker would otherwise do on its own first config and bag,
done once by the local engine's fork server (server.py, ``PRELOAD``), whose forked
workers inherit it: the tasks' modules imported, rosbags' stand-in types
(``rostypes.typestore_of``) and the requirement parsers built.  Each was a serial
part of every worker's start (docs/BENCHMARKS.md, "Fleet").  Only the fork server
imports this module: the command never does.
"""

from __future__ import annotations

import contextlib

# the modules a task runs: engine's ``_run`` and replay's session
import supervisor.tools.fleet.engine  # noqa: F401
import supervisor.tools.replay.session  # noqa: F401
from supervisor.cache import quiet


def warm() -> None:
    """The first bag's and the first config's one-off costs, paid here."""
    from rosbags.typesys import Stores, get_typestore

    from monitors.frontend.parse import parse_requirement
    from monitors.ir.formula import parse_formula, use_parser_cache
    from supervisor.cache import Cache

    get_typestore(Stores.ROS2_JAZZY)  # its module: 0.04 s, imported once per process
    cache = Cache.open_user()
    if cache is not None:  # as replay's ``prepare`` does: the parsers' tables from there
        use_parser_cache(cache.root)
    # each parser built, its lexer with it (both cached per process)
    parse_requirement("R shall always satisfy x")
    parse_formula("H x")


# the workers forked from here say nothing of the cache: the command says it once
quiet()
# a failure here is not the run's: a worker then does the same itself and says why
with contextlib.suppress(Exception):
    warm()
