"""``safety-supervisor install-service``: install the daemon as a systemd service.

What it does, in order (each step is printed before it runs):

1. the system user (``useradd --system``, no home, no login shell) and the
   operators' group (``groupadd --system safety-operators``: its members may
   reset through the control socket);
2. ``/etc/safety-supervisor`` with the config (copied only if absent: an
   existing config is never overwritten) and an environment file template;
3. a venv under the prefix (``/opt/safety-supervisor/venv``) and
   ``pip install SOURCE`` into it: ``--source``, else the checkout this runs
   from, else what pip installed the running package from (the same wheel, or
   the same version from the package index);
4. the unit and the logrotate snippet shipped in :mod:`supervisor.data`, with
   the prefix and the user substituted, and the operator page's unit
   (``safety-supervisor-ui.service``) with its token
   (``/etc/safety-supervisor/ui.token``, mode 0640 root:<user>, made once);
5. ``systemctl daemon-reload``.

The plan is data (a list of :class:`Step`), computed once from the arguments
and the machine's current state; ``--dry-run`` prints exactly the steps that
would run and executes nothing.  Without ``--dry-run`` it must run as root.
Errors are one line (``install-service: ...``), never a traceback.

Standard library only (plus PyYAML, a dependency anyway), so it stays quick.
"""

from __future__ import annotations

import argparse
import grp
import json
import os
import pwd
import re
import shlex
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlparse

import supervisor
from monitors.errors import UserError
from supervisor import children, data
from supervisor.files import write_atomic
from supervisor.names import OPERATORS_GROUP
from supervisor.tools.ui.token import TOKEN_FILE, TOKEN_MODE, new_token

NAME = "safety-supervisor"
PROG = "install-service"
UNIT_NAME = data.UNIT_NAME
UI_UNIT_NAME = "safety-supervisor-ui.service"  # beside the daemon's unit in supervisor.data
DEFAULT_PREFIX = "/opt/safety-supervisor"
DEFAULT_CONFIG = "srobot.yaml"  # a shipped example (supervisor.data)
CONFIG_DIR = Path("/etc/safety-supervisor")
# The unit names this file; whatever --config was, it is installed under this name.
INSTALLED_CONFIG = CONFIG_DIR / "supervisor.yaml"
ENVIRONMENT_FILE = CONFIG_DIR / "environment"
STATE_DIR = "/var/lib/safety-supervisor"  # the unit's StateDirectory=, the user's home
# ProtectHome=yes hides these from the service: nothing it runs may live there.
HIDDEN_BY_PROTECT_HOME = ("/home", "/root", "/run/user")
# The package's data inside a checkout (where --source DIR points).
DATA_IN_TREE = Path("supervisor/data")


def _running_checkout() -> Path | None:
    """The source tree the running package is imported from, if it is one (an
    editable install or PYTHONPATH), not an installed copy in site-packages."""
    root = Path(supervisor.__file__).resolve().parents[1]
    return root if (root / "pyproject.toml").is_file() else None


ENVIRONMENT_TEMPLATE = """\
# Environment of safety-supervisor.service (KEY=value lines; read at each start).
# Settings here override the unit's Environment= lines.
#
# The robot's DDS domain (default 0), and whether discovery leaves this host:
#ROS_DOMAIN_ID=0
#ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET
#
# The unit makes Fast DDS use UDP only: its shared memory transport does not
# work between processes of different users (the daemon keeps UDP only under
# LOCALHOST too).  To use shared memory anyway:
#FASTDDS_BUILTIN_TRANSPORTS=DEFAULT
"""


@dataclass(frozen=True)
class Step:
    """One thing the installer does: run ``argv``, create directory ``mkdir`` or
    write ``content`` to ``write``.  ``skip`` says why it is not needed (it is
    printed in the plan, and not done)."""

    description: str
    argv: tuple[str, ...] | None = None
    mkdir: Path | None = None
    write: Path | None = None
    content: bytes = b""
    mode: int = 0o644
    skip: str | None = None
    origin: str | None = None  # where written content comes from (for the plan)

    def action(self) -> str:
        """The exact action, one line (what ``--dry-run`` prints)."""
        if self.argv is not None:
            return "$ " + shlex.join(self.argv)
        if self.mkdir is not None:
            return f"mkdir -m {self.mode:04o} {self.mkdir}"
        assert self.write is not None
        origin = f" from {self.origin}" if self.origin else ""
        return f"write {self.write} (mode {self.mode:04o}, {len(self.content)} bytes{origin})"


@dataclass
class Plan:
    steps: list[Step]
    next_steps: list[str]
    notes: list[str]


# ------------------------------------------------------------------ rendering


def render_unit(
    text: str,
    *,
    prefix: str = DEFAULT_PREFIX,
    user: str = NAME,
    paths: dict[str, str] | None = None,
) -> str:
    """The shipped unit with the install prefix and user substituted; ``paths``
    maps further absolute paths to others (tests point them into a temp dir)."""
    out = text.replace(DEFAULT_PREFIX + "/", prefix.rstrip("/") + "/")
    for old, new in (paths or {}).items():
        out = out.replace(old, new)
    out = re.sub(r"(?m)^User=.*$", f"User={user}", out)
    return re.sub(r"(?m)^Group=.*$", f"Group={user}", out)


def render_logrotate(text: str, *, user: str = NAME, log_dir: str | None = None) -> str:
    """The shipped logrotate snippet for ``user`` (and another log directory)."""
    out = text
    if log_dir is not None:
        out = out.replace("/var/log/safety-supervisor/", log_dir.rstrip("/") + "/")
    out = re.sub(r"(?m)^(\s*su) \S+ \S+$", rf"\1 {user} {user}", out)
    return re.sub(r"(?m)^(\s*create \d+) \S+ \S+$", rf"\1 {user} {user}", out)


def unit_directives(text: str, key: str) -> list[str]:
    """Values of every ``key=`` line in a unit file (no continuation lines used)."""
    prefix = key + "="
    return [line[len(prefix) :].strip() for line in text.splitlines() if line.startswith(prefix)]


# ------------------------------------------------------------------ planning


def _hidden_by_protect_home(path: Path) -> bool:
    p = str(path)
    return any(p == h or p.startswith(h + "/") for h in HIDDEN_BY_PROTECT_HOME)


def _python_version(path: Path) -> tuple[int, int] | None:
    """The version in an interpreter's resolved file name (python3.11), if any:
    planning must not execute anything."""
    m = re.fullmatch(r"python(\d+)\.(\d+)", path.resolve().name)
    return (int(m.group(1)), int(m.group(2))) if m else None


def choose_python(requested: str | None) -> tuple[Path, str | None]:
    """The interpreter for the venv and, when it is not the running one, why.

    A venv's interpreter and standard library stay in the base installation, so
    a base under /home or /root (pyenv, conda) is invisible to the service."""
    if requested:
        py = Path(requested)
        if not py.is_file():
            raise UserError(f"--python {requested}: no such file", file=PROG)
        if _hidden_by_protect_home(py.resolve()):
            raise UserError(
                f"--python {requested} lives under {py.resolve()}, which ProtectHome=yes hides "
                "from the service",
                file=PROG,
                hint="use a system Python 3.11+, e.g. /usr/bin/python3",
            )
        return py, None
    running = Path(sys.executable)
    if not _hidden_by_protect_home(running.resolve()):
        return running, None
    system = Path("/usr/bin/python3")
    version = _python_version(system) if system.is_file() else None
    if version is None or version < (3, 11):
        raise UserError(
            f"this Python ({running.resolve()}) is under a home directory, which "
            "ProtectHome=yes hides from the service, and /usr/bin/python3 is not 3.11+",
            file=PROG,
            hint="install python3 (3.11+) and python3-venv, or give --python",
        )
    return system, f"venv from {system} ({running.resolve()} is hidden by ProtectHome=yes)"


@dataclass(frozen=True)
class Source:
    """What the venv gets: ``pip`` is the argument of ``pip install``, ``what``
    says it in the plan, ``tree`` is the checkout it is, if it is one (the unit,
    the logrotate snippet and the default config then come from it, so they
    match the code installed)."""

    pip: str
    what: str
    tree: Path | None = None


_SOURCE_HINT = "give --source DIR (a checkout), --source FILE.whl or an sdist"


def _is_archive(path: Path) -> bool:
    return path.is_file() and (path.suffix == ".whl" or path.name.endswith(".tar.gz"))


def _given_source(arg: str) -> Source:
    src = Path(arg).resolve()
    if _is_archive(src):
        return Source(str(src), str(src))
    if not (src / "pyproject.toml").is_file():
        raise UserError(
            f"{src} is not a safety-supervisor source tree (no pyproject.toml)",
            file=PROG,
            hint=_SOURCE_HINT,
        )
    return Source(str(src), str(src), src)


def _installed_source() -> Source:
    """What pip installed the running package from (PEP 610's direct_url.json):
    the service gets the same build.  Without that record it came from an index,
    so the index gives the same version again."""
    from importlib import metadata  # only here: the CLI imports this module for its parser

    try:
        dist = metadata.distribution(NAME)
    except metadata.PackageNotFoundError:
        dist = None
    here = Path(supervisor.__file__).resolve()
    if dist is None or Path(str(dist.locate_file("supervisor/__init__.py"))).resolve() != here:
        raise UserError(
            f"cannot tell where the running safety-supervisor ({here.parent}) was installed from",
            file=PROG,
            hint=_SOURCE_HINT,
        )
    try:
        direct = json.loads(dist.read_text("direct_url.json") or "null")
    except json.JSONDecodeError:
        direct = None
    if not isinstance(direct, dict) or not isinstance(direct.get("url"), str):
        pin = f"{NAME}=={dist.version}"
        return Source(pin, f"the package index ({pin}, the version running here)")
    url: str = direct["url"]
    vcs = direct.get("vcs_info")
    if isinstance(vcs, dict):
        ref = (
            f"{vcs.get('vcs', 'git')}+{url}@{vcs.get('commit_id') or vcs.get('requested_revision')}"
        )
        return Source(f"{NAME} @ {ref}", ref)
    parsed = urlparse(url)
    if parsed.scheme != "file":
        return Source(f"{NAME} @ {url}", url)
    path = Path(unquote(parsed.path))
    if _is_archive(path):
        return Source(str(path), f"{path}, which the running package was installed from")
    if (path / "pyproject.toml").is_file():
        return Source(str(path), f"{path}, which the running package was installed from", path)
    raise UserError(
        f"the running safety-supervisor was installed from {path}, which is gone",
        file=PROG,
        hint=_SOURCE_HINT,
    )


def _source(args: argparse.Namespace) -> Source:
    if args.source:
        return _given_source(args.source)
    tree = _running_checkout()
    return Source(str(tree), str(tree), tree) if tree else _installed_source()


def _shipped(source: Source, packaged: Path) -> Path:
    """A shipped file (``packaged``, from :mod:`supervisor.data`), taken from the
    checkout being installed when there is one, else from the running package."""
    if source.tree is not None:
        # Every shipped file is supervisor/data/<kind>/<name>.
        in_tree = source.tree / DATA_IN_TREE / packaged.parent.name / packaged.name
        if in_tree.is_file():
            return in_tree
    return packaged


def _template(source: Source, path: Path) -> tuple[Path, str]:
    path = _shipped(source, path)
    try:
        return path, path.read_text(encoding="utf-8")
    except OSError as e:
        raise UserError(f"cannot read {path}: {e.strerror or e}", file=PROG) from e


def _config_extras(config: Path) -> tuple[list[Path], list[str]]:
    """Files a config imports relative to itself (they are installed beside it)
    and the key/known_hosts files of its ``ssh`` mitigations."""
    import yaml

    try:
        doc = yaml.safe_load(config.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError, UnicodeDecodeError):
        return [], []  # `check` reports it with the line; copying needs no parse
    if not isinstance(doc, dict):
        return [], []
    extras: list[Path] = []
    for key in ("requirements_from", "variables_from"):
        value = doc.get(key)
        for name in [value] if isinstance(value, str) else value or []:
            if isinstance(name, str) and not Path(name).is_absolute():
                extras.append(Path(name))
    secrets: list[str] = []
    for m in (doc.get("mitigations") or {}).values():
        ssh = m.get("ssh") if isinstance(m, dict) else None
        if isinstance(ssh, dict):
            for key in ("key", "known_hosts"):
                if isinstance(ssh.get(key), str) and ssh[key] not in secrets:
                    secrets.append(ssh[key])
    return extras, secrets


def _systemd_running() -> bool:
    return Path("/run/systemd/system").is_dir()  # sd_booted(3)


def _checked_user_and_prefix(args: argparse.Namespace) -> tuple[str, Path]:
    user: str = args.user
    if not re.fullmatch(r"[a-z_][a-z0-9_-]{0,31}", user):
        raise UserError(f"--user {user!r} is not a valid user name", file=PROG)
    prefix = Path(args.prefix)
    if not prefix.is_absolute():
        raise UserError(f"--prefix {args.prefix} must be an absolute path", file=PROG)
    if _hidden_by_protect_home(prefix):
        raise UserError(
            f"--prefix {prefix} is under a home directory, which ProtectHome=yes hides "
            "from the service",
            file=PROG,
            hint=f"use e.g. {DEFAULT_PREFIX}",
        )
    return user, prefix


def make_plan(args: argparse.Namespace) -> Plan:
    """Every step of the installation, from the arguments and what exists now."""
    user, prefix = _checked_user_and_prefix(args)
    source = _source(args)
    config = Path(args.config) if args.config else _shipped(source, data.example(DEFAULT_CONFIG))
    try:
        config_bytes = config.read_bytes()
    except OSError as e:
        raise UserError(f"cannot read config: {e.strerror or e}", file=str(config)) from e
    python, python_note = choose_python(args.python)
    # unit, UI unit, logrotate snippet: read before anything is planned, so a broken
    # installation is said first
    templates = (
        _template(source, data.systemd_unit()),
        _template(source, data.systemd_unit().with_name(UI_UNIT_NAME)),
        _template(source, data.logrotate_snippet()),
    )
    venv = prefix / "venv"
    notes = [python_note] if python_note else []
    extras, secrets = _config_extras(config)
    steps = [
        *_account_steps(user),
        *_config_steps(config, config_bytes, extras),
        *_venv_steps(python, venv, source),
        *_unit_steps(templates, args, prefix, user),
    ]
    next_steps = _next_steps(venv / "bin" / NAME, user, secrets)
    if not (shutil.which("cc") or shutil.which("gcc")):
        notes.append("no C compiler found: the daemon compiles its monitor at start; install gcc")
    return Plan(steps, next_steps, notes)


def _account_steps(user: str) -> list[Step]:
    """The service user and the operators' group."""
    try:
        pwd.getpwnam(user)
        user_skip: str | None = f"user {user} exists"
    except KeyError:
        user_skip = None
    try:
        grp.getgrnam(OPERATORS_GROUP)
        group_skip: str | None = f"group {OPERATORS_GROUP} exists"
    except KeyError:
        group_skip = None
    return [
        Step(
            f"create the system user {user}",
            argv=(
                "useradd",
                "--system",
                "--user-group",
                "--no-create-home",
                "--home-dir",
                STATE_DIR,
                "--shell",
                "/usr/sbin/nologin",
                "--comment",
                "safety-supervisor daemon",
                user,
            ),
            skip=user_skip,
        ),
        Step(
            f"create the group {OPERATORS_GROUP}: its members may `safety-supervisor reset`",
            argv=("groupadd", "--system", OPERATORS_GROUP),
            skip=group_skip,
        ),
    ]


def _config_steps(config: Path, config_bytes: bytes, extras: list[Path]) -> list[Step]:
    """The config, the files it imports and the environment file; none overwritten."""
    steps = [
        Step(
            f"create {CONFIG_DIR}",
            mkdir=CONFIG_DIR,
            mode=0o755,
            skip="exists" if CONFIG_DIR.is_dir() else None,
        ),
        Step(
            "install the config",
            write=INSTALLED_CONFIG,
            content=config_bytes,
            origin=str(config),
            skip="exists, not overwritten" if INSTALLED_CONFIG.exists() else None,
        ),
    ]
    for rel in extras:
        src = config.parent / rel
        dst = CONFIG_DIR / rel
        try:
            imported = src.read_bytes()
        except OSError as e:
            raise UserError(
                f"cannot read {src} (imported by the config): {e.strerror or e}", file=str(config)
            ) from e
        steps.append(
            Step(
                f"install {rel}, which the config imports",
                write=dst,
                content=imported,
                origin=str(src),
                skip="exists, not overwritten" if dst.exists() else None,
            )
        )
    steps.append(
        Step(
            "install the environment file template (ROS_DOMAIN_ID, ...)",
            write=ENVIRONMENT_FILE,
            content=ENVIRONMENT_TEMPLATE.encode(),
            skip="exists, not overwritten" if ENVIRONMENT_FILE.exists() else None,
        )
    )
    return steps


def _venv_steps(python: Path, venv: Path, source: Source) -> list[Step]:
    return [
        Step(
            f"create the venv {venv}",
            argv=(str(python), "-m", "venv", str(venv)),
            skip="exists" if (venv / "bin" / "python").exists() else None,
        ),
        Step(
            f"install safety-supervisor into the venv from {source.what}",
            argv=(str(venv / "bin" / "python"), "-m", "pip", "install", "--upgrade", source.pip),
        ),
    ]


def _unit_steps(
    templates: tuple[tuple[Path, str], ...], args: argparse.Namespace, prefix: Path, user: str
) -> list[Step]:
    """The two units, the operator page's token, the logrotate snippet, daemon-reload."""
    (unit_src, unit_text), (ui_src, ui_text), (rot_src, rot_text) = templates
    unit_dir, rot_dir = Path(args.unit_dir), Path(args.logrotate_dir)
    # The page's resets need this token; the UI (the service user) reads it, root
    # hands it to operators.  Never overwritten: operators may have it already.
    token_skip = "exists, not overwritten" if TOKEN_FILE.exists() else None
    return [
        Step(
            f"install the unit (venv {prefix / 'venv'}, user {user})",
            write=unit_dir / UNIT_NAME,
            content=render_unit(unit_text, prefix=str(prefix), user=user).encode(),
            origin=str(unit_src),
        ),
        Step(
            f"install the operator page's unit (safety-supervisor ui, user {user})",
            write=unit_dir / UI_UNIT_NAME,
            content=render_unit(ui_text, prefix=str(prefix), user=user).encode(),
            origin=str(ui_src),
        ),
        Step(
            "create the operator page's token",
            write=TOKEN_FILE,
            content=new_token(),
            mode=TOKEN_MODE,
            origin="256 random bits",
            skip=token_skip,
        ),
        Step(
            f"let the service user {user} read the token",
            argv=("chown", f"root:{user}", str(TOKEN_FILE)),
            skip=token_skip,
        ),
        Step(
            f"install the logrotate snippet (user {user})",
            write=rot_dir / NAME,
            content=render_logrotate(rot_text, user=user).encode(),
            origin=str(rot_src),
        ),
        Step(
            "make systemd read the unit",
            argv=("systemctl", "daemon-reload"),
            skip=None if _systemd_running() else "systemd is not running on this machine",
        ),
    ]


def _next_steps(exe: Path, user: str, secrets: list[str]) -> list[str]:
    """What the administrator does after the installation."""
    check = f"{exe} check {INSTALLED_CONFIG}"
    ssh_files = ", ".join(secrets) if secrets else f"{CONFIG_DIR}/id_ed25519, known_hosts"
    return [
        f"Edit {INSTALLED_CONFIG}: topics, requirements, mitigations; then test it: {check}",
        f"Set the robot's ROS_DOMAIN_ID (and ROS_AUTOMATIC_DISCOVERY_RANGE) in {ENVIRONMENT_FILE}.",
        f"For ssh mitigations, install the private key and known_hosts ({ssh_files}) "
        f"readable by the service only: chown root:{user} FILE; chmod 0640 FILE "
        "(known_hosts: ssh-keyscan HOST, then compare the fingerprint with the host's).",
        f"Start it now and at boot: systemctl enable --now {UNIT_NAME}; watch it: "
        f"systemctl status {UNIT_NAME}; journalctl -u {UNIT_NAME} -f",
        f"Let operators reset latched mitigations: usermod -aG {OPERATORS_GROUP} USER "
        "(then `safety-supervisor reset` as that user, after logging in again).",
        f"The operator page (optional): systemctl enable --now {UI_UNIT_NAME}; it listens on "
        "127.0.0.1:8321 (from elsewhere: ssh -L 8321:127.0.0.1:8321 ROBOT); its resets need "
        f"the token in {TOKEN_FILE} (sudo cat it once per operator).",
        f"After editing the config: systemctl reload {UNIT_NAME} (returns once the new "
        "config is in force; a config that fails check is refused with its reason and the "
        "running monitor stays in place).",
    ]


# ------------------------------------------------------------------ output / execution


def format_plan(plan: Plan, *, dry_run: bool) -> str:
    head = (
        "install-service plan (dry run: nothing is changed)" if dry_run else "install-service plan"
    )
    lines = [head + ":"]
    for i, s in enumerate(plan.steps, 1):
        lines.append(f"{i:2}. {s.description}" + (f"  [skip: {s.skip}]" if s.skip else ""))
        lines.append(f"      {s.action()}")
    lines += [f"note: {n}" for n in plan.notes]
    return "\n".join(lines)


def format_next(plan: Plan) -> str:
    return "\n".join(["next:"] + [f" {i}. {t}" for i, t in enumerate(plan.next_steps, 1)])


def run_step(step: Step) -> None:
    """Do one step; raises UserError naming it when it fails."""
    try:
        if step.argv is not None:
            rc = children.run(
                step.argv, env=children.child_env(), timeout=None, capture=False
            ).returncode
            if rc != 0:
                raise UserError(f"{step.description}: {step.argv[0]} exited {rc}", file=PROG)
        elif step.mkdir is not None:
            step.mkdir.mkdir(mode=step.mode, exist_ok=True)
            os.chmod(step.mkdir, step.mode)  # mkdir's mode is masked by the umask
        elif step.write is not None:
            write_atomic(step.write, step.content, step.mode)
    except OSError as e:
        where = e.filename or (step.argv[0] if step.argv else "")
        raise UserError(f"{step.description}: {where}: {e.strerror or e}", file=PROG) from e


def execute(plan: Plan, out: Any = None) -> None:
    out = out or sys.stdout
    old = os.umask(0o022)  # the service user must be able to read the venv and /etc files
    try:
        n = len(plan.steps)
        for i, s in enumerate(plan.steps, 1):
            if s.skip:
                print(f"[{i}/{n}] {s.description}: skipped ({s.skip})", file=out, flush=True)
                continue
            print(f"[{i}/{n}] {s.description}: {s.action()}", file=out, flush=True)
            run_step(s)
    finally:
        os.umask(old)


# ------------------------------------------------------------------ command


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "install-service",
        help="install the daemon as a systemd service (user, /etc, venv, unit, logrotate)",
    )
    add_arguments(p)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dry-run", action="store_true", help="print every step and change nothing")
    p.add_argument(
        "--prefix", default=DEFAULT_PREFIX, metavar="DIR", help="the venv goes to DIR/venv"
    )
    p.add_argument(
        "--config",
        default=None,
        metavar="FILE",
        help=f"config to install as {INSTALLED_CONFIG} if absent (default: the shipped "
        f"{DEFAULT_CONFIG} example)",
    )
    p.add_argument("--user", default=NAME, help="the service's system user and group")
    p.add_argument("--unit-dir", default="/etc/systemd/system", metavar="DIR")
    p.add_argument("--logrotate-dir", default="/etc/logrotate.d", metavar="DIR")
    p.add_argument(
        "--source",
        default=None,
        metavar="DIR|FILE",
        help="what to pip install: a source checkout, a wheel or an sdist (default: this "
        "checkout, else what the running package was installed from)",
    )
    p.add_argument(
        "--python",
        default=None,
        metavar="PATH",
        help="interpreter for the venv (default: this one, or /usr/bin/python3 if this "
        "one is under a home directory)",
    )


def cmd_install_service(args: argparse.Namespace) -> int:
    if not args.dry_run and os.geteuid() != 0:
        raise UserError(
            "must run as root (it creates a user and writes /etc, /opt)",
            file=PROG,
            hint="sudo, or --dry-run to see the plan",
        )
    plan = make_plan(args)
    print(format_plan(plan, dry_run=args.dry_run), flush=True)
    if args.dry_run:
        print(format_next(plan), flush=True)
        return 0
    execute(plan)
    print(f"installed {UNIT_NAME}.", flush=True)
    print(format_next(plan), flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    """``install-service`` on its own (tests; the CLI wires :func:`add_parser`)."""
    p = argparse.ArgumentParser(prog=f"{NAME} install-service")
    add_arguments(p)
    args = p.parse_args(argv)
    try:
        return cmd_install_service(args)
    except UserError as e:
        print(str(e), file=sys.stderr, flush=True)
        return 1
