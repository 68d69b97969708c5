"""systemd notify protocol (``Type=notify``, ``WatchdogSec=``) through sdnotify.

sdnotify 0.3 handles ``NOTIFY_SOCKET`` paths and abstract sockets (``@name``
becomes ``\\0name``).  What this wrapper adds:

* errors are recorded and reported once on stderr instead of being swallowed
  silently (sdnotify's default) or raised (its debug mode): a send failure
  never reaches the caller;
* the socket is connected once, and again after a failure (systemd recreates
  its notify socket on ``daemon-reexec``);
* ``RELOADING=1`` carries ``MONOTONIC_USEC=`` in the same datagram, as systemd
  >= 253 requires for ``Type=notify-reload``;
* ``STATUS=`` text is sent as UTF-8 on one line (sdnotify encodes Latin-1,
  and a newline would start a new assignment).

Without ``NOTIFY_SOCKET`` every call is a no-op returning False.  ``vsock:``
addresses (systemd >= 254, VMs) are not supported and are treated as absent.
"""

from __future__ import annotations

import os
import socket
import sys
import time

import sdnotify


class _SdNotifier(sdnotify.SystemdNotifier):
    """sdnotify's notifier for a given address (its own __init__ reads the
    environment each time, which the daemon may have cleaned), raising on error."""

    def __init__(self, address: str) -> None:
        self.debug = True
        self.socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            self.socket.connect("\0" + address[1:] if address.startswith("@") else address)
        except OSError:
            self.socket.close()
            raise
        # Never block the monitoring loop on a reader that does not read (a full
        # socket queue): the datagram is dropped and the failure reported once.
        self.socket.setblocking(False)


def watchdog_interval() -> float | None:
    """Seconds between ``WATCHDOG=1`` pings: half of ``WATCHDOG_USEC`` (systemd's
    advice), or None when the watchdog is off or meant for another process
    (``WATCHDOG_PID`` set and not ours)."""
    pid = os.environ.get("WATCHDOG_PID")
    if pid:
        try:
            if int(pid) != os.getpid():
                return None
        except ValueError:
            return None
    try:
        usec = int(os.environ.get("WATCHDOG_USEC", ""))
    except ValueError:
        return None
    return usec / 2e6 if usec > 0 else None


class Notifier:
    """``READY=1``, ``STATUS=``, ``WATCHDOG=1``, ``RELOADING=1``, ``STOPPING=1``.

    The environment is read when the Notifier is created; ``unset_environment``
    then removes ``NOTIFY_SOCKET`` so that mitigation commands started later do
    not inherit it (as sd_notify(3)'s flag of that name)."""

    def __init__(self, *, unset_environment: bool = False) -> None:
        self._address = os.environ.get("NOTIFY_SOCKET") or None
        if self._address is not None and not self._address.startswith(("/", "@")):
            self._address = None  # vsock: and relative names: not ours to guess
        if unset_environment:
            os.environ.pop("NOTIFY_SOCKET", None)
        self._notifier: sdnotify.SystemdNotifier | None = None
        self.last_error: str | None = None
        self.failures = 0

    @property
    def enabled(self) -> bool:
        return self._address is not None

    def ready(self, status: str | None = None) -> bool:
        return self.send("READY=1", status=status)

    def status(self, text: str) -> bool:
        return self.send(status=text)

    def watchdog(self) -> bool:
        return self.send("WATCHDOG=1")

    def reloading(self, status: str | None = None) -> bool:
        usec = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
        return self.send("RELOADING=1", f"MONOTONIC_USEC={usec}", status=status)

    def stopping(self, status: str | None = None) -> bool:
        return self.send("STOPPING=1", status=status)

    def send(self, *assignments: str, status: str | None = None) -> bool:
        """One datagram of ``KEY=value`` lines; True when it was sent."""
        if self._address is None:
            return False
        lines = list(assignments)
        if status is not None:
            lines.append("STATUS=" + " ".join(status.splitlines()))
        # sdnotify encodes with Latin-1; decoding UTF-8 bytes as Latin-1 makes it
        # send exactly those bytes.
        payload = "\n".join(lines).encode("utf-8").decode("latin-1")
        for attempt in range(2):  # the second after reconnecting
            try:
                if self._notifier is None:
                    self._notifier = _SdNotifier(self._address)
                self._notifier.notify(payload)
            except Exception as e:  # noqa: BLE001 - sdnotify raises whatever socket raises
                self._drop()
                if attempt == 1:
                    self._failed(e)
                continue
            if self.last_error is not None:
                self._report(f"systemd notify: {self._address}: sending again")
                self.last_error = None
            return True
        return False

    def close(self) -> None:
        self._drop()

    def _drop(self) -> None:
        n, self._notifier = self._notifier, None
        sock = getattr(n, "socket", None)
        if sock is not None:
            sock.close()

    def _failed(self, e: Exception) -> None:
        self.failures += 1
        text = f"{type(e).__name__}: {e}"
        if text != self.last_error:  # once per distinct error, not per watchdog ping
            self._report(f"systemd notify: {self._address}: {text}")
        self.last_error = text

    @staticmethod
    def _report(text: str) -> None:
        try:
            print(text, file=sys.stderr, flush=True)
        except (OSError, ValueError):
            pass
