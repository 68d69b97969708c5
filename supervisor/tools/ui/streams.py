"""The browsers' Server-Sent Event streams of one page (a robot's or the fleet's).

Each browser has a bounded queue: its first item is the page's snapshot, then every
message.  A browser that stops reading is dropped; it reconnects and starts again
from a snapshot (docs/reference/commands.md, "ui").
"""

from __future__ import annotations

import contextlib
import json
import queue
import threading
from collections.abc import Callable
from typing import Any

CLIENT_QUEUE = 1000  # messages a slow browser may fall behind before it is dropped


class Streams:
    """Thread-safe: the ROS threads broadcast, the HTTP threads subscribe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._clients: set[queue.Queue[str | None]] = set()

    def subscribe(self, snapshot: Callable[[], dict[str, Any]]) -> queue.Queue[str | None]:
        """A queue of SSE ``data`` lines, the snapshot first."""
        q: queue.Queue[str | None] = queue.Queue(CLIENT_QUEUE)
        with self._lock:
            self._clients.add(q)
        q.put(json.dumps(snapshot()))
        return q

    def unsubscribe(self, q: queue.Queue[str | None]) -> None:
        with self._lock:
            self._clients.discard(q)

    def broadcast(self, message: dict[str, Any]) -> None:
        line = json.dumps(message)
        with self._lock:
            clients = list(self._clients)
        for q in clients:
            try:
                q.put_nowait(line)
            except queue.Full:
                # a browser that stopped reading: drop it; it reconnects with a snapshot
                self.unsubscribe(q)
                with contextlib.suppress(queue.Empty):
                    q.get_nowait()
                q.put_nowait(None)

    def close(self) -> None:
        """Ends every stream (None wakes its handler)."""
        with self._lock:
            clients = list(self._clients)
            self._clients.clear()
        for q in clients:
            with contextlib.suppress(queue.Full):
                q.put_nowait(None)
