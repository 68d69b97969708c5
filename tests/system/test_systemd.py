"""The shipped unit under a real systemd, as a robot integrator runs it.

A Debian bookworm rootfs (debootstrap, cached outside the checkout) is copied
for the session and booted with ``systemd-nspawn -b`` (systemd is its PID 1);
the wheel built from this checkout and a wheelhouse of its dependencies are
copied in, a bootstrap venv runs ``install-service`` exactly as the README's
integrator does, and every command runs inside through ``nsenter``.  The unit
checks on the host (tests/supervisor/tools/test_packaging.py) cannot see what only PID 1 does:
notify, the watchdog, the sandbox's seccomp filter, reload, stop.

The reload tests also run on Debian trixie (systemd 257, which has
``Type=notify-reload``; bookworm's 252 has not), built and cached the same way
with a wheelhouse for its Python 3.13; the rest of the tier runs on bookworm.

Needs root, ``systemd-nspawn`` (systemd-container), ``debootstrap`` and the
Debian mirror; skipped otherwise, except where ``SAFETY_SUPERVISOR_REQUIRE_SYSTEMD=1``
(.ci/run) makes a skip a failure.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

# The session fixture (debootstrap on a cold cache, two venvs) counts toward the
# first test's timeout.
pytestmark = [pytest.mark.systemd, pytest.mark.timeout(1500)]

ROOT = Path(__file__).resolve().parents[2]
CACHE = Path(os.environ.get("SAFETY_SUPERVISOR_TEST_CACHE", "/var/cache/safety-supervisor-tests"))
ROOTFS = CACHE / "rootfs-bookworm"
WHEELHOUSE = CACHE / "wheelhouse"
# trixie: its Python's version and the manylinux tags its glibc (2.41) loads, for
# the wheelhouse downloaded on this host (the container has no network).
TRIXIE_PYTHON = "3.13"
TRIXIE_PLATFORMS = ["manylinux2014_x86_64", *(f"manylinux_2_{n}_x86_64" for n in range(17, 42))]
MIRROR = "http://deb.debian.org/debian"
PACKAGES = (
    "systemd,systemd-sysv,dbus,python3,python3-venv,python3-dev,gcc,libc6-dev,"
    "logrotate,iproute2,procps"
)
UNIT = "safety-supervisor.service"
CONTROL_SOCKET = "/run/safety-supervisor/control.sock"
CONFIG = "/etc/safety-supervisor/supervisor.yaml"
VIOLATION_LOG = "/var/log/safety-supervisor/violations.jsonl"
NOT_SOURCE = shutil.ignore_patterns(
    ".git", "__pycache__", "*.egg-info", "build", "dist", ".*_cache", ".venv", "tests"
)
INSIDE_PATH = "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"


def _unavailable(reason: str) -> None:
    """Skip, or fail where CI (.ci/run) says the tier must run."""
    if os.environ.get("SAFETY_SUPERVISOR_REQUIRE_SYSTEMD") == "1":
        pytest.fail(f"SAFETY_SUPERVISOR_REQUIRE_SYSTEMD=1 but {reason}")
    pytest.skip(reason)


def _run(argv: list[str], timeout: float, **kw: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run(argv, capture_output=True, text=True, timeout=timeout, **kw)  # type: ignore[call-overload]


def _tail(text: str) -> str:
    return " | ".join(text.strip().splitlines()[-3:])


def _ok(r: subprocess.CompletedProcess[str]) -> str:
    assert r.returncode == 0, f"{r.args} exited {r.returncode}\n{r.stdout}\n{r.stderr}"
    return r.stdout


def _poll(what: str, deadline_s: float, probe: Callable[[], bool]) -> float:
    """Seconds until ``probe()`` holds; fails with ``what`` after the deadline.
    The container's state can only be asked for, so this polls (no fixed sleep)."""
    t0 = time.monotonic()
    while not probe():
        if time.monotonic() - t0 > deadline_s:
            pytest.fail(f"{what}: not within {deadline_s} s")
        time.sleep(0.05)
    return time.monotonic() - t0


# ------------------------------------------------------------------ the rootfs


def _cached_rootfs(release: str = "bookworm") -> Path:
    """The pristine rootfs of ``release``, built once.  It is built in a temporary
    directory beside the cache and renamed into place, so a killed build never
    passes for a cache."""
    rootfs = CACHE / f"rootfs-{release}"
    if rootfs.is_dir():
        return rootfs
    CACHE.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="rootfs-build-", dir=CACHE))
    # It becomes the container's /: mkdtemp's 0700 would lock every user but
    # root out of the whole file system.
    tmp.chmod(0o755)
    try:
        r = _run(
            [
                "debootstrap",
                "--variant=minbase",
                f"--include={PACKAGES}",
                release,
                str(tmp),
                MIRROR,
            ],
            timeout=900,
        )
        if r.returncode != 0:
            _unavailable(f"debootstrap failed ({r.returncode}): {_tail(r.stderr + r.stdout)}")
        try:
            os.rename(tmp, rootfs)
        except OSError:
            if not rootfs.is_dir():
                raise
            # Another session built it meanwhile (the same command): theirs is used.
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return rootfs


def _build_wheel(base: Path) -> Path:
    src = base / "src"
    shutil.copytree(ROOT, src, ignore=NOT_SOURCE, symlinks=True)
    dist = base / "dist"
    _ok(_run([sys.executable, "-m", "build", "--wheel", "--outdir", str(dist), str(src)], 300))
    (wheel,) = dist.glob("safety_supervisor-*.whl")
    return wheel


def _wheelhouse(wheel: Path) -> Path:
    """The wheel's dependencies for the container's Python (Debian's 3.11, the
    host's ABI), downloaded once into the cache and reused; pip skips what is
    already there."""
    WHEELHOUSE.mkdir(parents=True, exist_ok=True)
    r = _run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--quiet",
            # sdists (empy, sdnotify) built in an isolated build environment: the
            # legacy `setup.py bdist_wheel` needs the `wheel` package, which a fresh
            # virtualenv does not have.
            "--use-pep517",
            # What an earlier run left here is reused (sdnotify, for one, is an
            # sdist that pip builds into a wheel).
            "--find-links",
            str(WHEELHOUSE),
            "--wheel-dir",
            str(WHEELHOUSE),
            str(wheel),
        ],
        timeout=900,
    )
    if r.returncode != 0:
        _unavailable(f"pip wheel of the dependencies failed: {_tail(r.stderr)}")
    # The wheel under test comes from its own directory, never a stale one here.
    for stale in WHEELHOUSE.glob("safety_supervisor-*.whl"):
        stale.unlink()
    return WHEELHOUSE


def _wheelhouse_trixie(wheel: Path) -> Path:
    """The dependencies for trixie's Python 3.13: binary wheels downloaded for it,
    and the pure ones pip built for bookworm's wheelhouse (sdnotify is an sdist)."""
    house = _wheelhouse(wheel)
    trixie = CACHE / "wheelhouse-trixie"
    trixie.mkdir(parents=True, exist_ok=True)
    platforms = [arg for tag in TRIXIE_PLATFORMS for arg in ("--platform", tag)]
    r = _run(
        [
            sys.executable,
            "-m",
            "pip",
            "download",
            "--quiet",
            "--only-binary=:all:",
            f"--python-version={TRIXIE_PYTHON}",
            "--implementation=cp",
            *platforms,
            "--find-links",
            str(trixie),
            "--find-links",
            str(house),
            "--dest",
            str(trixie),
            str(wheel),
        ],
        timeout=900,
    )
    if r.returncode != 0:
        _unavailable(f"pip download for trixie's Python failed: {_tail(r.stderr)}")
    for stale in trixie.glob("safety_supervisor-*.whl"):
        stale.unlink()
    return trixie


# ------------------------------------------------------------------ the machine


@dataclass
class Machine:
    """A booted container: ``run`` executes a command inside (all namespaces of
    its PID 1) with a clean environment and a timeout."""

    root: Path
    name: str
    nspawn: subprocess.Popen[bytes]
    pid1: int
    release: str = "bookworm"

    def run(
        self, *argv: str, timeout: float = 60, env: dict[str, str] | None = None
    ) -> subprocess.CompletedProcess[str]:
        envs = [
            f"{k}={v}" for k, v in {"PATH": INSIDE_PATH, "LANG": "C.UTF-8", **(env or {})}.items()
        ]
        return _run(
            ["nsenter", "-t", str(self.pid1), "-a", "env", "-i", *envs, *argv], timeout=timeout
        )

    def ok(self, *argv: str, timeout: float = 60, env: dict[str, str] | None = None) -> str:
        return _ok(self.run(*argv, timeout=timeout, env=env))

    def show(self, *props: str) -> dict[str, str]:
        out = self.ok("systemctl", "show", UNIT, "-p", ",".join(props))
        return dict(line.split("=", 1) for line in out.splitlines() if "=" in line)

    def journal(self, since_cursor: str | None = None) -> str:
        args = ["journalctl", "-u", UNIT, "--no-pager", "-o", "cat"]
        if since_cursor:
            args += ["--after-cursor", since_cursor]
        return self.run(*args, timeout=30).stdout


def _children(pid: int) -> list[int]:
    out: list[int] = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            out += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            continue
    return out


def _boot(root: Path, name: str, log: Path) -> Machine:
    nspawn = subprocess.Popen(
        [
            "systemd-nspawn",
            "-D",
            str(root),
            "-M",
            name,
            "--register=no",
            # The host may have no systemd (no machined, no scope to move into).
            "--keep-unit",
            # DDS stays on the container's own loopback.
            "--private-network",
            "-b",
        ],
        stdin=subprocess.DEVNULL,
        stdout=log.open("wb"),
        stderr=subprocess.STDOUT,
    )
    try:
        return _wait_booted(nspawn, log)
    except BaseException:
        _stop_nspawn(nspawn)
        raise


def _stop_nspawn(nspawn: subprocess.Popen[bytes]) -> None:
    """SIGTERM makes systemd-nspawn power the container off; SIGKILL if it hangs."""
    if nspawn.poll() is None:
        nspawn.terminate()
        try:
            nspawn.wait(timeout=30)
        except subprocess.TimeoutExpired:
            # Killing the container's PID 1 ends its whole PID namespace; killing
            # only systemd-nspawn would orphan it.
            for pid in _children(nspawn.pid):
                os.kill(pid, signal.SIGKILL)
            nspawn.kill()
            nspawn.wait(timeout=30)


def _container_init(nspawn_pid: int) -> int:
    """The container's PID 1 among systemd-nspawn's children, 0 if not there yet.
    nspawn first forks a child in our own PID namespace, which clones PID 1 into the
    new one and exits; that first child is not the container (nsenter into it fails
    once it is gone), so a child counts only if its NSpid says 1 in a namespace below."""
    for pid in _children(nspawn_pid):
        try:
            status = Path(f"/proc/{pid}/status").read_text()
        except OSError:
            continue
        for line in status.splitlines():
            ids = line.split()[1:] if line.startswith("NSpid:") else []
            if len(ids) > 1 and ids[-1] == "1":
                return pid
    return 0


def _wait_booted(nspawn: subprocess.Popen[bytes], log: Path) -> Machine:
    pid1 = 0

    def found() -> bool:
        nonlocal pid1
        if nspawn.poll() is not None:
            pytest.fail(f"systemd-nspawn exited {nspawn.returncode}: {log.read_text()[-2000:]}")
        pid1 = _container_init(nspawn.pid)
        return pid1 != 0

    _poll("the container's PID 1", 30, found)
    m = Machine(Path(), "", nspawn, pid1)

    def running() -> bool:
        if nspawn.poll() is not None:
            pytest.fail(f"systemd-nspawn exited {nspawn.returncode}: {log.read_text()[-2000:]}")
        r = m.run("systemctl", "is-system-running", timeout=10)
        return r.stdout.strip() in ("running", "degraded")

    _poll("the container's systemd to finish booting", 120, running)
    return m


def _shutdown(m: Machine) -> None:
    if m.nspawn.poll() is None:
        try:
            m.run("systemctl", "poweroff", timeout=10)
        except subprocess.TimeoutExpired:
            pass
        try:
            m.nspawn.wait(timeout=30)
        except subprocess.TimeoutExpired:
            _stop_nspawn(m.nspawn)


def _remove_orphaned_sessions() -> None:
    """Session copies whose pytest process is gone (killed before its cleanup ran)."""
    for d in CACHE.glob("session-*"):
        pid = d.name.split("-")[1]
        if not pid.isdigit():  # the unnamed copies of earlier versions of this file
            shutil.rmtree(d, ignore_errors=True)
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            shutil.rmtree(d, ignore_errors=True)
        except PermissionError:
            pass  # alive, another user's


@pytest.fixture(scope="session")
def machine(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Machine]:
    yield from _machine("bookworm", tmp_path_factory)


@pytest.fixture(scope="session")
def machine_trixie(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Machine]:
    yield from _machine("trixie", tmp_path_factory)


@pytest.fixture(params=["bookworm", "trixie"])
def either_machine(request: pytest.FixtureRequest) -> Machine:
    """Bookworm's systemd 252 and trixie's 257: a test of this runs on both."""
    name = "machine" if request.param == "bookworm" else "machine_trixie"
    m: Machine = request.getfixturevalue(name)
    return m


def _machine(release: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Machine]:
    if os.geteuid() != 0:
        _unavailable("booting a container needs root")
    for tool in ("systemd-nspawn", "debootstrap", "nsenter"):
        if shutil.which(tool) is None:
            _unavailable(f"{tool} is not installed (Debian: systemd-container, debootstrap)")
    base = tmp_path_factory.mktemp(f"systemd-{release}")
    wheel = _build_wheel(base)
    house = _wheelhouse_trixie(wheel) if release == "trixie" else _wheelhouse(wheel)
    pristine = _cached_rootfs(release)
    # A throwaway copy per session: tests never dirty the cache.  Beside the
    # cache (same file system, out of a possibly small /tmp), named with this
    # process's pid so that a later session removes the copy of a killed one.
    _remove_orphaned_sessions()
    root = Path(tempfile.mkdtemp(prefix=f"session-{os.getpid()}-", dir=CACHE)) / "root"
    try:
        _ok(_run(["cp", "-a", "--reflink=auto", str(pristine), str(root)], 600))
        shutil.copytree(house, root / "wheelhouse")
        (root / "wheel").mkdir()
        shutil.copy2(wheel, root / "wheel" / wheel.name)
        name = "ss-" + uuid.uuid4().hex[:8]
        t0 = time.monotonic()
        m = _boot(root, name, base / "nspawn.log")
        m.root, m.name, m.release = root, name, release
        try:
            _install(m, f"/wheel/{wheel.name}")
            print(f"\n{release}: booted and installed in {time.monotonic() - t0:.1f} s")
            yield m
        finally:
            _shutdown(m)
    finally:
        shutil.rmtree(root.parent, ignore_errors=True)


def _install(m: Machine, wheel: str) -> None:
    """As an integrator: a venv with safety-supervisor from the wheelhouse, then
    ``install-service`` (which makes /opt/safety-supervisor/venv the same way)."""
    offline = {"PIP_NO_INDEX": "1", "PIP_FIND_LINKS": "/wheelhouse"}
    m.ok("python3", "-m", "venv", "/root/bootstrap", timeout=120)
    m.ok("/root/bootstrap/bin/pip", "install", "-q", wheel, timeout=600, env=offline)
    out = m.ok(
        "/root/bootstrap/bin/safety-supervisor",
        "install-service",
        "--source",
        wheel,
        "--python",
        "/usr/bin/python3",
        timeout=900,
        env=offline,
    )
    assert "installed safety-supervisor.service" in out, out


# ------------------------------------------------------------------ helpers


def _start(m: Machine) -> float:
    """``systemctl start``; seconds it took (it returns after READY=1)."""
    t0 = time.monotonic()
    r = m.run("systemctl", "start", UNIT, timeout=120)
    took = time.monotonic() - t0
    assert r.returncode == 0, f"start failed: {r.stderr}\n{m.journal()[-4000:]}"
    return took


def _ensure_started(m: Machine) -> dict[str, str]:
    st = m.show("ActiveState", "SubState")
    if (st["ActiveState"], st["SubState"]) != ("active", "running"):
        m.run("systemctl", "reset-failed", UNIT, timeout=30)
        _start(m)
    return m.show("ActiveState", "SubState", "MainPID", "NRestarts")


def _cursor(m: Machine) -> str:
    # The whole journal's last entry: the unit may have none yet.
    out = m.ok("journalctl", "-n", "1", "--show-cursor", "--no-pager", timeout=30)
    match = re.search(r"-- cursor: (\S+)", out)
    assert match, out
    return match.group(1)


# ------------------------------------------------------------------ tests


def test_start_returns_after_ready_and_runs(machine: Machine) -> None:
    m = machine
    took = _start(m)
    st = m.show("ActiveState", "SubState", "MainPID", "Type", "StatusText")
    assert (st["ActiveState"], st["SubState"]) == ("active", "running"), st
    assert int(st["MainPID"]) > 0
    # Type=notify: start returned only because the daemon said READY=1 (its
    # status line comes with it, see docs/reference/ros-interfaces.md).
    assert st["Type"] == "notify"
    assert m.run("test", "-S", CONTROL_SOCKET).returncode == 0, m.journal()[-3000:]
    # The first start filled the start-up cache in the state directory; a restart
    # takes the monitor and the findings from it (docs/reference/commands.md).
    cache = m.run("find", "/var/lib/safety-supervisor/cache", "-name", "findings.json")
    assert cache.stdout.strip(), f"no cache entry: {cache.stdout}{cache.stderr}"
    t0 = time.monotonic()
    m.ok("systemctl", "restart", UNIT, timeout=120)
    again = time.monotonic() - t0
    print(f"\nsystemctl start {UNIT}: {took:.2f} s to READY (empty start-up cache)")
    print(f"systemctl restart {UNIT}: {again:.2f} s to READY (stop, then the cache filled)")


def _hang_and_back(m: Machine, before: dict[str, str]) -> tuple[float, float]:
    """SIGSTOP the daemon; seconds until systemd has let go of it and until a new
    daemon is active (READY=1)."""
    old = before["MainPID"]
    m.ok("kill", "-STOP", old)
    t0 = time.monotonic()
    gone: list[float] = []  # when the stopped daemon is no longer MainPID

    def back() -> bool:
        st = m.show("ActiveState", "SubState", "MainPID")
        if st["MainPID"] != old and not gone:
            gone.append(time.monotonic() - t0)
        return st["MainPID"] not in (old, "0") and (st["ActiveState"], st["SubState"]) == (
            "active",
            "running",
        )

    _poll("a new daemon in service after SIGSTOP", 90, back)
    took = time.monotonic() - t0
    after = m.show("NRestarts", "MainPID")
    assert int(after["NRestarts"]) > int(before["NRestarts"]), (before, after)
    assert "Watchdog timeout" in m.journal() or "watchdog" in m.journal().lower()
    return gone[0], took


def test_watchdog_restarts_a_stopped_daemon(machine: Machine) -> None:
    m = machine
    before = _ensure_started(m)
    unit = m.show("WatchdogUSec", "RestartUSec")
    print(f"\nWatchdogSec {unit['WatchdogUSec']}, RestartSec {unit['RestartUSec']}:")
    # Three rounds: where in the ping interval the hang falls varies the figure.
    for _ in range(3):
        gone, took = _hang_and_back(m, before)
        print(
            f"SIGSTOP to back in service (watchdog kill, restart, READY): {took:.2f} s "
            f"(the old daemon gone after {gone:.2f} s, then {took - gone:.2f} s to READY)"
        )
        before = m.show("ActiveState", "SubState", "MainPID", "NRestarts")


def _last_reload(m: Machine) -> dict[str, object]:
    lines = m.ok("cat", VIOLATION_LOG).splitlines()
    records = [json.loads(line) for line in lines if line.endswith("}")]
    reloads = [r for r in records if r.get("what") == "reload"]
    assert reloads, records[-5:]
    return reloads[-1]


def test_reload_good_and_bad_config(either_machine: Machine) -> None:
    """``systemctl reload`` returns once the daemon has the new config in force
    (ExecReload waits for its answer), and fails while the old one stays in
    force for a config that fails check.  Each is checked once, right after
    ``systemctl`` returns: the outcome is there, not on its way.  The same unit
    on systemd 252 and 257."""
    m = either_machine
    before = _ensure_started(m)
    pid = before["MainPID"]
    cursor = _cursor(m)
    original = m.ok("cat", CONFIG)
    host_config = m.root / CONFIG.lstrip("/")
    try:
        edited = original + f"# reloaded by the systemd tier {uuid.uuid4().hex}\n"
        host_config.write_text(edited)
        new = hashlib.sha256(edited.encode()).hexdigest()
        t0 = time.monotonic()
        r = m.run("systemctl", "reload", UNIT, timeout=120)
        took_good = time.monotonic() - t0
        assert r.returncode == 0, f"{r.stderr}\n{m.journal(cursor)[-3000:]}"
        rec = _last_reload(m)
        assert rec["ok"] is True and rec["config_sha256"] == new, rec
        assert rec["via"] == "control_socket", rec
        st = m.show("MainPID", "ActiveState", "SubState", "StatusText")
        assert (st["MainPID"], st["ActiveState"], st["SubState"]) == (pid, "active", "running")
        assert st["StatusText"].startswith("reloaded:"), st

        m.ok("sh", "-c", f"printf 'requirements: [\\n' >> {CONFIG}")
        t0 = time.monotonic()
        r = m.run("systemctl", "reload", UNIT, timeout=120)
        took_bad = time.monotonic() - t0
        assert r.returncode != 0, "a config that fails check must fail the reload"
        rec = _last_reload(m)
        assert rec["ok"] is False and f"{CONFIG}:" in str(rec["why"]), rec
        assert rec["config_sha256"] == new, rec  # the previous config is in force
        st = m.show("MainPID", "ActiveState", "SubState", "StatusText")
        assert (st["MainPID"], st["ActiveState"], st["SubState"]) == (pid, "active", "running")
        assert st["StatusText"].startswith("reload rejected:"), st
    finally:
        host_config.write_text(original)
    # ExecReload's one line and the daemon's reload records reach the journal
    # (journald takes them in on its own time: polled).
    refusal = "reload rejected, still running the previous config: " + CONFIG
    _poll("ExecReload's refusal in the journal", 30, lambda: refusal in m.journal(cursor))
    priorities: list[str] = []

    def journalled() -> bool:
        # Selected by the new config's hash, which both records carry, not by
        # --after-cursor: journalctl 252 with a field match after a cursor
        # missed the first of the two entries.
        r = m.run("journalctl", "-u", UNIT, "WHAT=reload", "-o", "json", "--no-pager", timeout=30)
        entries = [json.loads(x) for x in r.stdout.splitlines() if x.strip()]
        priorities[:] = [e["PRIORITY"] for e in entries if e.get("CONFIG_SHA256") == new]
        return len(priorities) >= 2

    _poll("both reload records in the journal", 30, journalled)
    assert priorities[-2:] == ["6", "3"], priorities  # info, then err (docs/reference/log.md)
    assert m.show("MainPID")["MainPID"] == pid
    assert "Traceback" not in m.journal(cursor)
    print(
        f"\nsystemctl reload ({m.release}): {took_good:.2f} s (good config, in force on "
        f"return), {took_bad:.2f} s (broken config, refused)"
    )


def test_notify_reload_in_a_drop_in_reports_a_refusal_as_success(machine_trixie: Machine) -> None:
    """Where systemd has ``Type=notify-reload`` (253 and later), a drop-in may set it
    and clear ExecReload=: systemd sends SIGHUP and the daemon speaks the protocol
    (RELOADING=1 with MONOTONIC_USEC, then READY=1), so ``systemctl reload``
    returns once the new config is in force.  A refused config ends with READY=1
    too, and systemd 257 counts that reload a success (it has no way to hear a
    failure): why the shipped unit keeps ExecReload= (docs/reference/commands.md,
    ``reload``).  The refusal is still in the status, the log and the journal."""
    m = machine_trixie
    dropin = m.root / "etc/systemd/system" / f"{UNIT}.d" / "zz-test-notify-reload.conf"
    host_config = m.root / CONFIG.lstrip("/")
    original = host_config.read_text()
    m.run("systemctl", "stop", UNIT, timeout=60)
    dropin.parent.mkdir(parents=True, exist_ok=True)
    dropin.write_text("[Service]\nType=notify-reload\nExecReload=\n")
    try:
        m.ok("systemctl", "daemon-reload")
        m.run("systemctl", "reset-failed", UNIT, timeout=30)
        _start(m)
        st = m.show("Type", "MainPID")
        assert st["Type"] == "notify-reload", st
        pid = st["MainPID"]
        edited = original + f"# reloaded by notify-reload {uuid.uuid4().hex}\n"
        host_config.write_text(edited)
        new = hashlib.sha256(edited.encode()).hexdigest()
        t0 = time.monotonic()
        r = m.run("systemctl", "reload", UNIT, timeout=120)
        took_good = time.monotonic() - t0
        assert r.returncode == 0, f"{r.stderr}\n{m.journal()[-3000:]}"
        rec = _last_reload(m)  # right after the return: in force, not on its way
        assert (rec["ok"], rec["config_sha256"], rec["via"]) == (True, new, "signal"), rec
        assert m.show("StatusText")["StatusText"].startswith("reloaded:")

        host_config.write_text(edited + "requirements: [\n")
        r = m.run("systemctl", "reload", UNIT, timeout=120)
        assert r.returncode == 0, r.stderr  # systemd's verdict, not the daemon's
        assert m.show("ReloadResult")["ReloadResult"] == "success"
        rec = _last_reload(m)
        assert rec["ok"] is False and f"{CONFIG}:" in str(rec["why"]), rec
        assert rec["config_sha256"] == new, rec  # the previous config is in force
        st = m.show("MainPID", "ActiveState", "StatusText")
        assert (st["MainPID"], st["ActiveState"]) == (pid, "active"), st
        assert st["StatusText"].startswith("reload rejected:"), st
    finally:
        host_config.write_text(original)
        dropin.unlink(missing_ok=True)
        m.ok("systemctl", "daemon-reload")
        m.run("systemctl", "restart", UNIT, timeout=120)
    print(f"\nsystemctl reload under Type=notify-reload (trixie): {took_good:.2f} s (good config)")


def test_a_violation_reaches_the_journal_with_its_fields(machine: Machine) -> None:
    """``inject`` (a deployed system's self-test) breaks one requirement over DDS
    on the container's loopback; the record is in the journal with its fields
    (docs/reference/log.md) and the same JSON line as the log."""
    m = machine
    _ensure_started(m)
    req = "state_req000"
    log = "/var/log/safety-supervisor/violations.jsonl"
    env = {
        "HOME": "/root",
        "ROS_HOME": "/tmp/ros",
        "ROS_LOG_DIR": "/tmp/ros/log",
        # As the unit's daemon: UDP only (shared memory does not cross users).
        "FASTDDS_BUILTIN_TRANSPORTS": "UDPv4",
    }
    out = m.ok(
        "/opt/safety-supervisor/venv/bin/safety-supervisor",
        "inject",
        CONFIG,
        req,
        "--log",
        log,
        timeout=180,
        env=env,
    )
    assert req in out, out
    entries: list[dict[str, str]] = []

    def journalled() -> bool:
        r = m.run(
            "journalctl", "-u", UNIT, "EVENT=violation", f"REQUIREMENT={req}", "-o", "json",
            "--no-pager", timeout=30,
        )  # fmt: skip
        entries[:] = [json.loads(line) for line in r.stdout.splitlines() if line.strip()]
        return bool(entries)

    _poll("the violation in the journal", 30, journalled)
    e = entries[-1]
    record = json.loads(e["SAFETY_SUPERVISOR_RECORD"])
    assert record["event"] == "violation" and record["requirement"] == req, record
    assert e["PRIORITY"] == "4", e  # warning (docs/reference/log.md)
    assert e["SEQ"] == str(record["seq"]), e
    assert e["COMPONENT"] == "sRobot", e
    assert e["CONFIG_SHA256"] == record["config_sha256"], e
    assert e["SYSLOG_IDENTIFIER"] == "safety-supervisor", e
    # The same line as in the log file, which is what engineers replay.
    assert e["SAFETY_SUPERVISOR_RECORD"] in m.ok("cat", log).splitlines()


def test_the_ui_unit_serves_the_operator_page(machine: Machine) -> None:
    m = machine
    _ensure_started(m)
    ui = "safety-supervisor-ui.service"
    r = m.run("systemctl", "start", ui, timeout=60)
    assert r.returncode == 0, r.stderr
    fetch = (
        "import urllib.request as u; r = u.urlopen('http://127.0.0.1:8321/', timeout=5); "
        "print(r.status, r.headers.get_content_type())"
    )
    got: list[str] = []

    def serving() -> bool:
        st = m.ok("systemctl", "show", ui, "-p", "ActiveState", "--value").strip()
        assert st in ("active", "activating"), m.run("journalctl", "-u", ui, "--no-pager").stdout
        r = m.run("python3", "-c", fetch, timeout=30)
        got[:] = [r.stdout.strip()]
        return r.returncode == 0

    try:
        _poll("the operator page on 127.0.0.1:8321", 60, serving)
        assert got == ["200 text/html"], got
    finally:
        m.run("systemctl", "stop", ui, timeout=60)


def _resets(m: Machine) -> list[dict[str, object]]:
    lines = m.ok("cat", VIOLATION_LOG).splitlines()
    return [
        r for r in map(json.loads, lines) if r.get("event") == "reset" and r["requirement"] == "*"
    ]


def test_an_operator_and_the_ui_reset_through_the_sandboxed_socket(machine: Machine) -> None:
    """What a robot's operators rely on after an incident: a member of
    ``safety-operators`` resets with the CLI, the UI unit resets with its token,
    and anyone else is refused; each accepted reset is a record naming who asked
    (docs/reference/ros-interfaces.md, "Control socket")."""
    m = machine
    _ensure_started(m)
    cli = "/opt/safety-supervisor/venv/bin/safety-supervisor"
    m.run("useradd", "--no-create-home", "--groups", "safety-operators", "op1", timeout=30)
    m.run("useradd", "--no-create-home", "outsider", timeout=30)
    before = len(_resets(m))

    member = m.run("runuser", "-u", "op1", "--", cli, "reset", timeout=60)
    assert member.returncode == 0, member.stdout + member.stderr
    assert member.stdout.strip() == "all requirements reset", member.stdout
    outsider = m.run("runuser", "-u", "outsider", "--", cli, "reset", timeout=60)
    assert outsider.returncode != 0, outsider.stdout
    assert len(outsider.stderr.strip().splitlines()) == 1, outsider.stderr
    assert "Traceback" not in outsider.stderr, outsider.stderr

    ui = "safety-supervisor-ui.service"
    _ok(m.run("systemctl", "start", ui, timeout=60))
    post = (
        "import json, sys, urllib.error, urllib.request as u\n"
        "token = sys.argv[1]\n"
        "req = u.Request('http://127.0.0.1:8321/api/reset', data=b'{}', method='POST',\n"
        "    headers={'Content-Type': 'application/json', 'Authorization': 'Bearer ' + token})\n"
        "try:\n"
        "    r = u.urlopen(req, timeout=10); print(r.status, r.read().decode())\n"
        "except urllib.error.HTTPError as e:\n"
        "    print(e.code, e.read().decode())\n"
        "except OSError as e:\n"
        "    print(0, e)\n"
    )
    token = m.ok("cat", "/etc/safety-supervisor/ui.token").strip()
    answers: dict[str, str] = {}

    def answered(which: str, tok: str) -> Callable[[], bool]:
        def probe() -> bool:
            answers[which] = m.run("python3", "-c", post, tok, timeout=30).stdout.strip()
            # 0: the UI is not listening yet; 503: it has not seen the daemon yet;
            # "rate limited": the operator's reset was less than control.interval_ms ago.
            return not answers[which].startswith(("0 ", "503")) and (
                "rate limited" not in answers[which]
            )

        return probe

    try:
        _poll("the UI's answer to a reset with its token", 90, answered("token", token))
        _poll("the UI's answer to a reset without it", 30, answered("wrong", "x" * 43))
    finally:
        m.run("systemctl", "stop", ui, timeout=60)
    assert answers["token"].startswith("200 "), answers
    assert json.loads(answers["token"][4:])["ok"] is True, answers
    assert answers["wrong"].startswith("401 "), answers

    new = _resets(m)[before:]
    assert [r.get("via") for r in new] == ["control_socket", "ui"], new
    caller = new[0]["caller"]
    assert isinstance(caller, dict), new[0]
    assert (caller["uid"], caller["user"]) == (int(m.ok("id", "-u", "op1")), "op1"), caller


def test_logrotate_reopens_and_the_chain_verifies(machine: Machine) -> None:
    """The shipped snippet rotates (create, SIGUSR1 to the daemon only) and the
    hash chain verifies across the two files (docs/reference/log.md)."""
    m = machine
    pid = _ensure_started(m)["MainPID"]
    log = "/var/log/safety-supervisor/violations.jsonl"
    r = m.run("logrotate", "-f", "/etc/logrotate.d/safety-supervisor", timeout=60)
    assert r.returncode == 0, r.stderr

    def reopened() -> bool:
        r = m.run("cat", log)
        return r.returncode == 0 and r.stdout.strip() != ""

    _poll("the daemon's first record in the new log", 30, reopened)
    assert m.show("MainPID")["MainPID"] == pid  # reopened, not restarted
    out = m.ok(
        "/opt/safety-supervisor/venv/bin/safety-supervisor",
        "logs",
        "--verify",
        log + ".1",
        log,
        timeout=60,
    )
    assert "Traceback" not in out


def test_security_exposure_at_most_2(machine: Machine) -> None:
    out = machine.ok("systemd-analyze", "security", "--no-pager", UNIT)
    match = re.search(r"Overall exposure level for \S+: (\d+(?:\.\d+)?)", out)
    assert match, out
    print(f"\nsystemd-analyze security {UNIT}: {match.group(1)}")
    assert float(match.group(1)) <= 2.0, out


# Inside the machine: a ROS node that sees the daemon's node, runs `systemctl stop`
# and measures until the node is gone from its graph (a ghost would stay for the
# daemon's 20 s DDS lease; docs/reference/faults.md, "Stop").
STOP_OBSERVER = """
import subprocess, sys, time
import rclpy
from rclpy.context import Context
ctx = Context()
rclpy.init(context=ctx)
node = rclpy.create_node("stop_observer", context=ctx)
def present():
    return any(n == "safety_supervisor" for n, _ in node.get_node_names_and_namespaces())
end = time.monotonic() + 30
while not present():
    if time.monotonic() > end:
        sys.exit("the daemon's node was never seen")
    time.sleep(0.02)
r = subprocess.run(["systemctl", "stop", sys.argv[1]], capture_output=True, text=True)
if r.returncode:
    sys.exit("systemctl stop: " + r.stderr)
t = time.monotonic()
while present():
    if time.monotonic() - t > float(sys.argv[2]):
        sys.exit("the daemon's node is still in the graph after stop")
    time.sleep(0.02)
print(f"gone {time.monotonic() - t:.3f}")
"""


def test_stop_exits_0_and_leaves_nothing(machine: Machine) -> None:
    m = machine
    _ensure_started(m)
    cursor = _cursor(m)
    venv_python = "/opt/safety-supervisor/venv/bin/python"
    # HOME: rclpy logs under ~/.ros
    r = m.run(venv_python, "-c", STOP_OBSERVER, UNIT, "3.0", timeout=120, env={"HOME": "/root"})
    assert r.returncode == 0, r.stderr
    print(f"\nsystemctl stop: node left the graph {r.stdout.split()[-1]} s after stop returned")
    st = m.show("ActiveState", "Result")
    assert st["ActiveState"] == "inactive", st
    assert st["Result"] == "success", st
    # systemd 252 unloads the stopped unit, so its ExecMain* status is gone: the
    # journal says how it ended.  The daemon wrote its stop record (it handled
    # SIGTERM) and nothing was SIGKILLed after TimeoutStopSec.
    log = m.journal(cursor)
    assert "SUPERVISOR stop " in log, log
    assert "Deactivated successfully" in log, log
    assert "SIGKILL" not in log and "code=killed" not in log, log
    # No process of the unit's user is left, and the control socket is gone.
    assert m.run("pgrep", "-u", "safety-supervisor").returncode == 1
    assert m.run("test", "-e", CONTROL_SOCKET).returncode == 1


def test_a_sandbox_refusing_chown_is_named_not_the_group(machine: Machine) -> None:
    """With chown filtered out again (as ~@privileged alone did), the start fails
    with one line that names the filter, not the daemon's group membership."""
    m = machine
    m.run("systemctl", "stop", UNIT, timeout=60)
    dropin = m.root / "etc/systemd/system" / f"{UNIT}.d" / "zz-test-no-chown.conf"
    dropin.parent.mkdir(parents=True, exist_ok=True)
    # Restart=no: one failed start is the evidence, not a restart loop.
    dropin.write_text("[Service]\nSystemCallFilter=~@chown\nRestart=no\n")
    try:
        m.ok("systemctl", "daemon-reload")
        cursor = _cursor(m)
        r = m.run("systemctl", "start", UNIT, timeout=120)
        assert r.returncode != 0
        log = m.journal(cursor)
        assert f"control socket {CONTROL_SOCKET}: chown: Operation not permitted" in log, log
        assert "SystemCallFilter= must allow @chown" in log, log
        assert "must be a member of group" not in log, log
        assert "Traceback" not in log, log
    finally:
        dropin.unlink()
        m.ok("systemctl", "daemon-reload")
        m.run("systemctl", "reset-failed", UNIT, timeout=30)
    _start(m)
