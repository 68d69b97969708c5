"""A real OpenSSH server on 127.0.0.1 for tests, without pytest.

``start_sshd(directory)`` generates an Ed25519 host key and user key with
``ssh-keygen``, writes an ``sshd_config`` that allows exactly that user key for
the current user (no passwords, no keyboard-interactive, no PAM), runs
``/usr/sbin/sshd -D -e -f CONFIG -p PORT`` on a free port, waits until the server
sends its banner, and writes a ``known_hosts`` file with the host key under
``[127.0.0.1]:PORT``.  ``Sshd.stop()`` ends it.

Root and non-root: sshd started by an ordinary user can only log that same user
in (it cannot change uid) and, with ``UsePAM no``, needs nothing else.  Run as
root it needs the privilege-separation directory ``/run/sshd`` (created here if
missing) and, because the user it logs in is then root, ``PermitRootLogin
prohibit-password`` (key only) instead of ``no``, the only way a root test run
can log in at all.  Password and keyboard-interactive logins stay off either way.
"""

from __future__ import annotations

import getpass
import os
import shutil
import socket
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

SSHD = "/usr/sbin/sshd"


def sshd_available() -> bool:
    return os.access(SSHD, os.X_OK) and shutil.which("ssh-keygen") is not None


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def keygen(path: Path, comment: str = "safety-supervisor-test") -> str:
    """A new unencrypted Ed25519 key pair at ``path``; returns the public key line."""
    subprocess.run(
        ["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", comment, "-f", str(path)],
        check=True,
        stdin=subprocess.DEVNULL,
        capture_output=True,
    )
    return Path(f"{path}.pub").read_text().strip()


def known_hosts_line(host: str, port: int, pubkey_line: str) -> str:
    """``[host]:port type base64`` as OpenSSH and paramiko look a non-22 port up."""
    kind, b64 = pubkey_line.split()[:2]
    name = host if port == 22 else f"[{host}]:{port}"
    return f"{name} {kind} {b64}\n"


@dataclass
class Sshd:
    host: str
    port: int
    user: str
    directory: Path
    user_key: Path  # private key in authorized_keys
    host_key: Path
    known_hosts: Path  # holds the real host key
    authorized_keys: Path
    log: Path  # sshd's stderr (-e)
    proc: subprocess.Popen

    def params(self, command: str, **extra: object) -> dict:
        """``ssh:`` mitigation params that reach this server."""
        return {
            "host": self.host,
            "port": self.port,
            "user": self.user,
            "key": str(self.user_key),
            "known_hosts": str(self.known_hosts),
            "command": command,
            **extra,
        }

    def log_text(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5)


def _config(d: Path, port: int, user: str, host_key: Path, auth_keys: Path) -> str:
    root = os.geteuid() == 0
    return "\n".join(
        [
            "ListenAddress 127.0.0.1",
            f"Port {port}",
            f"HostKey {host_key}",
            f"PidFile {d / 'sshd.pid'}",
            f"AuthorizedKeysFile {auth_keys}",
            "PubkeyAuthentication yes",
            "PasswordAuthentication no",
            "KbdInteractiveAuthentication no",
            # See the module docstring: a root test run can only log in as root.
            f"PermitRootLogin {'prohibit-password' if root else 'no'}",
            "UsePAM no",
            # The tmp files belong to whoever runs the tests; don't insist on root-owned paths.
            "StrictModes no",
            f"AllowUsers {user}",
            "PrintMotd no",
            "UseDNS no",
            "LogLevel VERBOSE",
            "",
        ]
    )


def _banner(host: str, port: int, timeout: float) -> bytes:
    with socket.create_connection((host, port), timeout=timeout) as s:
        s.settimeout(timeout)
        return s.recv(256)


def start_sshd(directory: Path, timeout_s: float = 10.0) -> Sshd:
    """Start sshd in ``directory`` (created); raises RuntimeError with sshd's log if it fails."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    user = getpass.getuser()
    host_key, user_key = d / "ssh_host_ed25519_key", d / "id_ed25519"
    host_pub = keygen(host_key, "test-host")
    user_pub = keygen(user_key, "test-user")
    auth_keys = d / "authorized_keys"
    auth_keys.write_text(user_pub + "\n")
    config = d / "sshd_config"
    log = d / "sshd.log"
    if os.geteuid() == 0:
        # Privilege separation directory; Debian's packaging normally creates it at boot.
        Path("/run/sshd").mkdir(mode=0o755, parents=True, exist_ok=True)
    # A free port can be taken between probing and binding; try a few.
    last = ""
    for _ in range(5):
        port = free_port()
        config.write_text(_config(d, port, user, host_key, auth_keys))
        with log.open("wb") as err:
            proc = subprocess.Popen(
                [SSHD, "-D", "-e", "-f", str(config), "-p", str(port)],
                stdin=subprocess.DEVNULL,
                stdout=err,
                stderr=err,
                start_new_session=True,
            )
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and proc.poll() is None:
            try:
                if _banner("127.0.0.1", port, 1.0).startswith(b"SSH-2.0-"):
                    known = d / "known_hosts"
                    known.write_text(known_hosts_line("127.0.0.1", port, host_pub))
                    return Sshd(
                        "127.0.0.1", port, user, d, user_key, host_key, known, auth_keys, log, proc
                    )
            except OSError:
                pass
            time.sleep(0.02)  # poll interval while sshd binds; not a fixed wait
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        last = log.read_text(errors="replace")
        if "Address already in use" not in last:
            break
    raise RuntimeError(f"sshd did not start (rc={proc.returncode}):\n{last}")
