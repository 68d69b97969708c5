"""The wheel as a robot admin gets it: built from this tree, installed (not
editable, no dependencies) into a fresh venv that sees the dependencies the
tests run with (ROS 2, z3, ...) but not this checkout, and used from an empty
directory with a clean environment: ``init``, ``check`` on what it wrote,
``demo`` and ``install-service --dry-run``.  Everything the commands read must
come from the installed package's own data.
"""

from __future__ import annotations

import os
import random
import re
import shutil
import subprocess
import sys
import zipfile
from dataclasses import dataclass
from pathlib import Path

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[2]
# Non-Python files the commands read at run time.
PACKAGE_DATA = [
    "monitors/frontend/fretish.lark",
    "monitors/ir/expressions.lark",
    "supervisor/data/examples/srobot.yaml",
    "supervisor/data/examples/template.yaml",
    "supervisor/data/examples/srobot-from-fret.yaml",
    "supervisor/data/examples/srobot-fret-export.json",
    "supervisor/data/examples/srobot-ogma-variables.txt",
    "supervisor/data/examples/heartbeat_guard.py",
    "supervisor/data/systemd/safety-supervisor.service",
    "supervisor/data/logrotate/safety-supervisor",
]
# Not part of a build: version control, caches, earlier builds, the tests.
NOT_SOURCE = shutil.ignore_patterns(
    ".git", "__pycache__", "*.egg-info", "build", "dist", ".*_cache", ".venv", "tests"
)


@dataclass(frozen=True)
class Venv:
    root: Path
    wheel: Path
    site: Path  # the venv's own site-packages
    home: Path
    domain_id: int

    def run(self, cwd: Path, *argv: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
        """A venv command with nothing of this process's environment (no
        PYTHONPATH) but the ROS 2 libraries' path, as sourcing ROS sets it on a
        robot, and the test's own DDS domain."""
        env = {
            "PATH": f"{self.root / 'bin'}:/usr/local/bin:/usr/bin:/bin",
            "HOME": str(self.home),
            "LANG": "C.UTF-8",
            "ROS_DOMAIN_ID": str(self.domain_id),
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        }
        if "LD_LIBRARY_PATH" in os.environ:
            env["LD_LIBRARY_PATH"] = os.environ["LD_LIBRARY_PATH"]
        return subprocess.run(
            argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
        )


def _ok(r: subprocess.CompletedProcess[str]) -> str:
    assert r.returncode == 0, f"{r.args} exited {r.returncode}\n{r.stdout}\n{r.stderr}"
    assert "Traceback" not in r.stderr, r.stderr
    return r.stdout


def _empty_dir(tmp: pytest.TempPathFactory, name: str) -> Path:
    d = tmp.mktemp(name)
    assert list(d.iterdir()) == []
    return d


@pytest.fixture(scope="module")
def venv(tmp_path_factory: pytest.TempPathFactory) -> Venv:
    base = tmp_path_factory.mktemp("wheel")
    # Build from a copy: a build writes build/ and *.egg-info next to its sources.
    src = base / "src"
    shutil.copytree(ROOT, src, ignore=NOT_SOURCE, symlinks=True)
    dist = base / "dist"
    _ok(
        subprocess.run(
            [sys.executable, "-m", "build", "--wheel", "--outdir", str(dist), str(src)],
            cwd=base,
            capture_output=True,
            text=True,
            timeout=300,
        )
    )
    (wheel,) = dist.glob("safety_supervisor-*.whl")
    root = base / "venv"
    _ok(
        subprocess.run(
            [sys.executable, "-m", "venv", str(root)],
            capture_output=True,
            text=True,
            timeout=120,
        )
    )
    home = base / "home"
    home.mkdir()
    v = Venv(root, wheel, Path(), home, random.randint(1, 200))
    here = _empty_dir(tmp_path_factory, "pip")
    py = str(root / "bin" / "python")
    _ok(v.run(here, py, "-m", "pip", "install", "--no-deps", "--no-index", str(wheel)))
    site = Path(
        _ok(
            v.run(here, py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])")
        ).strip()
    )
    (site / "zz_test_dependencies.pth").write_text(_see_dependencies())
    return Venv(root, wheel, site, home, v.domain_id)


def _see_dependencies() -> str:
    """A ``.pth`` line that adds the site directories this interpreter really
    imports from, after the venv's own.  ``venv --system-site-packages`` would
    see the base interpreter's, which has none of the dependencies when the
    tests themselves run in a venv (as the README's commands make them).
    ``site.addsitedir`` also runs their ``.pth`` files, as Python does for its
    own site directories (https://docs.python.org/3/library/site.html)."""
    dirs = [p for p in sys.path if Path(p).name in ("site-packages", "dist-packages")]
    assert dirs, sys.path
    # One statement without a nested scope: site.py runs a .pth line with exec() in a
    # function, where a comprehension would not see the imported name.
    return f"import site; list(map(site.addsitedir, {dirs!r}))\n"


def test_wheel_ships_the_package_data(venv: Venv) -> None:
    names = set(zipfile.ZipFile(venv.wheel).namelist())
    assert [n for n in PACKAGE_DATA if n not in names] == []
    assert not [n for n in names if n.startswith(("tests/", "config/", "packaging/"))]


def test_the_venv_imports_the_installed_package_not_the_checkout(
    venv: Venv, tmp_path_factory: pytest.TempPathFactory
) -> None:
    # The editable install of this checkout is in the site-packages the venv
    # sees: the venv's own copy must come first.
    probe = "import monitors, mitigations, supervisor; print(supervisor.__file__, monitors.__file__, mitigations.__file__)"
    out = _ok(venv.run(_empty_dir(tmp_path_factory, "probe"), "python", "-c", probe))
    for f in out.split():
        assert Path(f).is_relative_to(venv.site), (f, venv.site)
    script = venv.root / "bin" / "safety-supervisor"
    assert script.read_text().splitlines()[0] == f"#!{venv.root / 'bin' / 'python'}"


def test_init_then_check(venv: Venv, tmp_path_factory: pytest.TempPathFactory) -> None:
    here = _empty_dir(tmp_path_factory, "robot")
    out = _ok(venv.run(here, "safety-supervisor", "init"))
    assert sorted(p.name for p in here.iterdir()) == ["srobot.yaml", "template.yaml"]
    assert "safety-supervisor check template.yaml" in out
    for name in ("srobot.yaml", "template.yaml"):
        out = _ok(venv.run(here, "safety-supervisor", "check", name))
        assert re.search(rf"^{name}: \d+ requirements ok, monitor compiled and loaded", out, re.M)


def test_demo(venv: Venv, tmp_path_factory: pytest.TempPathFactory) -> None:
    out = _ok(
        venv.run(
            _empty_dir(tmp_path_factory, "demo"),
            "safety-supervisor",
            "demo",
            "--duration",
            "8",
            timeout=180,
        )
    )
    assert "demo finished after 8.0 s" in out, out
    ticks = re.search(r"supervisor ticks  (\d+)", out)
    assert ticks is not None and int(ticks.group(1)) >= 50, out


def test_install_service_dry_run(venv: Venv, tmp_path_factory: pytest.TempPathFactory) -> None:
    out = _ok(
        venv.run(
            _empty_dir(tmp_path_factory, "admin"),
            "safety-supervisor",
            "install-service",
            "--dry-run",
        )
    )
    data = venv.site / "supervisor" / "data"
    for text in (
        "dry run: nothing is changed",
        f"-m pip install --upgrade {venv.wheel}",
        f"from {venv.wheel}, which the running package was installed from",
        f"from {data / 'examples' / 'srobot.yaml'})",
        f"from {data / 'systemd' / 'safety-supervisor.service'})",
        f"from {data / 'logrotate' / 'safety-supervisor'})",
        "systemctl enable --now safety-supervisor.service",
    ):
        assert text in out, f"{text!r} not in:\n{out}"
