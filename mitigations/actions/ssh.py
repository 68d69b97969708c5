"""The ``ssh`` mitigation: run one command on another machine (typically: power the robot off).

Configuration (``mitigations:`` in the YAML)::

    power_off:
      ssh: {host: robot-pc.local, port: 22, user: safety, key: /etc/safety-supervisor/id_ed25519,
            known_hosts: /etc/safety-supervisor/known_hosts,
            command: sudo /usr/bin/systemctl poweroff,
            connect_timeout_s: 5, command_timeout_s: 10, retries: 3, backoff_s: 0.5}

What the supervisor does (paramiko):

* The server's host key must be in ``known_hosts`` (only that file; the system's
  and the user's known_hosts files are not read) under the name the config
  gives, ``host`` for port 22 and ``[host]:port`` otherwise, as OpenSSH writes
  it; hashed entries work.  An unknown or different host key is refused and
  never added, and it is not retried: retrying cannot fix it.
* Key authentication with the ``key`` file only: no agent, no ``~/.ssh`` keys,
  no password.  The key must not have a passphrase (the daemon runs unattended).
* ``connect_timeout_s`` bounds the TCP connect, the SSH banner, authentication
  and opening the session; ``command_timeout_s`` bounds the command.  The action
  succeeds only if the command exits with status 0.
* ``retries`` is the total number of attempts (default 3), with a wait of
  ``backoff_s`` (default 0.5 s) after the first failure, doubling after each
  further one, at most 5 s.  Only failures that happen before the command was
  sent are retried (refused, unreachable, timed out, name not resolved), since
  the command cannot have run yet.  A non-zero exit status, a command timeout
  or a connection lost while the command ran are not retried: the command may
  already have had its effect, and running it twice is not safe in general.
  Authentication and key-file problems are not retried either.
* The action runs on a worker thread of its own, so even the worst case
  (``retries`` x (connect + command timeouts) plus the backoffs) never delays
  the monitor; supervisor shutdown stops the retries at once.

Robot-side setup (Debian/Ubuntu, as root on the robot).  A dedicated user whose
key can do one thing only, power off::

    # 1. A system user without a password.  Its shell must be a real shell
    #    (sshd runs the forced command with it), not nologin.
    adduser --system --group --shell /bin/sh --home /var/lib/safety safety

    # 2. The supervisor's public key, restricted to one forced command.  'restrict'
    #    turns off port/agent/X11 forwarding and the pty; sshd runs the forced
    #    command whatever command the client asks for.  from="..." (the
    #    supervisor's address) narrows it further.
    install -d -m 700 -o safety -g safety /var/lib/safety/.ssh
    echo 'restrict,command="sudo /usr/bin/systemctl poweroff" ssh-ed25519 AAAA... safety-supervisor' \\
        > /var/lib/safety/.ssh/authorized_keys
    chown safety:safety /var/lib/safety/.ssh/authorized_keys
    chmod 600 /var/lib/safety/.ssh/authorized_keys

    # 3. sudo may run exactly 'systemctl poweroff' as root for this user, nothing else.
    echo 'safety ALL=(root) NOPASSWD: /usr/bin/systemctl poweroff' > /etc/sudoers.d/safety-supervisor
    chmod 440 /etc/sudoers.d/safety-supervisor
    visudo -cf /etc/sudoers.d/safety-supervisor

On the supervisor's machine::

    # The key pair (no passphrase), readable only by the user the daemon runs as.
    ssh-keygen -t ed25519 -N '' -C safety-supervisor -f /etc/safety-supervisor/id_ed25519
    # The robot's host key, under the exact 'host' (and port) of the config.  Compare
    # the fingerprint with 'ssh-keygen -lf /etc/ssh/ssh_host_ed25519_key.pub' run on
    # the robot itself before trusting it.
    ssh-keyscan -t ed25519 -p 22 robot-pc.local > /etc/safety-supervisor/known_hosts
    ssh-keygen -lf /etc/safety-supervisor/known_hosts

Set ``command`` in the config to the same forced command, so the log says what
runs.  ``systemctl poweroff`` queues the shutdown and exits 0 before sshd is
stopped, so the exit status normally arrives; should the connection drop first,
the record says the connection closed before an exit status.
"""

from __future__ import annotations

import os
import socket
import stat
import threading
import time
from typing import Any

import paramiko

from mitigations.actions.base import Outcome, RetryingAction, one_line
from mitigations.settings import SshSettings

TAIL_CHARS = 500  # of stderr/stdout kept in an outcome's detail
_KEEP_BYTES = 4096  # raw bytes kept per stream while reading (enough for TAIL_CHARS of UTF-8)


class _UnknownHostKey(paramiko.SSHException):
    """The server's host name has no key in our known_hosts."""

    def __init__(self, hostname: str, key: paramiko.PKey) -> None:
        super().__init__(hostname)
        self.hostname = hostname
        self.key = key


class _RejectUnknown(paramiko.RejectPolicy):
    """RejectPolicy (never adds a key) with an exception we can tell apart from others."""

    def missing_host_key(
        self, client: paramiko.SSHClient, hostname: str, key: paramiko.PKey
    ) -> None:
        raise _UnknownHostKey(hostname, key)


def _fingerprint(key: paramiko.PKey) -> str:
    return f"{key.get_name()} {key.fingerprint}"


class _Fail(Exception):
    """An attempt's failure: one-line message and whether retrying could help."""

    def __init__(self, message: str, retryable: bool, detail: dict[str, Any] | None = None) -> None:
        super().__init__(message)
        self.retryable = retryable
        self.detail = detail or {}


def _tail(buf: bytes | bytearray) -> str:
    return buf.decode("utf-8", errors="replace")[-TAIL_CHARS:]


def _where(s: SshSettings) -> str:
    host = f"[{s.host}]" if ":" in s.host else s.host  # IPv6 literal
    return f"ssh {s.user}@{host}:{s.port}"


def _host_key_name(s: SshSettings) -> str:
    """The name paramiko (and OpenSSH) look the host key up under."""
    return s.host if s.port == 22 else f"[{s.host}]:{s.port}"


def _key_error(key: str, e: Exception) -> str:
    if isinstance(e, OSError):
        return f"cannot read key {key}: {e.strerror or e}"
    # cryptography's wording differs by version and key format; both mention one of these.
    if isinstance(e, TypeError) and any(w in str(e).lower() for w in ("password", "encrypted")):
        return f"key {key} has a passphrase; the daemon needs a key without one"
    return f"key {key} is not a usable private key ({type(e).__name__}: {one_line(e, 200)})"


def preflight(s: SshSettings) -> list[str]:
    """Problems found without connecting: the key and known_hosts files (``check``)."""
    where, problems = _where(s), []
    try:
        mode = os.stat(s.key).st_mode
        paramiko.PKey.from_path(s.key)
    except Exception as e:  # noqa: BLE001 - any failure to read or load is the finding
        problems.append(f"{where}: {_key_error(s.key, e)}")
    else:
        if mode & (stat.S_IRWXG | stat.S_IRWXO):
            # ssh(1) itself refuses such a key; the secret should be the daemon's alone.
            problems.append(
                f"{where}: key {s.key} is accessible by group/others "
                f"(mode {stat.S_IMODE(mode):04o}); chmod 600 it"
            )
    try:
        keys = paramiko.HostKeys(s.known_hosts)
    except OSError as e:
        problems.append(f"{where}: known_hosts {s.known_hosts}: {e.strerror or e}")
    else:
        if keys.lookup(_host_key_name(s)) is None:
            problems.append(
                f"{where}: known_hosts {s.known_hosts} has no key for "
                f"{_host_key_name(s)} (every connection would be refused)"
            )
    return problems


class SshAction(RetryingAction):
    kind = "ssh"

    def __init__(self, name: str, settings: SshSettings) -> None:
        self.name = name
        self.host = settings.host
        self.port = settings.port
        self.user = settings.user
        self.key = settings.key
        self.known_hosts = settings.known_hosts
        self.command = settings.command
        self.connect_timeout_s = settings.connect_timeout_s
        self.command_timeout_s = settings.command_timeout_s
        self.retries = settings.retries
        self.backoff_s = settings.backoff_s
        self.where = _where(settings)
        self.host_key_name = _host_key_name(settings)

    def __repr__(self) -> str:
        return f"SshAction({self.name!r}, {self.where!r}, {self.command!r})"

    # -- running -------------------------------------------------------------------------

    def attempt(self, cancel: threading.Event) -> tuple[Outcome, bool]:
        try:
            return self._connect_and_run(cancel), False
        except _Fail as f:
            return Outcome(False, f"{self.where}: {f}", detail=f.detail), f.retryable

    def _connect_and_run(self, cancel: threading.Event) -> Outcome:
        try:
            pkey = paramiko.PKey.from_path(self.key)
        except Exception as e:  # noqa: BLE001 - any failure to load the key means: no attempt
            raise _Fail(_key_error(self.key, e), retryable=False) from e
        client = paramiko.SSHClient()
        try:
            try:
                # Only this file: the system's known_hosts must not vouch for the robot.
                client.load_host_keys(self.known_hosts)
            except OSError as e:
                raise _Fail(
                    f"cannot read known_hosts {self.known_hosts}: {e.strerror or e}", False
                ) from e
            client.set_missing_host_key_policy(_RejectUnknown())
            self._connect(client, pkey)
            return self._exec(client, cancel)
        finally:
            client.close()

    def _connect(self, client: paramiko.SSHClient, pkey: paramiko.PKey) -> None:
        t = self.connect_timeout_s
        start = time.monotonic()
        try:
            client.connect(
                self.host,
                port=self.port,
                username=self.user,
                pkey=pkey,
                allow_agent=False,
                look_for_keys=False,
                timeout=t,
                banner_timeout=t,
                auth_timeout=t,
                channel_timeout=t,
            )
        except _UnknownHostKey as e:
            raise _Fail(
                f"host key for {self.host_key_name} not in {self.known_hosts} (refused; server offered "
                f"{_fingerprint(e.key)}; not retried: add the robot's key to known_hosts)",
                retryable=False,
            ) from e
        except paramiko.BadHostKeyException as e:
            raise _Fail(
                f"host key for {self.host_key_name} does not match {self.known_hosts} (refused; server "
                f"offered {_fingerprint(e.key)}, expected {_fingerprint(e.expected_key)}; "
                "not retried: the robot was reinstalled, or this is not the robot)",
                retryable=False,
            ) from e
        except paramiko.BadAuthenticationType as e:
            raise _Fail(
                f"server does not accept public key authentication "
                f"(allowed: {', '.join(e.allowed_types) or 'none'})",
                retryable=False,
            ) from e
        except paramiko.AuthenticationException as e:
            if "timeout" in str(e).lower():
                raise _Fail(f"authentication timed out after {t:g} s", retryable=True) from e
            raise _Fail(
                f"authentication failed (key {self.key}; is its public key in the user's "
                "authorized_keys?)",
                retryable=False,
            ) from e
        except paramiko.ssh_exception.NoValidConnectionsError as e:
            errnos = {getattr(x, "errno", None) for x in e.errors.values()}
            if errnos <= {111}:  # ECONNREFUSED: nothing listens (sshd down, robot booting)
                raise _Fail("connection refused", retryable=True) from e
            raise _Fail(f"cannot connect: {one_line(e, 200)}", retryable=True) from e
        except socket.gaierror as e:
            raise _Fail(f"cannot resolve host {self.host}: {e.strerror}", retryable=True) from e
        except TimeoutError as e:  # socket.timeout: the TCP connect
            raise _Fail(f"connect timed out after {t:g} s", retryable=True) from e
        except (paramiko.SSHException, OSError, EOFError) as e:
            # Banner timeouts, resets, negotiation failures: the command was not sent yet.
            if time.monotonic() - start >= 0.95 * t:
                # paramiko's own words are misleading here (a silent server gives
                # "No existing session"), so say what happened.
                raise _Fail(
                    f"timed out after {t:g} s in the SSH handshake "
                    f"(no banner or no key exchange; paramiko: {one_line(e, 100)})",
                    retryable=True,
                ) from e
            raise _Fail(f"connect failed: {one_line(e, 200)}", retryable=True) from e

    def _exec(self, client: paramiko.SSHClient, cancel: threading.Event) -> Outcome:
        transport = client.get_transport()
        if transport is None:  # connect() returned, so this is not expected
            raise _Fail("no SSH transport after connecting", retryable=True)
        try:
            chan = transport.open_session(timeout=self.connect_timeout_s)
        except (paramiko.SSHException, OSError, EOFError) as e:
            raise _Fail(f"cannot open a session: {one_line(e, 200)}", retryable=True) from e
        chan.settimeout(self.command_timeout_s)
        # From here the command may run: no retries (see the module docstring).
        try:
            chan.exec_command(self.command)
            chan.shutdown_write()  # the command reads EOF on stdin, like ssh -n
        except (paramiko.SSHException, OSError, EOFError) as e:
            raise _Fail(f"the server refused the command: {one_line(e, 200)}", False) from e
        return self._wait(chan, cancel)

    def _wait(self, chan: paramiko.Channel, cancel: threading.Event) -> Outcome:
        out, err = bytearray(), bytearray()

        def drain() -> None:
            # Read as we go: a full window would stall a chatty command until the timeout.
            while chan.recv_ready():
                out.extend(chan.recv(65536))
                del out[:-_KEEP_BYTES]
            while chan.recv_stderr_ready():
                err.extend(chan.recv_stderr(65536))
                del err[:-_KEEP_BYTES]

        def tails() -> dict[str, Any]:
            return {"stderr": _tail(err), "stdout": _tail(out)}

        deadline = time.monotonic() + self.command_timeout_s
        output_deadline: float | None = None
        while True:
            drain()
            now = time.monotonic()
            if chan.exit_status_ready():
                # sshd may send the exit status before the last output; wait for EOF
                # briefly, but a background child holding stdout open must not count.
                if output_deadline is None:
                    output_deadline = min(deadline, now + 1.0)
                if chan.eof_received or chan.closed or now >= output_deadline:
                    break
                time.sleep(0.005)
                continue
            if now >= deadline:
                raise _Fail(
                    f"command timed out after {self.command_timeout_s:g} s (channel closed; "
                    "the remote command may still be running)",
                    retryable=False,
                    detail=tails(),
                )
            if cancel.is_set():
                raise _Fail("cancelled (shutdown) while the command ran", False, tails())
            # Woken at once by the exit status or a closed channel.
            chan.status_event.wait(min(0.1, deadline - now))
        drain()
        status = chan.recv_exit_status()  # already known: returns at once
        detail = {"exit_status": status, **tails()}
        if status == 0:
            return Outcome(True, detail=detail)
        if status == -1:  # paramiko's value when the channel closed without an exit-status
            raise _Fail(
                "connection closed before the command reported an exit status "
                "(killed by a signal, or the connection dropped; it may have run)",
                False,
                detail,
            )
        stderr = one_line(detail["stderr"], 200)
        raise _Fail(
            f"command exited with status {status}" + (f": {stderr}" if stderr else ""),
            False,
            detail,
        )
