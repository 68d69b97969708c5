"""Engines: what runs the tasks. An engine takes ``BagTask``s and the content hashes
already done, and yields each ``BagResult`` as it comes, in any order; the caller
writes it (dataset.py).  ``local`` is a process pool on this machine; another engine
(a Ray cluster) is one more class with the same ``results``.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Collection, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from supervisor.tools.fleet.task import BagResult, BagTask, run_task

ATTEMPTS = 2  # a task whose worker dies this many times is failed, not tried again

_done: Collection[str] = ()


def _init(done: Collection[str]) -> None:
    global _done
    _done = done


def _run(task: BagTask) -> BagResult:
    return run_task(task, _done)


class LocalEngine:
    """``jobs`` worker processes (``spawn``: a worker starts clean, never a fork of a
    parent that may hold threads).  A worker that dies (killed, out of memory)
    breaks the pool: its tasks go to a new pool, each at most ``ATTEMPTS`` times."""

    def __init__(self, jobs: int | None = None) -> None:
        self.jobs = jobs or os.cpu_count() or 1

    def results(self, tasks: list[BagTask], done: Collection[str]) -> Iterator[BagResult]:
        todo = [(t, 1) for t in tasks]  # (task, attempt)
        while todo:
            retry: list[tuple[BagTask, int]] = []
            pool = ProcessPoolExecutor(
                max_workers=min(self.jobs, len(todo)),
                mp_context=multiprocessing.get_context("spawn"),
                initializer=_init,
                initargs=(frozenset(done),),
            )
            # closed early (the caller stopped on an error, or Ctrl-C): the tasks not
            # started are dropped, not run to the end of the archive
            try:
                running: dict[Future[BagResult], tuple[BagTask, int]] = {
                    pool.submit(_run, t): (t, n) for t, n in todo
                }
                while running:
                    finished, _ = wait(running, return_when=FIRST_COMPLETED)
                    for f in finished:
                        task, n = running.pop(f)
                        try:
                            yield f.result()
                        except BrokenProcessPool:
                            if n < ATTEMPTS:
                                retry.append((task, n + 1))
                            else:
                                yield BagResult(
                                    task, "failed", f"its worker process died {n} times"
                                )
                        except Exception as e:  # noqa: BLE001 - one bag's bug is its row
                            yield BagResult(
                                task, "failed", f"internal error: {type(e).__name__}: {e}"
                            )
            finally:
                pool.shutdown(wait=True, cancel_futures=True)
            todo = retry
