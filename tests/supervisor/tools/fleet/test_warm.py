"""The fork server's preload (supervisor/tools/fleet/warm.py): a worker it forks starts
with what its first config and bag would build, the requirement parsers and rosbags'
Jazzy types (docs/BENCHMARKS.md, "Fleet").  warm.py swallows its own failures (a
worker then builds them itself), so only this test sees it stop working."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor

from supervisor.tools.fleet import server

# evaluated in the worker: what it inherited from the fork server, before any task
PROBE = (
    "(__import__('monitors.frontend.parse', fromlist=['_'])._parser.cache_info().currsize,"
    " __import__('monitors.ir.formula', fromlist=['_'])._parser.cache_info().currsize,"
    " 'rosbags.typesys.stores.ros2_jazzy' in __import__('sys').modules,"
    " 'paramiko' in __import__('sys').modules)"
)


def test_a_forked_worker_starts_with_the_parsers_and_types_built() -> None:
    # a fork server an earlier test of this process left running is stopped first:
    # serve() would take it as it is, with its own preload (CI failed on it once)
    server.stop()
    try:
        with ProcessPoolExecutor(1, mp_context=server.serve()) as pool:
            # eval: a builtin, sent by name, so the probe needs no module of the tests
            inherited = pool.submit(eval, PROBE).result(timeout=120)
    finally:
        server.stop()
    assert inherited == (1, 1, True, False)
