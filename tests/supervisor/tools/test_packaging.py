"""The systemd unit, the logrotate snippet, ``install-service`` and ``init``.

The unit is checked by systemd's own tools (``systemd-analyze verify`` and
``security``), and its command lines are run here, outside systemd: ExecStart
with NOTIFY_SOCKET bound by the test, ExecStartPre's ``check`` on the shipped
config (ExecReload's ``reload`` runs under systemd in tests/system/test_systemd.py).
Paths are substituted by the installer's own renderer, so what is tested is
what ``install-service`` writes.
"""

from __future__ import annotations

import json
import os
import pwd
import random
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path

import pytest

import supervisor
from supervisor import data
from supervisor.tools import install
from supervisor.tools.children import NotifySocket, ros_env, ros_vars
from supervisor.tools.install import render_logrotate, render_unit, unit_directives

ROOT = Path(__file__).resolve().parents[3]
UNIT = ROOT / "packaging/systemd/safety-supervisor.service"
LOGROTATE = ROOT / "packaging/logrotate/safety-supervisor"
SHIPPED_EXE = "/opt/safety-supervisor/venv/bin/safety-supervisor"


def _need(tool: str, package: str) -> str:
    path = shutil.which(tool) or (
        f"/usr/sbin/{tool}" if Path(f"/usr/sbin/{tool}").exists() else None
    )
    if path is None:
        reason = f"{tool} missing (install Debian's {package})"
        if os.environ.get("CI"):  # .ci/run installs it: a broken setup, not a skip
            pytest.fail(reason)
        pytest.skip(reason)
    return path


def _console_script() -> str:
    """The installed ``safety-supervisor`` of the Python running the tests."""
    beside = Path(sys.executable).parent / "safety-supervisor"
    found = str(beside) if beside.is_file() else shutil.which("safety-supervisor")
    if found is None:
        pytest.fail("no safety-supervisor console script: pip install -e '.[test]' first")
    return found


@pytest.fixture
def site(tmp_path: Path) -> dict[str, Path]:
    """Temp stand-ins for /etc, /var/lib and /var/log, and the shipped config
    with its violation log pointed into them."""
    d = {
        "etc": tmp_path / "etc",
        "state": tmp_path / "state",
        "logs": tmp_path / "logs",
    }
    for p in d.values():
        p.mkdir()
    (d["logs"] / "ros").mkdir()  # LogsDirectory= creates both
    text = (ROOT / "config/srobot.yaml").read_text()
    text, n = re.subn(
        r"(?m)^(\s*violations:) /var/log/safety-supervisor/",
        rf"\1 {d['logs']}/",
        text,
    )
    assert n == 1
    (d["etc"] / "supervisor.yaml").write_text(text)
    return d


def _unit_for(site: dict[str, Path]) -> str:
    return render_unit(
        UNIT.read_text(),
        paths={
            SHIPPED_EXE: _console_script(),
            "/etc/safety-supervisor/": f"{site['etc']}/",
            "/var/lib/safety-supervisor": str(site["state"]),
            "/var/log/safety-supervisor": str(site["logs"]),
        },
    )


def _unit_env(unit: str) -> dict[str, str]:
    """The unit's Environment=, plus PYTHONPATH so that the console script runs
    this checkout whatever the editable install points at."""
    env: dict[str, str] = {"PYTHONPATH": str(ROOT)}
    for value in unit_directives(unit, "Environment"):
        for word in shlex.split(value):
            k, _, v = word.partition("=")
            env[k] = v
    return env


# ------------------------------------------------------------------ the unit file


def test_unit_settings_fast_dds_needs() -> None:
    unit = UNIT.read_text()
    one = {k: unit_directives(unit, k) for k in ("Type", "NotifyAccess", "MemoryDenyWriteExecute")}
    assert one == {"Type": ["notify"], "NotifyAccess": ["main"], "MemoryDenyWriteExecute": ["yes"]}
    families = " ".join(unit_directives(unit, "RestrictAddressFamilies")).split()
    assert {"AF_NETLINK", "AF_INET", "AF_INET6", "AF_UNIX"} <= set(families)
    filters = unit_directives(unit, "SystemCallFilter")
    assert not any("@resources" in f for f in filters)
    assert not unit_directives(unit, "PrivateIPC")  # Fast DDS shared memory (if turned on)
    assert not unit_directives(unit, "PrivateNetwork")  # DDS and ssh mitigations
    # systemctl reload waits for the daemon's answer (the daemon validates as check does).
    (reload,) = unit_directives(unit, "ExecReload")
    assert shlex.split(reload)[1:] == ["reload", "--socket", "/run/safety-supervisor/control.sock"]
    assert any(
        e.startswith("ROS_LOG_DIR=/var/log/safety-supervisor/")
        for e in unit_directives(unit, "Environment")
    )
    assert unit_directives(unit, "EnvironmentFile") == ["-/etc/safety-supervisor/environment"]


def test_unit_verifies_clean(tmp_path: Path, site: dict[str, Path]) -> None:
    tool = _need("systemd-analyze", "systemd")
    path = tmp_path / "safety-supervisor.service"
    path.write_text(_unit_for(site))
    r = subprocess.run(
        [tool, "verify", "--man=no", str(path)], capture_output=True, text=True, timeout=60
    )
    assert r.returncode == 0 and r.stderr == "", (r.returncode, r.stdout, r.stderr)


def test_unit_exposure_at_most_2(tmp_path: Path) -> None:
    tool = _need("systemd-analyze", "systemd")
    path = tmp_path / "safety-supervisor.service"
    shutil.copy(UNIT, path)
    r = subprocess.run(
        [tool, "security", "--offline=true", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    m = re.search(r"Overall exposure level for \S+: (\d+(?:\.\d+)?)", r.stdout)
    assert m, (r.returncode, r.stdout[-2000:], r.stderr)
    assert float(m.group(1)) <= 2.0, r.stdout


def test_check_command_passes_on_shipped_config(site: dict[str, Path]) -> None:
    unit = _unit_for(site)
    (pre,) = unit_directives(unit, "ExecStartPre")
    argv = shlex.split(pre)
    assert argv[1:] == ["check", str(site["etc"] / "supervisor.yaml")]
    r = subprocess.run(
        argv,
        cwd=site["state"],
        env={**os.environ, **_unit_env(unit)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert "13 requirements ok" in r.stdout


# The daemon test's helpers: its NOTIFY_SOCKET reader and the violating burst.
from tests.system.test_daemon import VIOLATING_STATE, Daemon  # noqa: E402


class UnitDaemon(Daemon):
    """The unit's ExecStart, with the unit's environment and working directory."""

    def __init__(self, tmp: Path, unit: str, domain_id: int) -> None:
        (start,) = unit_directives(unit, "ExecStart")
        argv = shlex.split(start)
        self.log = Path(argv[argv.index("--log") + 1])
        self.notify = NotifySocket(tmp / "notify.sock")
        env = {
            **ros_env(domain_id),
            **_unit_env(unit),
            **self.notify.env(),
            **ros_vars(domain_id),
        }
        (cwd,) = unit_directives(unit, "WorkingDirectory")
        self.spawn(tmp, argv, env, cwd=Path(cwd))


@pytest.fixture
def unit_daemon(tmp_path: Path, site: dict[str, Path]) -> Iterator[tuple[UnitDaemon, int]]:
    domain_id = random.randint(100, 200)
    d = UnitDaemon(tmp_path, _unit_for(site), domain_id)
    try:
        yield d, domain_id
    finally:
        d.close()


@pytest.mark.ros
def test_exec_start_runs_the_daemon(unit_daemon: tuple[UnitDaemon, int]) -> None:
    """ExecStart as systemd would run it, with the unit's environment: READY=1,
    it hears the robot and logs a violation, STOPPING=1 and exit 0 on SIGTERM."""
    rclpy = pytest.importorskip("rclpy")
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions

    daemon, domain_id = unit_daemon
    daemon.wait_notify("READY=1", timeout=30)
    assert (Path(daemon.log).parent / "ros").is_dir()

    # A robot with Fast DDS's default transports (shared memory + UDP).
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = Node("packaging_test_robot", context=ctx)
        pubs = [(node.create_publisher(t, topic, 10), t, v) for _, topic, t, v in VIOLATING_STATE]
        deadline = time.monotonic() + 20
        while not any(r["event"] == "violation" for r in daemon.records()):
            assert time.monotonic() < deadline, (
                f"the daemon heard nothing; log: {daemon.records()}\n{daemon.stderr.read_text()}"
            )
            for pub, mtype, value in pubs:
                pub.publish(mtype(data=value))
            time.sleep(0.3)  # publishing interval until the violation is on disk
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)

    t0 = time.monotonic()
    daemon.proc.send_signal(signal.SIGTERM)
    daemon.wait_notify("STOPPING=1", timeout=5)
    daemon.proc.wait(timeout=5)
    assert daemon.proc.returncode == 0, daemon.stderr.read_text()
    assert time.monotonic() - t0 < 5


# ------------------------------------------------------------------ logrotate


def test_logrotate_creates_and_never_copytruncates() -> None:
    words = [
        line.split()
        for line in LOGROTATE.read_text().splitlines()
        if line.strip() and not line.strip().startswith("#")
    ]
    directives = {w[0]: w[1:] for w in words}
    assert directives["create"] == ["0640", "safety-supervisor", "safety-supervisor"]
    assert "copytruncate" not in directives and "nocopytruncate" in directives
    for d in ("compress", "delaycompress", "missingok", "notifempty", "postrotate"):
        assert d in directives
    script = LOGROTATE.read_text().split("postrotate", 1)[1].split("endscript", 1)[0]
    commands = "\n".join(w for w in script.splitlines() if not w.strip().startswith("#"))
    # USR1 reopens the log only; HUP would reload the config (docs/reference/log.md).
    assert "systemctl kill --kill-who=main --signal=USR1 safety-supervisor.service" in commands
    assert "reload" not in commands  # a rotation must not re-run check


def test_logrotate_parses_and_rotates(tmp_path: Path) -> None:
    tool = _need("logrotate", "logrotate")
    me = pwd.getpwuid(os.getuid()).pw_name
    logs = tmp_path / "logs"
    logs.mkdir()
    conf = tmp_path / "logrotate.conf"
    conf.write_text(render_logrotate(LOGROTATE.read_text(), user=me, log_dir=str(logs)))
    state = tmp_path / "state"

    r = subprocess.run([tool, "-d", "-s", str(state), str(conf)], capture_output=True, text=True)
    assert r.returncode == 0 and "error" not in r.stderr.lower(), r.stderr

    log = logs / "violations.jsonl"
    log.write_text('{"event":"supervisor"}\n')
    r = subprocess.run([tool, "-f", "-s", str(state), str(conf)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert (logs / "violations.jsonl.1").read_text() == '{"event":"supervisor"}\n'
    assert log.exists() and log.stat().st_size == 0  # created anew, not truncated
    assert log.stat().st_mode & 0o777 == 0o640


# ------------------------------------------------------------------ install-service


def test_dry_run_prints_plan_and_changes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    def forbidden(*a: object, **k: object) -> None:
        raise AssertionError(f"dry run executed something: {a}")

    monkeypatch.setattr(install, "run_step", forbidden)
    monkeypatch.setattr(install.children, "run", forbidden)  # its one way to start a child
    monkeypatch.setattr(install.children, "start", forbidden)
    prefix, unit_dir, rot_dir = tmp_path / "opt", tmp_path / "units", tmp_path / "logrotate.d"
    user = "ss-test-" + os.urandom(3).hex()
    etc_existed = install.CONFIG_DIR.exists()
    python = _fake_python(tmp_path)

    rc = install.main(
        [
            "--dry-run",
            "--python",
            str(python),
            "--prefix",
            str(prefix),
            "--unit-dir",
            str(unit_dir),
            "--logrotate-dir",
            str(rot_dir),
            "--user",
            user,
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0, out
    expected = [
        "dry run: nothing is changed",
        f"useradd --system --user-group --no-create-home --home-dir /var/lib/safety-supervisor "
        f"--shell /usr/sbin/nologin --comment 'safety-supervisor daemon' {user}",
        "/etc/safety-supervisor",
        "write /etc/safety-supervisor/supervisor.yaml",
        "write /etc/safety-supervisor/environment",
        f"$ {python} -m venv {prefix}/venv",
        f"{prefix}/venv/bin/python -m pip install --upgrade {ROOT}",
        f"write {unit_dir}/safety-supervisor.service",
        f"write {rot_dir}/safety-supervisor",
        "$ systemctl daemon-reload",
        "next:",
        "ROS_DOMAIN_ID",
        "known_hosts",
        f"chown root:{user}",
        "systemctl enable --now safety-supervisor.service",
        f"{prefix}/venv/bin/safety-supervisor check /etc/safety-supervisor/supervisor.yaml",
    ]
    for text in expected:
        assert text in out, f"{text!r} not in:\n{out}"
    for p in (prefix, unit_dir, rot_dir):
        assert not p.exists()
    assert install.CONFIG_DIR.exists() == etc_existed
    with pytest.raises(KeyError):
        pwd.getpwnam(user)


def test_plan_renders_unit_and_logrotate_for_prefix_and_user(tmp_path: Path) -> None:
    args = _args(tmp_path, "--user", "robosafe")
    plan = install.make_plan(args)
    by_path = {s.write: s.content.decode() for s in plan.steps if s.write is not None}
    unit = by_path[tmp_path / "units/safety-supervisor.service"]
    assert unit_directives(unit, "User") == ["robosafe"]
    assert unit_directives(unit, "Group") == ["robosafe"]
    (start,) = unit_directives(unit, "ExecStart")
    assert start.startswith(f"{tmp_path}/opt/venv/bin/safety-supervisor run ")
    assert not [w for w in unit.splitlines() if "/opt/safety-supervisor" in w and w[:1] != "#"]
    rot = by_path[tmp_path / "logrotate.d/safety-supervisor"]
    assert "create 0640 robosafe robosafe" in rot and "su robosafe robosafe" in rot
    config = by_path[install.INSTALLED_CONFIG]
    assert config == (ROOT / "config/srobot.yaml").read_text()


def test_config_imports_are_installed_beside_it(tmp_path: Path) -> None:
    plan = install.make_plan(
        _args(tmp_path, "--config", str(ROOT / "config/srobot-from-fret.yaml"))
    )
    written = {s.write for s in plan.steps if s.write is not None}
    assert install.CONFIG_DIR / "srobot-fret-export.json" in written
    assert install.CONFIG_DIR / "srobot-ogma-variables.txt" in written


def _fake_python(tmp_path: Path) -> Path:
    """An interpreter path outside any home directory (planning never runs it), so
    that the plan does not depend on where this machine's Python lives."""
    py = tmp_path / "bin" / "python3.11"
    py.parent.mkdir(parents=True, exist_ok=True)
    py.write_text("#!/bin/sh\nexit 1\n")
    py.chmod(0o755)
    return py


def _args(tmp_path: Path, *extra: str) -> object:
    p = install.argparse.ArgumentParser()
    install.add_arguments(p)
    return p.parse_args(
        [
            "--python",
            str(_fake_python(tmp_path)),
            "--prefix",
            str(tmp_path / "opt"),
            "--unit-dir",
            str(tmp_path / "units"),
            "--logrotate-dir",
            str(tmp_path / "logrotate.d"),
            *extra,
        ]
    )


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--prefix", "/home/robot/ss"], "ProtectHome=yes hides"),
        (["--prefix", "opt"], "must be an absolute path"),
        (["--config", "/nonexistent/x.yaml"], "cannot read config"),
        (["--user", "Bad User"], "not a valid user name"),
        (["--source", "/nonexistent"], "not a safety-supervisor source tree"),
    ],
)
def test_errors_are_one_line(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert install.main(["--dry-run", *argv]) == 1
    captured = capsys.readouterr()
    assert message in captured.err and captured.err.count("\n") == 1, captured.err
    assert "Traceback" not in captured.err + captured.out


def test_venv_python_must_be_visible_to_the_service(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    home = tmp_path / "home"
    monkeypatch.setattr(install, "HIDDEN_BY_PROTECT_HOME", (str(home),))
    hidden = _fake_python(home)
    with pytest.raises(install.UserError, match="ProtectHome=yes hides"):
        install.choose_python(str(hidden))
    with pytest.raises(install.UserError, match="no such file"):
        install.choose_python(str(tmp_path / "nope"))
    visible = _fake_python(tmp_path)
    assert install.choose_python(str(visible)) == (visible, None)
    # This Python under a home directory: the system's python3, if it is 3.11+.
    monkeypatch.setattr(install.sys, "executable", str(hidden))
    try:
        chosen, why = install.choose_python(None)
    except install.UserError as e:
        assert "/usr/bin/python3 is not 3.11+" in str(e)
    else:
        assert chosen == Path("/usr/bin/python3") and why and "ProtectHome" in why


def test_must_be_root_without_dry_run(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(install.os, "geteuid", lambda: 1000)
    monkeypatch.setattr(install, "make_plan", lambda a: pytest.fail("planned as non-root"))
    assert install.main([]) == 1
    err = capsys.readouterr().err
    assert err.startswith("install-service: must run as root") and err.count("\n") == 1


def test_execute_runs_writes_and_skips(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The executor itself, on steps confined to a temp dir."""
    d = tmp_path / "etc"
    plan = install.Plan(
        steps=[
            install.Step("make dir", mkdir=d, mode=0o750),
            install.Step("write file", write=d / "f", content=b"x=1\n", mode=0o600),
            install.Step("skipped", write=d / "g", content=b"no", skip="exists"),
            install.Step("run", argv=("sh", "-c", f"echo ran > {d}/r")),
        ],
        next_steps=[],
        notes=[],
    )
    install.execute(plan)
    assert d.stat().st_mode & 0o777 == 0o750
    assert (d / "f").read_bytes() == b"x=1\n" and (d / "f").stat().st_mode & 0o777 == 0o600
    assert not (d / "g").exists()
    assert (d / "r").read_text() == "ran\n"
    assert "skipped: skipped (exists)" in capsys.readouterr().out

    failing = install.Plan([install.Step("fail", argv=("false",))], [], [])
    with pytest.raises(install.UserError, match="fail: false exited 1"):
        install.execute(failing)


# ------------------------------------------------------------------ install-service from a wheel


class _Dist:
    """What importlib.metadata says about an installed safety-supervisor: its
    version and PEP 610's direct_url.json (None: it came from an index)."""

    version = "0.1.0"

    def __init__(self, direct_url: dict | None) -> None:
        self.direct_url = direct_url

    def locate_file(self, path: str) -> Path:
        return Path(supervisor.__file__).resolve().parents[1] / path

    def read_text(self, name: str) -> str | None:
        if name == "direct_url.json" and self.direct_url is not None:
            return json.dumps(self.direct_url)
        return None


def _installed_plan(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, direct_url: dict | None
) -> install.Plan:
    """The plan when the running package is an installed copy, not a checkout."""
    monkeypatch.setattr(install, "_running_checkout", lambda: None)
    monkeypatch.setattr(metadata, "distribution", lambda name: _Dist(direct_url))
    return install.make_plan(_args(tmp_path))


def _pip_step(plan: install.Plan) -> install.Step:
    (step,) = [s for s in plan.steps if s.argv and s.argv[1:4] == ("-m", "pip", "install")]
    return step


def test_plan_from_a_wheel_install_installs_the_same_wheel(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    wheel = tmp_path / "safety_supervisor-0.1.0-py3-none-any.whl"
    wheel.write_bytes(b"PK")
    url = {"url": wheel.as_uri(), "archive_info": {}}
    plan = _installed_plan(tmp_path, monkeypatch, url)
    step = _pip_step(plan)
    assert step.argv is not None and step.argv[-1] == str(wheel)
    assert f"from {wheel}, which the running package was installed from" in step.description
    # The unit, logrotate snippet and config are the running package's own.
    origins = {s.write: s.origin for s in plan.steps if s.write is not None}
    assert origins[tmp_path / "units/safety-supervisor.service"] == str(data.systemd_unit())
    assert origins[install.INSTALLED_CONFIG] == str(data.example("srobot.yaml"))


def test_plan_from_an_index_install_pins_the_running_version(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    step = _pip_step(_installed_plan(tmp_path, monkeypatch, None))
    assert step.argv is not None and step.argv[-1] == "safety-supervisor==0.1.0"
    assert "package index (safety-supervisor==0.1.0" in step.description


def test_plan_from_a_vcs_install_pins_the_commit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    url = {"url": "https://example.org/ss.git", "vcs_info": {"vcs": "git", "commit_id": "abc123"}}
    step = _pip_step(_installed_plan(tmp_path, monkeypatch, url))
    assert step.argv is not None
    assert step.argv[-1] == "safety-supervisor @ git+https://example.org/ss.git@abc123"


def test_plan_from_a_vanished_wheel_is_a_one_line_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    gone = tmp_path / "gone" / "safety_supervisor-0.1.0-py3-none-any.whl"
    monkeypatch.setattr(install, "_running_checkout", lambda: None)
    monkeypatch.setattr(metadata, "distribution", lambda name: _Dist({"url": gone.as_uri()}))
    assert install.main(["--dry-run", "--python", str(_fake_python(tmp_path))]) == 1
    err = capsys.readouterr().err
    assert f"installed from {gone}, which is gone" in err and "--source" in err
    assert err.count("\n") == 1


def test_plan_with_a_wheel_as_source(tmp_path: Path) -> None:
    wheel = tmp_path / "safety_supervisor-0.1.0-py3-none-any.whl"
    wheel.write_bytes(b"PK")
    step = _pip_step(install.make_plan(_args(tmp_path, "--source", str(wheel))))
    assert step.argv is not None and step.argv[-1] == str(wheel)


# ------------------------------------------------------------------ init


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "supervisor", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.slow  # a full check in a subprocess: full suite only (README, quick tier)
def test_init_writes_configs_that_pass_check(tmp_path: Path) -> None:
    r = _cli("init", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["srobot.yaml", "template.yaml"]
    assert (tmp_path / "srobot.yaml").read_text() == (ROOT / "config/srobot.yaml").read_text()
    assert "wrote srobot.yaml" in r.stdout and "wrote template.yaml" in r.stdout
    assert r.stdout.splitlines()[-1].endswith("safety-supervisor check template.yaml")
    for name in ("srobot.yaml", "template.yaml"):
        c = _cli("check", name, cwd=tmp_path)
        assert c.returncode == 0, c.stdout + c.stderr
        assert f"{name}: " in c.stdout and "requirements ok" in c.stdout


def test_init_never_overwrites_without_force(tmp_path: Path) -> None:
    target = tmp_path / "robot"
    target.mkdir()
    (target / "template.yaml").write_text("mine\n")
    r = _cli("init", "robot", cwd=tmp_path)
    assert r.returncode == 1 and r.stdout == ""
    assert (
        r.stderr == "robot/template.yaml: exists, not overwritten (hint: --force overwrites it)\n"
    )
    assert not (target / "srobot.yaml").exists()  # nothing written when one file exists
    assert (target / "template.yaml").read_text() == "mine\n"
    r = _cli("init", "--force", "robot", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (target / "template.yaml").read_text() != "mine\n"
    assert "robot/srobot.yaml" in r.stdout


def test_template_has_a_comment_for_every_key() -> None:
    """Each key of the template is commented where it first appears (on its
    line or just above); later entries repeat keys without comments."""
    lines = (ROOT / "config/template.yaml").read_text().splitlines()
    commented: dict[str, bool] = {}
    for i, line in enumerate(lines):
        m = re.match(r"^\s*#?(?:- )?([A-Za-z_]+):(?:\s|$)", line)
        if m is None or line.lstrip().startswith("# "):
            continue
        above = lines[i - 1].lstrip() if i else ""
        ok = " # " in line or above.startswith("# ")
        commented[m.group(1)] = commented.get(m.group(1), False) or ok
    assert len(commented) > 40
    assert not [k for k, ok in commented.items() if not ok]
