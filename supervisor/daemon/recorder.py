"""Recording the daemon's inputs and records into rosbag2 MCAP bags (``run --record``).

Every input message goes into the bag as it arrived (serialized CDR, its own topic
and type) with the daemon's receive time; the daemon's log lines go to
``RECORDS_TOPIC`` as ``std_msgs/msg/String``, so one bag shows inputs and violations
on one timeline (docs/reference/config.md, record; docs/reference/log.md).

The receive loop only appends to a queue (``message``, ``record``); a sender thread
passes it in batches through a pipe to a writer process
(:mod:`supervisor.daemon.record_writer`), which encodes and writes with rosbags'
rosbag2 writer, so that work does not compete with the loop for the GIL. Recording
never stops monitoring: a full queue drops and counts, a write error or the writer's
death stops the recording and is reported once through ``on_stopped``. No rclpy here,
so it is tested without ROS.
"""

from __future__ import annotations

import collections
import contextlib
import fcntl
import json
import os
import re
import select
import struct
import subprocess
import sys
import threading
import time
from array import array
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from supervisor.children import child_env, start
from supervisor.names import RECORDS_TOPIC as RECORDS_TOPIC

if TYPE_CHECKING:
    from supervisor.config.record import RecordConfig

RECORDS_TYPE = "std_msgs/msg/String"
# The input index of a queue entry that carries an input's offered QoS profiles (JSON:
# {"input": i, "profiles": [...]}) rather than a message; -1 is a log record.
QOS_INDEX = -2
# A bag directory: its first message's UTC time and a sequence number that goes on
# across rotations and restarts (the next free one in the directory).
BAG_NAME = re.compile(r"^(\d{8}T\d{6}Z)_(\d{6,})$")
# MCAP's per-message overhead in the file (record header, index entry), for the size
# rotation; the exact size is only known once the chunk is written.
MESSAGE_OVERHEAD = 47
# Records are few and are the evidence: they may exceed the message bound by this many
# so that a flood of inputs cannot push a violation out of the recording.
RECORD_RESERVE = 1000
MB = 1 << 20
# A batch's header for the writer process (count, payload bytes, dropped so far), and
# the bytes per message before the payloads (int64 time, int32 index, uint32 length).
HEAD = struct.Struct("=IIq")
PER_MESSAGE = 16
F_SETPIPE_SZ = getattr(fcntl, "F_SETPIPE_SZ", 1031)
PIPE_BYTES = 1 << 20  # Linux's limit for an unprivileged process (fs.pipe-max-size)


@dataclass(frozen=True)
class RecorderStats:
    written: int  # messages and records in the bags
    dropped: int  # not queued: the writer was behind by queue_messages / queue_bytes
    skipped: int  # messages of topics whose type could not be described (never recorded)
    lost: int  # queued or offered after the recording stopped
    bytes: int  # payload bytes written
    bags: int  # bags begun by this recorder
    stopped: str | None  # why the recording stopped, None while it runs or after close()


def bag_dirs(directory: Path) -> list[tuple[int, Path]]:
    """The bag directories a recorder made in ``directory``, oldest first."""
    out = []
    for p in directory.iterdir() if directory.is_dir() else ():
        m = BAG_NAME.match(p.name)
        if m and p.is_dir():
            out.append((int(m.group(2)), p))
    return sorted(out)


def _duration(value: Any) -> dict[str, int]:
    """An rclpy Duration as rmw_time_t ({sec, nsec}); infinite (2**63 - 1 ns) comes out
    as RMW_DURATION_INFINITE, as rosbag2 writes it."""
    ns = int(value.nanoseconds)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def offered_profile(qos: Any) -> dict[str, Any]:
    """An rclpy QoSProfile as a rosbag2 offered-QoS entry (metadata version 9: the
    policies by their rmw names, e.g. ``transient_local``; docs/reference/config.md,
    record). Duck-typed, so this module stays free of rclpy."""
    return {
        "history": qos.history.name.lower(),
        "depth": int(qos.depth),
        "reliability": qos.reliability.name.lower(),
        "durability": qos.durability.name.lower(),
        "deadline": _duration(qos.deadline),
        "lifespan": _duration(qos.lifespan),
        "liveliness": qos.liveliness.name.lower(),
        "liveliness_lease_duration": _duration(qos.liveliness_lease_duration),
        "avoid_ros_namespace_conventions": bool(qos.avoid_ros_namespace_conventions),
    }


def frame(batch: Sequence[tuple[int, int, bytes]], dropped: int) -> bytes:
    """One batch for the writer process as one bytes object: ``HEAD`` (count n,
    payload bytes, messages dropped so far), n int64 receive times, n int32 input
    indices (-1: a log record), n uint32 lengths, then the payloads (native byte
    order: one machine). A few C-level passes over the batch, no Python per message."""
    if not batch:
        return HEAD.pack(0, 0, dropped)
    indices, times, payloads = zip(*batch, strict=True)
    lengths = array("I", map(len, payloads))
    parts = [
        HEAD.pack(len(indices), sum(lengths), dropped),
        array("q", times).tobytes(),
        array("i", indices).tobytes(),
        lengths.tobytes(),
    ]
    parts.extend(payloads)
    return b"".join(parts)


class Recorder:
    """Records input messages and log records into rotating rosbag2 MCAP bags.

    ``message`` and ``record`` may be called from any thread; they append to a queue
    under one short lock and never block on I/O or raise. ``inputs[i]`` is the
    (topic, ROS type) of input ``i``; ``message(i, ...)`` records on it.

    The bags are written by a child process (:mod:`supervisor.daemon.record_writer`,
    ``writer_pid``): a sender thread here takes the queue every ``poll_s`` and writes
    it to the child's stdin as one batch (one ``os.write``, which releases the GIL);
    a reader thread turns the child's reports into ``stats()`` and the callbacks.
    While the child is behind, the pipe is full and the queue fills up to its bound:
    beyond it messages are dropped and counted, the callers never wait.

    Times: callers pass ``time.monotonic_ns()``; the bag holds wall-clock time
    ``t_ns + wall_offset_ns`` with one offset fixed here, so differences between bag
    timestamps are exactly the differences of the receive times.

    Construction creates the directory and starts the child (OSError if it cannot);
    every later error (a failed write, the child's death) stops the recording and is
    reported once through ``on_stopped(reason)``. ``on_warning(text)`` says what the
    recording leaves out (a topic whose type cannot be described, messages dropped
    while the writer was behind).
    """

    def __init__(
        self,
        directory: str | Path,
        inputs: Sequence[tuple[str, str]],
        *,
        max_bag_bytes: int = 100 * MB,
        max_bag_s: float = 300.0,
        keep: int = 20,
        queue_messages: int = 100_000,
        queue_bytes: int = 64 * MB,
        on_stopped: Callable[[str], None] | None = None,
        on_warning: Callable[[str], None] | None = None,
        flush_s: float = 0.5,
        flush_messages: int = 10_000,
        poll_s: float = 0.05,
        msg_prefixes: Sequence[Path] | None = None,
    ) -> None:
        if keep < 1 or max_bag_bytes < 1 or max_bag_s <= 0 or queue_messages < 1:
            raise ValueError("keep, max_bag_bytes, max_bag_s and queue_messages must be positive")
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.inputs = [(str(topic), str(msgtype)) for topic, msgtype in inputs]
        self.wall_offset_ns = time.time_ns() - time.monotonic_ns()
        self._max_queue = queue_messages
        self._max_queue_bytes = queue_bytes
        self._on_stopped = on_stopped
        self._on_warning = on_warning
        self._poll_s = poll_s

        # Shared with the callers, under _lock: the queue and what it holds.
        self._lock = threading.Lock()
        self._queue: collections.deque[tuple[int, int, bytes]] = collections.deque()
        self._queued = 0
        self._queued_bytes = 0
        self._dropped = 0
        self._lost = 0
        self._stopped = False

        # The reader thread's: the child's latest counts and why the recording stopped.
        self._counts: dict[str, int] = {}
        self._reason: str | None = None
        self._reported_stop = False
        self._kill_reason: str | None = None
        self._reported_drops = 0
        self._last_drop_report = 0.0
        self._offered: dict[int, list[dict[str, Any]]] = {}  # last sent, by input

        settings = {
            "directory": str(self.directory),
            "inputs": self.inputs,
            "wall_offset_ns": self.wall_offset_ns,
            "max_bag_bytes": max_bag_bytes,
            "max_bag_ns": int(max_bag_s * 1e9),
            "keep": keep,
            "flush_ns": int(flush_s * 1e9),
            "flush_messages": flush_messages,
            "msg_prefixes": None if msg_prefixes is None else [str(p) for p in msg_prefixes],
        }
        # No parent-death signal: EOF on its stdin tells the child that the daemon is
        # gone (even after SIGKILL), and it closes the bag before it exits; a signal
        # would also fire when the thread that made this recorder ends.
        self._proc = start(
            [sys.executable, "-m", "supervisor.daemon.record_writer", json.dumps(settings)],
            env=child_env(),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            parent_death_signal=None,
        )
        assert self._proc.stdin is not None and self._proc.stdout is not None
        self._pipe = self._proc.stdin.fileno()
        os.set_blocking(self._pipe, False)  # the sender waits in select, abortable
        with contextlib.suppress(OSError):  # room for about 50 ms at 20k msg/s
            fcntl.fcntl(self._pipe, F_SETPIPE_SZ, PIPE_BYTES)

        self._closing = threading.Event()
        self._abort = threading.Event()
        self._sender = threading.Thread(target=self._send_loop, name="recorder", daemon=True)
        self._reader = threading.Thread(target=self._read_loop, name="recorder-in", daemon=True)
        self._sender.start()
        self._reader.start()

    @property
    def writer_pid(self) -> int:
        """The writer process's pid."""
        return self._proc.pid

    @classmethod
    def from_config(
        cls,
        config: RecordConfig,
        inputs: Sequence[tuple[str, str]],
        *,
        path: str | Path | None = None,
        on_stopped: Callable[[str], None] | None = None,
        on_warning: Callable[[str], None] | None = None,
    ) -> Recorder:
        """A recorder with the ``record:`` section's settings; ``path`` (``run
        --record``) overrides ``record.path``."""
        directory = path if path is not None else config.path
        if directory is None:
            raise ValueError("no directory to record into (record.path or run --record)")
        return cls(
            directory,
            inputs,
            max_bag_bytes=config.max_bag_bytes,
            max_bag_s=config.max_bag_s,
            keep=config.keep,
            queue_messages=config.queue_messages,
            on_stopped=on_stopped,
            on_warning=on_warning,
        )

    # -- the callers' side: cheap, never blocks on I/O, never raises ---------------

    def message(self, index: int, t_ns: int, data: bytes) -> None:
        """Input ``index``'s serialized message, received at monotonic ``t_ns``."""
        n = len(data)
        with self._lock:
            if self._stopped:
                self._lost += 1
            elif self._queued >= self._max_queue or self._queued_bytes + n > self._max_queue_bytes:
                self._dropped += 1
            else:
                self._queued += 1
                self._queued_bytes += n
                self._queue.append((index, t_ns, data))

    def offered_qos(self, index: int, profiles: Iterable[Any]) -> None:
        """The QoS profiles (rclpy QoSProfile) the publishers of input ``index``'s topic
        offer, as the node sees them in the graph: written as the topic's
        ``offered_qos_profiles`` so that ``ros2 bag play`` keeps its reliability and
        durability. A change while a bag holds the topic starts a new bag."""
        # The graph lists publishers in no fixed order: sorted, so that only a real
        # change starts a new bag.
        dicts = sorted(map(offered_profile, profiles), key=lambda d: json.dumps(d, sort_keys=True))
        if self._offered.get(index) == dicts:
            return
        self._offered[index] = dicts
        data = json.dumps({"input": index, "profiles": dicts}).encode()
        with self._lock:
            # Never dropped: rare and small, and a bag without it loses latching.
            if not self._stopped:
                self._queued += 1
                self._queued_bytes += len(data)
                self._queue.append((QOS_INDEX, time.monotonic_ns(), data))

    def record(self, t_ns: int, json_text: str) -> None:
        """One log line (a JSON record) made at monotonic ``t_ns``, for RECORDS_TOPIC."""
        data = json_text.encode()
        with self._lock:
            if self._stopped:
                self._lost += 1
            elif self._queued >= self._max_queue + RECORD_RESERVE:
                self._dropped += 1
            else:
                self._queued += 1
                self._queued_bytes += len(data)
                self._queue.append((-1, t_ns, data))

    def stats(self) -> RecorderStats:
        with self._lock:
            dropped, lost = self._dropped, self._lost
        counts = self._counts
        return RecorderStats(
            written=counts.get("written", 0),
            dropped=dropped,
            skipped=counts.get("skipped", 0),
            lost=lost,
            bytes=counts.get("bytes", 0),
            bags=counts.get("bags", 0),
            stopped=self._reason,
        )

    def close(self, timeout_s: float = 30.0) -> RecorderStats:
        """Sends what is queued and waits for the writer process to write it, close
        the bag (index and metadata.yaml) and exit; at most ``timeout_s``, then the
        writer is killed (the bag is then readable up to its last flushed chunk)."""
        deadline = time.monotonic() + timeout_s
        self._closing.set()
        self._sender.join(max(0.0, deadline - time.monotonic()))
        if self._sender.is_alive():  # the child takes nothing: stop offering
            self._abort.set()
            self._sender.join()
        if self._proc.stdin is not None:
            with contextlib.suppress(OSError):
                self._proc.stdin.close()  # EOF: the child's end
        self._reader.join(max(0.0, deadline - time.monotonic()))
        if self._reader.is_alive():
            self._kill_reason = (
                f"recording stopped: the writer process did not finish within {timeout_s:g} s "
                "and was killed; the bag is readable up to its last flushed chunk"
            )
            self._proc.kill()
            self._reader.join()
        with self._lock:  # from now on message() and record() only count
            self._stopped = True
        return self.stats()

    # -- the sender thread --------------------------------------------------------------

    def _send_loop(self) -> None:
        try:
            while True:
                closing = self._closing.wait(self._poll_s)
                batch = self._take()
                if (batch or closing) and not self._send(frame(batch, self._dropped)):
                    with self._lock:
                        self._lost += len(batch)
                self._report_drops(final=closing)
                if closing and not self._queue:
                    return
        except Exception as e:  # whatever fails ends the recording, never the daemon
            self._stop(f"recording stopped: {type(e).__name__}: {e}")

    def _take(self) -> collections.deque[tuple[int, int, bytes]]:
        with self._lock:  # a swap, so the callers never wait for a copy
            batch, self._queue = self._queue, collections.deque()
            self._queued = 0
            self._queued_bytes = 0
        return batch

    def _send(self, data: bytes) -> bool:
        """All of ``data`` into the pipe; False if the child is gone or the recording
        stopped meanwhile. Waits while the pipe is full, never the callers."""
        view = memoryview(data)
        while view:
            if self._abort.is_set():
                return False
            try:
                view = view[os.write(self._pipe, view) :]
            except BlockingIOError:
                select.select([], [self._pipe], [], 0.1)
                self._report_drops()
            except OSError:  # EPIPE: the child ended; the reader says why
                self._abort.set()
                return False
        return True

    def _report_drops(self, *, final: bool = False) -> None:
        dropped = self._dropped
        now = time.monotonic()
        if dropped > self._reported_drops and (final or now - self._last_drop_report >= 1.0):
            self._warn(
                f"recording fell behind: {dropped - self._reported_drops} messages dropped "
                f"({dropped} in all; record.queue_messages is {self._max_queue})"
            )
            self._reported_drops = dropped
            self._last_drop_report = now

    # -- the reader thread: the child's reports -------------------------------------

    def _read_loop(self) -> None:
        closed = False
        assert self._proc.stdout is not None
        for line in self._proc.stdout:
            try:
                obj = json.loads(line)
            except ValueError:
                continue
            if not isinstance(obj, dict):
                continue
            if isinstance(obj.get("stats"), dict):
                self._counts = obj["stats"]
                closed = closed or bool(obj.get("closed"))
            if "warning" in obj:
                self._warn(str(obj["warning"]))
            if "stopped" in obj:
                self._stop(str(obj["stopped"]), int(obj.get("lost", 0)))
        code = self._proc.wait()
        if not closed:
            how = f"was killed by signal {-code}" if code < 0 else f"exited with status {code}"
            self._stop(
                self._kill_reason
                or f"recording stopped: the writer process (pid {self._proc.pid}) {how}; "
                "the bag is readable up to its last flushed chunk"
            )

    def _warn(self, text: str) -> None:
        if self._on_warning is not None:
            try:
                self._on_warning(text)
            except Exception:  # the daemon's callback must not end the recording
                pass

    def _stop(self, reason: str, child_lost: int = 0) -> None:
        """The recording ends (once): what is queued and what the child did not write
        count as lost, and the sender stops waiting for the pipe."""
        with self._lock:
            self._lost += self._queued + child_lost
            if self._reported_stop:
                return
            self._reported_stop = True
            self._stopped = True
            self._queue.clear()
            self._queued = 0
            self._queued_bytes = 0
        self._reason = reason
        self._abort.set()
        if self._on_stopped is not None:
            try:
                self._on_stopped(reason)
            except Exception:  # the daemon's callback must not end the recording
                pass


def benchmark(rate_hz: float = 20_000.0, seconds: float = 2.0, size: int = 16) -> dict[str, float]:
    """Cost of ``message()`` on the caller's thread at ``rate_hz`` messages of ``size``
    bytes (paced, with the writer thread running), and the writer thread's
    throughput (a backlog of messages written as fast as it can)."""
    import tempfile

    data = bytes(size)
    out: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        rec = Recorder(Path(tmp) / "paced", [("/x", "std_msgs/msg/Int64")], max_bag_s=1e6)
        n = int(rate_hz * seconds)
        period = 1e9 / rate_hz
        costs = []
        start = time.perf_counter_ns()
        for i in range(n):
            due = start + i * period
            while time.perf_counter_ns() < due:
                pass
            t0 = time.perf_counter_ns()
            rec.message(0, t0, data)
            costs.append(time.perf_counter_ns() - t0)
        stats = rec.close()
        costs.sort()
        out["call_ns_median"] = costs[len(costs) // 2]
        out["call_ns_p99"] = costs[int(len(costs) * 0.99)]
        out["call_ns_p999"] = costs[int(len(costs) * 0.999)]
        out["call_ns_max"] = costs[-1]
        out["paced_written"] = stats.written
        out["paced_dropped"] = stats.dropped

        # Throughput: fill the queue first, then time how long the writer takes.
        n = 200_000
        rec = Recorder(
            Path(tmp) / "backlog",
            [("/x", "std_msgs/msg/Int64")],
            max_bag_s=1e6,
            queue_messages=n + 1,
            queue_bytes=n * size + 1,
            poll_s=3600,
        )
        t0 = time.perf_counter_ns()
        for i in range(n):
            rec.message(0, i, data)
        out["unpaced_call_ns_mean"] = (time.perf_counter_ns() - t0) / n
        t0 = time.perf_counter_ns()
        stats = rec.close()
        out["writer_msgs_per_s"] = stats.written / ((time.perf_counter_ns() - t0) / 1e9)
    return out


if __name__ == "__main__":
    for key, value in benchmark().items():
        print(f"{key:24} {value:,.0f}")
