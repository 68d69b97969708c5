"""What an input lost, and which of its messages were the daemon's own.

No rclpy here. The message info of rclpy's ``take_message`` carries the
writer's ``publication_sequence_number`` (1, 2, 3, ... per publisher) and its
``source_timestamp`` (CLOCK_REALTIME at the write) but no publisher id
(rclpy 7, rmw_fastrtps_cpp). So:

* :class:`SequenceStreams` tells the publishers of one topic apart by the
  continuity of their sequence numbers and counts the gaps: exact with one
  publisher per topic, a best guess of the split (not of the total) when
  several publishers' numbers interleave closely. What a publisher sent before
  the first message heard from it is not counted: it may have been sent before
  the subscription matched (its first number is reported instead); nor is what
  it sent after the last one heard, which no later number reveals (the last
  number is reported, so whoever knows what was sent can tell;
  docs/reference/ros-interfaces.md#lost-messages);
* :class:`OwnWrites` remembers what the daemon's own publishers wrote (their
  sequence number and the real-time window of the write), so a mitigation's
  message that comes back on an input topic is recognised and never taken
  for the robot's (docs/reference/faults.md, "The supervisor's own messages").
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

MAX_STREAMS = 32  # publishers remembered per input (least recently heard dropped)
OWN_WRITES_KEPT = 256  # own writes remembered per topic (latched ones come back late)


@dataclass
class _Stream:
    first: int  # the first number heard: what came before may predate our match
    last: int
    heard: int  # order of last use, for dropping the least recently heard
    received: int = 1
    lost: int = 0


class SequenceStreams:
    """One input's publication sequence numbers -> messages lost, per publisher."""

    def __init__(self) -> None:
        self._streams: list[_Stream] = []
        self._clock = 0
        self.lost = 0

    def on_sequence(self, seq: int) -> int:
        """A message with publication sequence number ``seq`` was taken; how
        many of its publisher's messages were skipped since the previous one."""
        self._clock += 1
        best: _Stream | None = None
        for s in self._streams:
            if s.last < seq and (best is None or s.last > best.last):
                best = s
        if best is None:
            # A publisher heard for the first time (or restarted): what it sent
            # before we matched was never ours to receive, so it is not loss.
            self._streams.append(_Stream(seq, seq, self._clock))
            if len(self._streams) > MAX_STREAMS:
                self._streams.remove(min(self._streams, key=lambda s: s.heard))
            return 0
        gap = seq - best.last - 1
        best.last, best.heard = seq, self._clock
        best.received += 1
        best.lost += gap
        self.lost += gap
        return gap

    def by_publisher(self) -> list[dict[str, int]]:
        """Per publisher stream: the first and the last sequence number heard,
        messages received and lost between them (``last - first + 1 ==
        received + lost``)."""
        return [
            {"first": s.first, "last": s.last, "received": s.received, "lost": s.lost}
            for s in self._streams
        ]


class OwnWrites:
    """The daemon's own writes per topic: (sequence number, real-time window)."""

    def __init__(self) -> None:
        self._by_topic: dict[str, deque[tuple[int, int, int]]] = {}
        self._lock = threading.Lock()  # actions may publish from worker threads

    def wrote(self, topic: str, seq: int, t0_ns: int, t1_ns: int) -> None:
        with self._lock:
            q = self._by_topic.get(topic)
            if q is None:
                q = self._by_topic[topic] = deque(maxlen=OWN_WRITES_KEPT)
            q.append((seq, t0_ns, t1_ns))

    def is_own(self, topic: str, seq: int, source_ns: int | None) -> bool:
        """A message with this sequence number and source timestamp is one we wrote:
        the same number, stamped inside the window of our write."""
        q = self._by_topic.get(topic)
        if not q or source_ns is None:
            return False
        with self._lock:
            return any(s == seq and t0 <= source_ns <= t1 for s, t0, t1 in q)


class RecordingPublisher:
    """An rclpy publisher whose writes are remembered in :class:`OwnWrites`.

    The writer numbers its samples 1, 2, 3, ...; the n-th ``publish`` is
    sample n, stamped between the two clock reads around it."""

    def __init__(self, inner: Any, topic: str, own: OwnWrites) -> None:
        self.inner = inner
        self.topic = topic
        self._own = own
        self._written = 0
        self._lock = threading.Lock()

    def publish(self, msg: Any) -> None:
        with self._lock:
            t0 = time.time_ns()
            self.inner.publish(msg)
            t1 = time.time_ns()
            self._written += 1
            self._own.wrote(self.topic, self._written, t0, t1)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


class LossReports:
    """What the daemon says of lost messages: one ``input_lost`` record per input
    that lost messages since the last report, the count since the last
    ``/diagnostics``, and the ``stop`` record's per-input figures."""

    def __init__(self, log: Any, warn: Callable[[str], None]) -> None:
        self.log = log
        self.warn = warn
        self._reported: dict[str, int] = {}  # per input: lost total last logged
        self._at_diagnostics: dict[str, int] = {}  # per input: lost total last on /diagnostics

    def report(
        self,
        stats: dict[str, dict[str, Any]],
        inputs: Iterable[tuple[str, str | None, SequenceStreams | None]],
    ) -> None:
        """``stats``: the core's input_stats(); ``inputs``: (name, topic, streams) each."""
        for name, topic, streams in inputs:
            total = stats[name]["lost"]
            new = total - self._reported.get(name, 0)
            if new <= 0:
                continue
            self._reported[name] = total
            self.warn(f"input '{name}': {new} messages lost ({total} so far) on {topic}")
            self.log.supervisor(
                "input_lost",
                input=name,
                topic=topic,
                lost=new,
                total=total,
                by_publisher=streams.by_publisher() if streams else [],
            )

    def since_diagnostics(self, name: str, total: int) -> int:
        """Messages of input ``name`` lost since the last /diagnostics (``total`` so far)."""
        recent = total - self._at_diagnostics.get(name, 0)
        self._at_diagnostics[name] = total
        return recent


def stop_stats(
    stats: dict[str, dict[str, Any]], streams: dict[str, SequenceStreams | None]
) -> dict[str, dict[str, Any]]:
    """Per input, for the ``stop`` record: the counts, and per publisher stream
    the first and last number heard, received and lost: what a publisher sent
    outside them is not counted as lost, but whoever knows what it sent can
    (docs/reference/ros-interfaces.md#lost-messages)."""
    out: dict[str, dict[str, Any]] = {}
    for name, st in stats.items():
        out[name] = {k: st[k] for k in ("messages", "rejected", "nan", "lost", "own")}
        seqs = streams.get(name)
        out[name]["by_publisher"] = seqs.by_publisher() if seqs else []
    return out
