"""Engines: what runs the tasks. An engine takes ``BagTask``s and the content hashes
already done, and yields each ``BagResult`` as it comes, in any order.
``LocalEngine`` is a process pool on this machine; given the dataset
(``writes_to``), each worker writes its bag's files itself (``dataset.Commits``) and
yields the result only once they are written, without its Arrow table, so the
parent writes nothing and the pool's processes are the run's only busy ones
(docs/BENCHMARKS.md, "Fleet"); a dead worker's committed bags stay done, the rest
are retried one a call (``LocalEngine``).  ``RayEngine`` runs the same ``run_task`` as Ray
tasks, on a cluster or on a local one it starts (``ray`` is imported only there:
the base install has no Ray); its results come back as Arrow tables for the caller
to write (``dataset.Writers``).
"""

from __future__ import annotations

import contextlib
import ctypes
import io
import itertools
import logging
import multiprocessing.forkserver as forkserver
import os
import pickle
import re
import shutil
import signal
import socket
import sys
import tempfile
import threading
from collections import deque
from collections.abc import Collection, Iterator
from concurrent.futures import (
    FIRST_COMPLETED,
    Future,
    ProcessPoolExecutor,
    ThreadPoolExecutor,
    wait,
)
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, Protocol, TextIO

from monitors.errors import UserError
from monitors.untrusted import printable
from supervisor.tools.fleet import server
from supervisor.tools.fleet.dataset import Commits, Dataset
from supervisor.tools.fleet.task import (
    BagResult,
    BagTask,
    _reason,
    compile_config,
    config_error,
    run_task,
)
from supervisor.tools.stopping import uninterrupted

ATTEMPTS = 2  # a task whose worker dies this many times is failed, not tried again
WINDOW_PER_JOB = 4  # calls in flight per worker: the next one is queued as one ends
# bags per call when the workers write: each bag's files written on a thread while
# the next is replayed; fewer near the end, so that no worker is left with a long call
BATCH = 8

_done: Collection[str] = ()
_dataset: Dataset | None = None  # this worker writes its bags' files there
_writer: ThreadPoolExecutor | None = None  # ... on this one thread, in order


def _init(done: Collection[str], writes_to: Path | None = None) -> None:
    global _done, _dataset, _writer
    _die_with_server()
    _done = done
    if writes_to is not None:
        _dataset = Dataset(writes_to, make=False)
        _writer = ThreadPoolExecutor(1, thread_name_prefix="fleet-write")


def _one(task: BagTask, done: Collection[str]) -> BagResult:
    """One bag of a call, in either engine's worker: its bug is its row, not its call's."""
    try:
        return run_task(task, done)
    except Exception as e:  # noqa: BLE001 - one bag's bug is its row, not its batch's
        return _internal(task, e)


class WriteFailed(Exception):
    """A worker's ``Dataset.write`` error (message, file): a ``UserError`` does not
    cross processes whole (its fields are keyword-only)."""


def _run(tasks: list[BagTask]) -> list[BagResult]:
    """``tasks`` one after the other.  Given the dataset, each bag's files are written
    on this worker's writer thread while the next bag is replayed, durable in groups
    (``dataset.Commits``: one sync for several bags, a row only once its violations
    are synced; docs/BENCHMARKS.md, "Fleet"), and the results are returned, without
    their tables, once the call's last group is committed: done means written.  A
    write error stops the call before its next bag."""
    if _dataset is None or _writer is None:
        return [_one(t, _done) for t in tasks]
    commits = Commits(_dataset)
    writes: list[tuple[Future[None], BagResult]] = []
    for t in tasks:
        if any(f.done() and f.exception() is not None for f, _ in writes):
            break  # a write failed (a full disk): the run stops, the rest is not replayed
        result = _one(t, _done)
        # the table stays with its write alone: a call does not hold all its bags' tables
        writes.append(
            (_writer.submit(commits.add, result, t.robot, t.fingerprint), result.without_table())
        )
    last = _writer.submit(commits.commit)
    out = []
    for future, slim in [*writes, (last, None)]:
        try:
            future.result()
        except UserError as e:
            raise WriteFailed(e.message, e.file) from None
        if slim is not None:
            out.append(slim)
    return out


PR_SET_PDEATHSIG = 1  # linux/prctl.h


def _die_with_server() -> None:
    """This worker killed (SIGKILL) when its parent, the fork server, exits, and the
    server left free to exit when the command does: no worker outlives the command,
    however it ends (a second Ctrl-C, a kill).  The server exits once every copy of
    the command's end of its liveness pipe is closed, and the standard library gives
    each worker one (multiprocessing/forkserver.py): kept, a live worker kept the
    server, and the command's stop waiting for it, alive.  PR_SET_PDEATHSIG is Linux
    only; elsewhere a worker ends at its next read of the pool's queue."""
    server_state = getattr(forkserver, "_forkserver", None)
    alive = getattr(server_state, "_forkserver_alive_fd", None)
    if isinstance(alive, int):
        with contextlib.suppress(OSError):
            os.close(alive)
        server_state._forkserver_alive_fd = None  # type: ignore[union-attr]
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)


ConfigError = tuple[str, str, int | None, int | None, str | None]


def _identities(answers: list[str | ConfigError]) -> list[str]:
    """``_warm``'s answers: the configs' identities, or the first error raised."""
    for answer in answers:
        if not isinstance(answer, str):
            raise config_error(answer)
    return [a for a in answers if isinstance(a, str)]


def _warm(configs: tuple[str, ...] = ()) -> tuple[int, list[str | ConfigError]]:
    """What every task imports, imported, and ``configs`` compiled (their monitors
    loaded), while the parent lists the archive (``LocalEngine.start``): the worker's
    pid and each config's identity or error."""
    import supervisor.tools.replay.session  # noqa: F401 - imported for the tasks
    from supervisor.cache import quiet

    quiet()  # the command says the cache's warnings once (command.py)
    return os.getpid(), [compile_config(c) for c in configs]


class Engine(Protocol):
    """What ``fleet replay`` needs of an engine (command.py): its workers started and
    the configs compiled by them while the archive is listed, each bag's result as it
    comes, and everything it started stopped."""

    def start(
        self, done: Collection[str], tasks: int | None = None, configs: tuple[str, ...] = ()
    ) -> None: ...

    def checked(self) -> list[str] | None: ...

    def results(self, tasks: list[BagTask], done: Collection[str]) -> Iterator[BagResult]: ...

    def close(self) -> None: ...


class LocalEngine:
    """``jobs`` worker processes, forked by a ``forkserver``: a process started clean
    (never a fork of this parent, which may hold threads) that imports what a task
    needs once (server.py), so a second worker costs no second import, 0.4 s of
    CPU each (docs/BENCHMARKS.md, "Fleet").  A worker that dies (killed, out of
    memory) breaks the pool, and every call in flight with it: a bag whose row a worker
    committed in this run is done (read back, ``Dataset.row``), never retried nor
    written over; each other bag goes to a new pool, in a call of its own, at most
    ``ATTEMPTS`` times.  concurrent.futures does not say which worker died, so every
    uncommitted bag in flight is charged an attempt; no two bags on their last attempt
    are in flight together, so a bag that kills its worker fails alone.  Killed between
    a bag's violations and its row, a worker left the bag unfinished (no row), and the
    retry writes the same files again (dataset.py).  Stopped early (an error, Ctrl-C),
    the pool's queued calls are cancelled and its workers killed, not left to finish
    their calls; each worker also dies with the fork server, which exits with this
    process, so none outlives the command (``_die_with_server``)."""

    def __init__(
        self,
        jobs: int | None = None,
        writes_to: Path | None = None,
        *,
        batch: int = BATCH,
        window: int = WINDOW_PER_JOB,
    ) -> None:
        """``writes_to``: the dataset the workers write each bag's files to (the
        results then come without their tables); None: the caller writes them.
        ``batch``: bags a call at most; ``window``: calls in flight per worker."""
        self.jobs = jobs or os.cpu_count() or 1
        self.writes_to = writes_to
        self.batch, self.window = batch, window
        self._started: tuple[ProcessPoolExecutor, frozenset[str]] | None = None
        self._live: ProcessPoolExecutor | None = None  # the pool ``results`` runs on
        # the started workers' imports and compiles (their pids, the configs' errors)
        self.warm: list[Future[tuple[int, list[str | ConfigError]]]] = []

    def start(
        self, done: Collection[str], tasks: int | None = None, configs: tuple[str, ...] = ()
    ) -> None:
        """Start the workers now, each importing what a task needs, so that their
        start-up overlaps the parent's (the config compiled): a serial part of every
        run otherwise (docs/BENCHMARKS.md, "Fleet").  ``tasks``: at most that many
        tasks to come (no more workers than that).  ``configs``: compiled by each worker
        as it starts (``checked`` says whether they compiled).  ``results`` with the
        same ``done`` uses them."""
        self._stop_started()  # the fork server kept: serve() may have started it
        workers = self.jobs if tasks is None else min(self.jobs, tasks)
        if workers < 1:
            return
        done = frozenset(done)
        pool = self._pool(workers, done)
        self._started = (pool, done)
        # started one per submit (concurrent.futures), each compile on a worker of its own
        self.warm = [pool.submit(_warm, configs) for _ in range(workers)]

    def checked(self) -> list[str] | None:
        """The identities of the configs given to ``start``, as the started workers
        compiled them: the first worker's answer awaited, its first config error
        raised (``UserError``); None when no worker was started (the caller compiles
        them)."""
        if not self.warm:
            return None
        try:
            first = self.warm[0].result()
        except BrokenProcessPool:  # its worker died (out of memory): the caller compiles
            return None
        return _identities(first[1])

    def close(self) -> None:
        """The started workers stopped, when ``results`` did not take them, and the
        fork server with them: no process outlives the run, and its CPU (its
        workers', which it reaps) is counted in this process's children's."""
        with uninterrupted():
            self._stop_started()
            if self._live is not None:  # a run whose own stop was cut short (Ctrl-C)
                _halt(self._live)
                self._live.shutdown(wait=True, cancel_futures=True)
                self._live = None
            server.stop()

    def _stop_started(self) -> None:
        if self._started is not None:
            _halt(self._started[0])  # its workers only compile: nothing to finish
            self._started[0].shutdown(wait=True, cancel_futures=True)
            self._started = None
        self.warm = []

    def _pool(self, jobs: int, done: frozenset[str]) -> ProcessPoolExecutor:
        context = server.serve()
        return ProcessPoolExecutor(
            max_workers=jobs,
            mp_context=context,
            initializer=_init,
            initargs=(done, self.writes_to),
        )

    def _batch(self, left: int, running: dict[Any, list[Any]]) -> int:
        """Bags in the next call: one when the parent writes; else up to ``batch``,
        fewer as the bags not yet sent run out, so the last calls are short."""
        if self.writes_to is None:
            return 1
        unsent = left - sum(len(b) for b in running.values())
        return max(1, min(self.batch, unsent // (self.window * self.jobs)))

    def results(self, tasks: list[BagTask], done: Collection[str]) -> Iterator[BagResult]:
        # fresh tasks, taken as the window has room: each wait() installs a waiter on
        # every future it is given, so the whole archive in flight cost the parent
        # time growing with the square of the bags
        todo: Iterator[BagTask] = iter(tasks)
        # (task, attempt) of the bags a dead worker's call took down: one bag a call
        retry: deque[tuple[BagTask, int]] = deque()
        written = Dataset(self.writes_to, make=False) if self.writes_to is not None else None
        # each bag's row file as it was before its first call: another one since is
        # this run's commit (``_committed``)
        before: dict[BagTask, tuple[int, int] | None] = {}
        started, self._started = self._started, None
        if started is not None and (not tasks or started[1] != frozenset(done)):
            started[0].shutdown(wait=True, cancel_futures=True)
            started = None
        left = len(tasks)
        while left:
            if started is not None:
                pool, started = started[0], None
            else:
                pool = self._pool(min(self.jobs, left), frozenset(done))
            self._live = pool
            window = self.window * self.jobs
            broken: list[list[tuple[BagTask, int]]] = []  # the calls the pool's break took
            unrun: list[tuple[BagTask, int]] = []  # sent to a pool already broken: not run
            running: dict[Future[list[BagResult]], list[tuple[BagTask, int]]] = {}
            whole = False
            try:
                while True:
                    while not (broken or unrun) and len(running) < window:
                        batch = self._next(todo, retry, left, running)
                        if not batch:
                            break
                        if written is not None:
                            for t, _ in batch:
                                if t not in before:
                                    before[t] = written.row_id(t.config_sha256, t.fingerprint)
                        try:
                            running[pool.submit(_run, [t for t, _ in batch])] = batch
                        except BrokenProcessPool:  # a worker died: the next pool runs them
                            unrun.extend(batch)
                            break
                    if not running:
                        break
                    finished, _ = wait(running, return_when=FIRST_COMPLETED)
                    for f in finished:
                        batch = running.pop(f)
                        try:
                            results = f.result()
                        except BrokenProcessPool:
                            broken.append(batch)  # judged once the pool's workers are gone
                            continue
                        except WriteFailed as e:  # a full disk stops the run, as in the parent
                            raise UserError(e.args[0], file=e.args[1]) from None
                        except Exception as e:  # noqa: BLE001 - one bag's bug is its row
                            # the call's worker is done with it: its committed rows stand
                            results = []
                            for task, n in batch:
                                if (r := _committed(written, task, before.get(task))) is not None:
                                    results.append(r)
                                elif len(batch) > 1 and n < ATTEMPTS:
                                    retry.append((task, n + 1))  # alone: its own error
                                else:
                                    results.append(_internal(task, e))
                        for result in results:
                            left -= 1
                            yield result
                whole = True
            finally:
                with uninterrupted():  # a second Ctrl-C cannot leave workers behind
                    if not whole:  # closed early (an error, Ctrl-C): stop now (``_halt``)
                        _halt(pool)
                    pool.shutdown(wait=True, cancel_futures=True)
                    self._live = None
            # The pool's workers are all gone now (a break terminates them all): a row
            # a worker committed before is final, and a bag without one is charged an
            # attempt, whichever worker died, as concurrent.futures does not say which.
            # A bag on its last attempt ran alone (``_next``): its death was its own.
            retry.extend(unrun)
            for batch in broken:
                for task, n in batch:
                    if (r := _committed(written, task, before.get(task))) is not None:
                        left -= 1
                        yield r
                    elif n < ATTEMPTS:
                        retry.append((task, n + 1))
                    else:
                        left -= 1
                        yield BagResult(task, "failed", f"its worker process died {n} times")

    def _next(
        self,
        todo: Iterator[BagTask],
        retry: deque[tuple[BagTask, int]],
        left: int,
        running: dict[Future[list[BagResult]], list[tuple[BagTask, int]]],
    ) -> list[tuple[BagTask, int]]:
        """The next call's bags: a retried bag alone, and a bag on its last attempt
        alone in the pool (none: wait for the calls in flight to end), so that a bag
        that kills its worker fails alone and no bag is failed for another's death;
        else fresh bags (``_batch``).  A death takes at most the calls then in flight
        to their last attempt, so the bags run alone after it stay few."""
        if any(b[0][1] >= ATTEMPTS for b in running.values()):
            return []
        if retry:
            if retry[0][1] < ATTEMPTS or not running:
                return [retry.popleft()]
            return []
        return [(t, 1) for t in itertools.islice(todo, self._batch(left, running))]


def _committed(
    written: Dataset | None, task: BagTask, before: tuple[int, int] | None
) -> BagResult | None:
    """The bag's row as the worker committed it in this run (a row file other than
    ``before``, the one it had before its first call), as a result the caller counts
    and does not write again: a row of an earlier run (failed, so replayed again) is
    not this run's, whatever the clock said when it was written."""
    if written is None or written.row_id(task.config_sha256, task.fingerprint) == before:
        return None
    row = written.row(task.config_sha256, task.fingerprint)
    if row is None:
        return None
    return BagResult(
        task,
        row["status"],
        row["reason"] or "",
        row["bag_sha256"] or "",
        row["messages"] or 0,
        row["seconds"] or 0.0,
        written=row["violations"] or 0,
    )


def _internal(task: BagTask, e: Exception) -> BagResult:
    return BagResult(task, "failed", _reason(f"internal error: {type(e).__name__}: {e}"))


def _halt(pool: ProcessPoolExecutor) -> None:
    """Stop a pool now: its workers killed rather than left to finish the calls they
    hold (up to ``batch`` bags each).  A killed worker leaves no partial file under a
    name a reader reads (supervisor/files.py; at most a hidden temporary): a bag
    without its row is not finished, and the next run replays it.  Python 3.11's pool cannot terminate its
    workers (``terminate_workers`` is 3.14's), so they are taken from its process list."""
    # the calls not started are cancelled by the caller's shutdown(cancel_futures=True),
    # in the pool's own thread: a cancel() here races its marking them broken
    processes = getattr(pool, "_processes", None)
    for process in list(processes.values()) if isinstance(processes, dict) else []:
        with contextlib.suppress(OSError, ValueError, AttributeError):
            process.kill()


RAY_MISSING = "pip install 'safety-supervisor[fleet]'"
REACH_S = 10.0  # a cluster's head that has not answered by then is not there


RAY_BATCH = 16  # bags per Ray task at most: Ray's own cost is per task, milliseconds
RAY_WINDOW_PER_CPU = 4  # Ray tasks in flight per CPU of the cluster
RAY_NOTE_CHARS = 500  # of one of Ray's messages, as a line on stderr
_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


class RayNotes(io.TextIOBase):
    """What Ray's driver prints on ``sys.stdout`` while it is on a cluster: the
    raylet's errors pushed to it (a worker's death, the task's retry), in colour,
    even into a pipe.  Standard output holds the run's one summary line
    (docs/reference/fleet.md), so while the engine is on a cluster they go to stderr
    instead, one plain, bounded line each."""

    def __init__(self, err: TextIO) -> None:
        self.err = err
        self._part = ""
        self._lock = threading.Lock()

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        with self._lock:  # Ray's threads print
            *lines, part = (self._part + text).split("\n")
            self._part = part[: 4 * RAY_NOTE_CHARS]  # a line's start is what is shown
            for line in lines:
                if plain := _ANSI.sub("", line).strip():
                    self.err.write(f"fleet replay: ray: {printable(plain)[:RAY_NOTE_CHARS]}\n")
            if lines:
                self.err.flush()
        return len(text)

    def flush(self) -> None:
        self.err.flush()


def _run_ray(tasks: list[BagTask], done: Collection[str]) -> bytes:
    """A Ray task: ``run_task`` on each of a few bags in a Ray worker, a result each (a
    module-level function, so workers import it by name rather than unpickling its
    code).  Several bags a task, as the pool's calls: each Ray task costs its worker
    and this process milliseconds of their CPU, as much as a small bag's replay
    (docs/BENCHMARKS.md, "Fleet").  The results, their Arrow tables with them, are
    pickled here by the standard library's pickler, as the pool's are, and handed to
    Ray as bytes: Ray's own serializer took 10 times as long for the same results,
    1.5 ms a bag, a seventh of a small bag's replay (docs/BENCHMARKS.md, "Fleet").
    ``_ray_results`` unpickles them: what Ray would have unpickled, from the same
    workers."""
    from supervisor.cache import quiet

    quiet()  # a worker Ray started again after a kill runs no ``_warm`` first
    return pickle.dumps([_one(task, done) for task in tasks], protocol=pickle.HIGHEST_PROTOCOL)


class RayEngine:
    """The tasks as Ray tasks: on the cluster at ``address`` (``ray start``, KubeRay),
    or on a local cluster of ``jobs`` CPUs started here and shut down at the end.  The
    task carries the bag's path, never its bytes: a cluster's workers read the bags on
    a filesystem they share with this process.  A worker that dies is Ray's to retry
    (``max_retries``); after ``ATTEMPTS`` deaths the bag is failed, as in
    ``LocalEngine``."""

    def __init__(self, jobs: int | None = None, address: str | None = None) -> None:
        self.jobs = jobs or os.cpu_count() or 1
        self.address = address
        if address is not None:
            _reachable(address)
        self._ray: Any = None  # the module, once this engine is on a cluster
        self._owns = False  # ... one it joined or started: left by close()
        self._temp: str | None = None  # a local cluster's sockets and logs
        self._stdout: TextIO | None = None  # while on a cluster (``RayNotes``)
        # the started workers' compiles of the configs (ObjectRefs of ``_warm``)
        self.warm: list[Any] = []

    def start(
        self, done: Collection[str], tasks: int | None = None, configs: tuple[str, ...] = ()
    ) -> None:
        """Join (or start) the cluster now, and have one worker compile ``configs``
        (``_warm``) while this process lists the archive: this process compiles
        nothing, as with ``LocalEngine.start`` (docs/BENCHMARKS.md, "Fleet").
        ``checked`` gives its verdict.  One task, not one per CPU: the raylet starts a
        worker for a lease and prestarts more for its backlog, and two leases at once
        on a node with no idle worker of the job started a worker more than the CPUs,
        left idle (docs/BENCHMARKS.md, "Fleet"); the other workers start with the
        first batches."""
        if tasks == 0 or not configs:
            return
        ray = self._connect()
        warm = ray.remote(num_cpus=1, max_retries=ATTEMPTS - 1)(_warm)
        self.warm = [warm.remote(configs)]

    def checked(self) -> list[str] | None:
        """The identities of the configs given to ``start``, as a started worker
        compiled them, its first config error raised (``UserError``); None when none
        was started or its worker died (the caller compiles them)."""
        if not self.warm:
            return None
        ray = self._ray
        try:
            answers = ray.get(self.warm[0])[1]
        except ray.exceptions.RayError:
            return None
        return _identities(answers)

    def close(self) -> None:
        """The cluster left (stopped, when this engine started it) and its temporary
        directory removed: also when ``results`` never ran (a bad config)."""
        self.warm = []
        if self._ray is not None and self._owns:
            self._ray.shutdown()
        self._ray, self._owns = None, False
        if self._temp is not None:
            shutil.rmtree(self._temp, ignore_errors=True)
            self._temp = None
        if self._stdout is not None:  # Ray's threads are stopped: its notes are done
            sys.stdout, self._stdout = self._stdout, None

    def _connect(self) -> Any:
        """``ray``, on the cluster this engine joined or started (once)."""
        if self._ray is not None:
            return self._ray
        ray = import_ray()
        if not ray.is_initialized():  # a cluster this engine joins or starts
            if not self.address:
                self._temp = tempfile.mkdtemp(prefix="ss-fleet-ray-")
            try:
                self._init(ray, self._temp)
            except BaseException:
                self.close()
                raise
            self._owns = True
        # after its init, which may look at the real stdout: Ray's listener thread
        # looks sys.stdout up at each message
        self._stdout, sys.stdout = sys.stdout, RayNotes(sys.stderr)
        self._ray = ray
        return ray

    def results(self, tasks: list[BagTask], done: Collection[str]) -> Iterator[BagResult]:
        running: dict[Any, list[BagTask]] = {}
        ray = self._ray or import_ray()  # for the finally's cancel
        try:
            ray = self._connect()
            if not tasks:
                return
            remote = ray.remote(num_cpus=1, max_retries=ATTEMPTS - 1)(_run_ray)
            done_ref = ray.put(frozenset(done))  # once in the object store, not per task
            # A window of tasks in flight, a few per CPU, not the whole archive: each
            # ray.wait looks at every pending task, and the results waiting for this
            # process stay few.
            cpus = int(ray.cluster_resources().get("CPU", 1))
            window = max(4, RAY_WINDOW_PER_CPU * cpus)
            todo = iter(tasks)
            unsent = len(tasks)

            def send() -> None:
                nonlocal unsent
                # fewer bags a task as the unsent run out: no worker left with a long one
                batch = list(itertools.islice(todo, max(1, min(RAY_BATCH, unsent // window))))
                unsent -= len(batch)
                running[remote.remote(batch, done_ref)] = batch

            while unsent and len(running) < window:
                send()
            while running:
                ready, _ = ray.wait(list(running), num_returns=1)
                for ref in ready:
                    batch = running.pop(ref)
                    if unsent:
                        send()
                    results = _ray_results(ray, ref, batch)
                    if results is None:  # a task of several bags failed: each goes alone,
                        for t in batch:  # so one bag's death is not its neighbours' row
                            running[remote.remote([t], done_ref)] = [t]
                        continue
                    yield from results
        finally:
            # closed early (an error, Ctrl-C): the tasks not finished are cancelled
            for ref in running:
                with contextlib.suppress(Exception):
                    ray.cancel(ref, force=True)
            self.close()

    def _init(self, ray: Any, temp: str | None) -> None:
        # ray.init makes SIGTERM the driver's sys.exit: the command's own handler
        # (stopping.py) is put back, so that SIGTERM stops a run as Ctrl-C does
        main = threading.current_thread() is threading.main_thread()
        term = signal.getsignal(signal.SIGTERM) if main else None
        try:
            self._join(ray, temp)
        finally:
            if term is not None:
                signal.signal(signal.SIGTERM, term)

    def _join(self, ray: Any, temp: str | None) -> None:
        quiet = {"logging_level": logging.ERROR, "log_to_driver": False}
        if self.address:
            try:
                ray.init(address=self.address, **quiet)
            except Exception as e:  # noqa: BLE001 - Ray's many connection errors are one line
                raise UserError(
                    f"cannot join the Ray cluster at {printable(self.address)}: "
                    f"{printable(' '.join(str(e).split()))[:300]}",
                    file="fleet replay",
                    hint="the address of a running cluster (ray start --head prints it)",
                ) from None
            return
        # a local cluster: our CPUs, no dashboard, its sockets and logs in our own
        # temporary directory (removed at the end), no usage report
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
        try:
            ray.init(num_cpus=self.jobs, include_dashboard=False, _temp_dir=temp, **quiet)
        except Exception as e:  # noqa: BLE001 - a cluster that cannot start is one line
            raise UserError(
                f"cannot start a local Ray cluster: {printable(' '.join(str(e).split()))[:300]}",
                file="fleet replay",
                hint="--engine local runs the same tasks in a process pool",
            ) from None


def _reachable(address: str) -> None:
    """``HOST:PORT`` of a cluster that answers, or one line: Ray's own client retries
    an unreachable address for minutes, printing warnings."""
    host, _, port = address.rpartition(":")
    where = printable(address)
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise UserError(
            f"--address {where!r} is not HOST:PORT",
            file="fleet replay",
            hint="the address ray start --head prints, as 10.0.0.5:6379",
        )
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=REACH_S).close()
    except OSError as e:
        raise UserError(
            f"cannot reach the Ray cluster at {where}: {e.strerror or e}",
            file="fleet replay",
            hint="is the cluster up (ray status on its head node)?",
        ) from None


def _ray_results(ray: Any, ref: Any, batch: list[BagTask]) -> list[BagResult] | None:
    """A Ray task's results, or each of its bags failed with the reason: its worker
    died on every attempt (Ray retried the whole task; nothing of it was written),
    or a node was lost.  None for a task of several bags that failed: which of its
    bags failed it is not known, and the caller sends each again alone."""
    try:
        results: list[BagResult] = pickle.loads(ray.get(ref))  # _run_ray pickled them
        return results
    except ray.exceptions.RayError as e:
        if len(batch) > 1:
            return None
        if isinstance(e, ray.exceptions.WorkerCrashedError):
            return [BagResult(batch[0], "failed", f"its worker process died {ATTEMPTS} times")]
        cause = getattr(e, "cause", None) or e
        why = _reason(f"internal error: {type(cause).__name__}: {cause}")
        return [BagResult(batch[0], "failed", why)]


def import_ray() -> Any:
    """``ray``, or the one line that says how to install it."""
    try:
        import ray
    except ImportError:
        raise UserError(
            "--engine ray needs Ray, which the base install leaves out",
            file="fleet replay",
            hint=RAY_MISSING,
        ) from None
    return ray
