"""The start-up cache (supervisor/cache.py) as systemd's ExecStartPre=check uses it:
the real CLI with a STATE_DIRECTORY, the real compiler behind a wrapper that logs
each compilation, real files in the cache."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from supervisor import cache

ROOT = Path(__file__).resolve().parents[2]
SROBOT = ROOT / "config" / "srobot.yaml"


def _wrapper(path: Path, log: Path, version: str = "wrapped cc 1") -> Path:
    """A compiler that logs each compile (not ``--version``) and runs the real cc.
    ``$CC_LOG`` and ``$CC_VERSION``, when set, replace ``log`` and ``version``: one
    wrapper, so one compiler path in the cache's key, serves every copied site."""
    real = shutil.which("cc") or shutil.which("gcc")
    assert real is not None
    path.write_text(
        "#!/bin/sh\n"
        f'if [ "$1" = --version ]; then echo "${{CC_VERSION:-{version}}}"; '
        f"exec {real} --version; fi\n"
        f'echo compile >> "${{CC_LOG:-{log}}}"\n'
        f'exec {real} "$@"\n'
    )
    path.chmod(0o755)
    return path


class Site:
    """A state directory, a config and a logging compiler."""

    def __init__(self, tmp: Path, cc: Path | None = None) -> None:
        self.state = tmp / "state"
        self.state.mkdir()
        self.config = tmp / "supervisor.yaml"
        shutil.copyfile(SROBOT, self.config)
        self.log = tmp / "cc.log"
        self.cc = cc or _wrapper(tmp / "cc", self.log)
        self.cc_version: str | None = None  # what the compiler says, when not its own

    def check(self, *extra_env: tuple[str, str]) -> subprocess.CompletedProcess[str]:
        env = {k: v for k, v in os.environ.items() if k != "SAFETY_SUPERVISOR_DEBUG"}
        env.update(STATE_DIRECTORY=str(self.state), CC=str(self.cc), CC_LOG=str(self.log))
        if self.cc_version is not None:
            env["CC_VERSION"] = self.cc_version
        env.update(dict(extra_env))
        r = subprocess.run(
            [sys.executable, "-m", "supervisor", "check", str(self.config)],
            capture_output=True,
            text=True,
            env=env,
            timeout=300,
        )
        assert "Traceback" not in r.stderr, r.stderr
        return r

    def compiles(self) -> int:
        """Compiler runs since the last call."""
        n = len(self.log.read_text().splitlines()) if self.log.exists() else 0
        self.log.unlink(missing_ok=True)
        return n

    def entries(self) -> list[Path]:
        return sorted(p for p in (self.state / "cache").iterdir() if p.is_dir())

    def library(self) -> Path:
        (entry,) = self.entries()
        name = json.loads((entry / "monitor.json").read_text())["library"]
        return entry / name


@pytest.fixture(scope="module")
def cold(tmp_path_factory: pytest.TempPathFactory) -> Site:
    """The first check, cold, once for the module: it builds and fills the cache."""
    s = Site(tmp_path_factory.mktemp("cold"))
    r = s.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert s.compiles() > 0  # cold: built
    return s


@pytest.fixture
def site(cold: Site, tmp_path: Path) -> Site:
    """A site after its first check: a copy of ``cold``'s state (modes kept), with the
    same compiler, so the cache's key is the same."""
    s = Site(tmp_path, cc=cold.cc)
    s.state.rmdir()
    shutil.copytree(cold.state, s.state, symlinks=True)
    return s


def test_a_second_check_compiles_nothing_and_reports_the_stored_findings(site: Site) -> None:
    (entry,) = site.entries()
    findings = entry / "findings.json"
    doc = json.loads(findings.read_text())
    assert "consistency:" in doc["report"]
    # Change the stored report (and its digest): the second check must print it,
    # which it can only do if it took the findings from the cache.
    doc["report"] = doc["report"].replace("consistency:", "consistency (from the cache):")
    data = json.dumps(doc).encode()
    findings.write_bytes(data)
    (entry / "findings.json.sha256").write_text(hashlib.sha256(data).hexdigest())
    r = site.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert "consistency (from the cache):" in r.stdout
    assert "monitor compiled and loaded" in r.stdout
    assert site.compiles() == 0
    assert site.entries() == [entry]


def test_a_changed_config_is_a_miss(site: Site) -> None:
    with site.config.open("a") as f:
        f.write("# an edit that changes nothing but the file\n")
    r = site.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert site.compiles() > 0
    assert len(site.entries()) == 2


def test_a_changed_requirement_changes_the_c_and_is_a_miss(site: Site) -> None:
    text = site.config.read_text()
    changed = text.replace("classifier=1 xor classifier=2", "classifier=2 xor classifier=1", 1)
    assert changed != text
    site.config.write_text(changed)
    r = site.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert site.compiles() > 0
    assert len(site.entries()) == 2


def test_another_compiler_version_is_a_miss(site: Site) -> None:
    site.cc_version = "wrapped cc 2"  # the same compiler's path, another --version
    r = site.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert site.compiles() > 0
    assert len(site.entries()) == 2


@pytest.mark.parametrize("part", ["cffi", "python"])
def test_cffi_and_python_abi_are_in_the_key(
    part: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # No second cffi or Python on this machine: the key is computed in-process
    # with the one component swapped, everything else real.
    from supervisor.pipeline import project_for
    from supervisor.validation import open_cache, startup_key

    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path))
    project = project_for(SROBOT)
    _, before = startup_key(project, None, open_cache())
    if part == "cffi":
        from importlib import metadata

        real = metadata.version
        monkeypatch.setattr(
            metadata, "version", lambda name: "0.0-other" if name == "cffi" else real(name)
        )
    else:
        monkeypatch.setattr(sys.implementation, "cache_tag", "cpython-0", raising=False)
    _, after = startup_key(project, None, open_cache())
    assert before is not None and after is not None and before != after


def test_a_damaged_library_is_rebuilt(site: Site) -> None:
    lib = site.library()
    lib.write_bytes(lib.read_bytes()[:100])  # a truncated file, digest unchanged
    r = site.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert "damaged; rebuilt" in r.stderr
    assert site.compiles() > 0
    r = site.check()  # and the rebuilt entry is good again
    assert r.returncode == 0 and site.compiles() == 0, r.stderr
    assert "damaged" not in r.stderr


def test_a_library_without_its_digest_is_not_taken_for_good(site: Site) -> None:
    # What a start killed between the library and its digest leaves.
    lib = site.library()
    lib.with_name(lib.name + ".sha256").unlink()
    lib.write_bytes(b"half a library")
    r = site.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert site.compiles() > 0


def test_damaged_findings_are_analysed_again(site: Site) -> None:
    (entry,) = site.entries()
    (entry / "findings.json").write_text('{"report": ')
    r = site.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert "damaged; rebuilt" in r.stderr
    assert "consistency:" in r.stdout
    assert json.loads((entry / "findings.json").read_text())["report"]


def test_a_library_others_can_write_is_refused(site: Site) -> None:
    lib = site.library()
    lib.chmod(0o620)
    before = lib.read_bytes()
    r = site.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert "is not this user's own; not used" in r.stderr
    assert site.compiles() > 0
    assert lib.read_bytes() == before  # refused, not taken over


@pytest.mark.skipif(os.geteuid() != 0, reason="giving a file to another user needs root")
def test_an_entry_of_another_user_is_refused(site: Site) -> None:
    (entry,) = site.entries()
    os.chown(entry, 65534, 65534)
    r = site.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert "not this user's own" in r.stderr
    assert site.compiles() > 0


def test_a_cache_directory_others_can_write_is_not_used(site: Site) -> None:
    cache = site.state / "cache"
    cache.chmod(cache.stat().st_mode | stat.S_IWOTH)
    r = site.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert "not used" in r.stderr
    assert site.compiles() > 0


def test_without_a_state_directory_nothing_is_cached(tmp_path: Path) -> None:
    s = Site(tmp_path)
    env = {k: v for k, v in os.environ.items() if k not in ("STATE_DIRECTORY",)}
    env["CC"] = str(s.cc)
    r = subprocess.run(
        [sys.executable, "-m", "supervisor", "check", str(s.config)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert s.compiles() > 0
    assert not (s.state / "cache").exists()


def test_the_parsers_tables_are_kept_and_damaged_ones_rebuilt(site: Site) -> None:
    tables = sorted((site.state / "cache").glob("lark-*.tables"))
    assert len(tables) == 2  # FRETISH and FRET's formula text
    for t in tables:
        t.write_bytes(t.read_bytes()[:100])
    r = site.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert r.stderr.strip() == "", r.stderr  # lark checks them and builds them again
    assert all(t.stat().st_size > 1000 for t in tables)


def test_parser_tables_others_can_write_are_not_loaded(site: Site) -> None:
    (table, *_) = sorted((site.state / "cache").glob("lark-*.tables"))
    table.write_bytes(b"not lark's")
    table.chmod(0o666)
    r = site.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert table.read_bytes() == b"not lark's"  # neither read nor replaced


def test_the_analyses_resource_limit_is_in_the_key(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # z3's resource count decides which findings a budgeted analysis reaches: cached
    # findings of one limit must not stand for another (the same file bytes can mean
    # another limit when the default changes, so the key takes the value itself).
    from dataclasses import replace

    from supervisor.pipeline import project_for
    from supervisor.validation import open_cache, startup_key

    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path))
    project = project_for(SROBOT)
    _, before = startup_key(project, None, open_cache())
    _, again = startup_key(project, None, open_cache())
    analysis = project.config.analysis
    object.__setattr__(project.config, "analysis", replace(analysis, rlimit=analysis.rlimit + 1))
    _, after = startup_key(project, None, open_cache())
    assert before is not None and before == again and after is not None and before != after


# ------------------------------------------------------------------ pruning


def _aged_copies(site: Site, n: int, age_s: float, step_s: float = 60) -> list[Path]:
    """``n`` more entries (copies of the site's one under other keys), last used
    ``age_s`` seconds ago and more, ``step_s`` apart, youngest first."""
    (entry,) = site.entries()
    now = time.time()
    copies = []
    for i in range(n):
        copy = entry.with_name(hashlib.sha256(f"aged {i}".encode()).hexdigest())
        shutil.copytree(entry, copy)
        t = now - age_s - step_s * i
        os.utime(copy, (t, t))
        copies.append(copy)
    return copies


def _edit(site: Site, what: str) -> None:
    """A new key for the next check: the config file's bytes are in it."""
    with site.config.open("a") as f:
        f.write(f"# {what}\n")


def test_a_new_entry_prunes_the_least_recently_used_beyond_keep(site: Site) -> None:
    """A daily edit adds an entry a day: the cache keeps the KEEP most recently used
    (the new one and the first check's among them) and removes the rest."""
    (first,) = site.entries()
    os.utime(first)  # used by the first check, just now
    aged = _aged_copies(site, 10, age_s=2 * cache.GRACE_S)
    _edit(site, "the next day's config")
    r = site.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert r.stderr.strip() == "", r.stderr
    (new,) = set(site.entries()) - {first, *aged}
    assert set(site.entries()) == {new, first, *aged[: cache.KEEP - 2]}
    # the new entry is whole: a second check takes everything from it
    assert site.compiles() > 0
    r = site.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert site.compiles() == 0
    assert not [p.name for p in (site.state / "cache").iterdir() if p.name.startswith(".")]


def test_entries_used_within_the_grace_age_are_not_pruned(site: Site) -> None:
    """Another process (a concurrent test, replay beside run) may be about to load
    an entry it looked at a moment ago: however many there are, none goes."""
    (first,) = site.entries()
    os.utime(first)
    recent = _aged_copies(site, cache.KEEP + 2, age_s=60, step_s=1)
    _edit(site, "an edit while the others are in use")
    r = site.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert len(site.entries()) == cache.KEEP + 4
    assert {first, *recent} < set(site.entries())


def test_an_entry_another_process_holds_is_not_pruned_until_it_lets_go(site: Site) -> None:
    """The entry of a daemon's config stays while the daemon runs, however long ago
    it was read: the holder is a real process that read it through the cache
    (as ``run`` does) and keeps it until it ends."""
    (first,) = site.entries()
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys; from pathlib import Path; from supervisor.cache import Cache\n"
            "c = Cache(Path(sys.argv[1]))\n"
            "assert c.get(sys.argv[2], 'findings.json') is not None\n"
            "print('held', flush=True); sys.stdin.read()",
            str(site.state / "cache"),
            first.name,
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        # It was read weeks ago, and more than KEEP configs came after it.
        aged = _aged_copies(site, cache.KEEP + 2, age_s=2 * cache.GRACE_S)
        weeks = time.time() - 30 * 86400
        os.utime(first, (weeks, weeks))
        _edit(site, "a new config while the daemon runs the old one")
        r = site.check()
        assert r.returncode == 0, r.stdout + r.stderr
        (new,) = set(site.entries()) - {first, *aged}
        assert set(site.entries()) == {new, first, *aged[: cache.KEEP - 1]}
    finally:
        assert holder.stdin is not None
        holder.stdin.close()
        holder.wait(timeout=60)
    assert holder.returncode == 0
    # Let go (the daemon stopped): the next new entry prunes it.
    os.utime(first, (weeks, weeks))
    _edit(site, "and one more")
    r = site.check()
    assert r.returncode == 0, r.stdout + r.stderr
    assert first not in site.entries()
    assert len(site.entries()) == cache.KEEP


RACER = """
import hashlib, sys, time
from pathlib import Path
from supervisor import cache
# Everything not held is pruned at once: the race at its tightest.
cache.KEEP, cache.GRACE_S = 0, 0.0
root, key, role, stop = Path(sys.argv[1]), sys.argv[2], sys.argv[3], Path(sys.argv[4])
data = b"monitor " * 20_000
want = hashlib.sha256(data).hexdigest()
count, end = 0, time.monotonic() + 120
while time.monotonic() < end:
    if role == "writer" and stop.exists() or role != "writer" and count >= 30:
        break
    c = cache.Cache(root)
    if role == "reader":
        p = c.get(key, "item")
        if p is not None:  # whole and readable, never pruned under the reader
            assert hashlib.sha256(p.read_bytes()).hexdigest() == want
            count += 1
    elif role == "pruner":
        count += len(c.prune())
    else:
        c.put(key, "item", data)
    c.close()
print(role, count, flush=True)
"""


def test_a_reader_never_loses_an_entry_to_a_concurrent_pruner(tmp_path: Path) -> None:
    """Real processes sharing one cache, as xdist workers share the suite's
    ``XDG_CACHE_HOME`` and ExecStartPre's ``check`` shares ``run``'s: a writer makes
    the entry again and again, a pruner removes it whenever nobody holds it, and
    readers read it.  A reader sees the whole entry or a miss, never a file
    removed under it (FileNotFoundError) or half an entry."""
    looping, counted = _race(tmp_path, RACER, ["writer"], ["pruner", "reader", "reader"])
    ((code, _, err),) = looping
    assert code == 0, err
    for code, out, err in counted:
        assert code == 0 and "Traceback" not in err, err
        role, count = out.split()
        assert int(count) >= 30, out  # the race was run: entries read and pruned


def _race(
    tmp_path: Path, script: str, looping: list[str], counting: list[str]
) -> tuple[list[tuple[int, str, str]], list[tuple[int, str, str]]]:
    """Processes running ``script`` (argv: cache root, key, role, stop file) on one
    cache: the ``counting`` roles run until they have counted enough, then the
    ``looping`` ones are told to stop; each one's exit code, stdout and stderr."""
    root = tmp_path / "cache"
    root.mkdir(mode=0o700)
    stop = tmp_path / "stop"
    key = hashlib.sha256(script.encode()).hexdigest()

    def start(role: str) -> subprocess.Popen[str]:
        argv = [sys.executable, "-c", script, str(root), key, role, str(stop)]
        return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    loops = [start(r) for r in looping]
    counts = [start(r) for r in counting]
    try:
        counted = [p.communicate(timeout=180) for p in counts]
    finally:
        stop.touch()
        looped = [p.communicate(timeout=60) for p in loops]
    return (
        [(p.returncode, o, e) for p, (o, e) in zip(loops, looped, strict=True)],
        [(p.returncode, o, e) for p, (o, e) in zip(counts, counted, strict=True)],
    )


PUTTER = """
import hashlib, sys, time
from pathlib import Path
from supervisor import cache
root, key, role, stop = Path(sys.argv[1]), sys.argv[2], sys.argv[3], Path(sys.argv[4])
# Two builders of one key whose bytes differ, as two gcc runs in two build directories
data = {"a": b"monitor a " * 20_000, "b": b"monitor b " * 20_000}
wants = {hashlib.sha256(d).hexdigest() for d in data.values()}
count, end = 0, time.monotonic() + 120
while time.monotonic() < end:
    if role in data and stop.exists() or role == "reader" and count >= 300:
        break
    c = cache.Cache(root)
    if role == "reader":
        p = c.get(key, "item")
        if p is not None:
            assert hashlib.sha256(p.read_bytes()).hexdigest() in wants
            count += 1
    else:
        c.put(key, "item", data[role])
    c.close()
print(role, count, flush=True)
"""


def test_two_builders_of_one_entry_never_make_a_reader_call_it_damaged(tmp_path: Path) -> None:
    """Two processes building the same entry at once (two ``fleet replay`` workers
    compiling one config into a cold cache) whose bytes differ: a reader between one's
    item and its digest would see the other's digest.  It sees either whole item,
    never a "damaged" one that it then removes from under both."""
    builders, readers = _race(tmp_path, PUTTER, ["a", "b"], ["reader", "reader"])
    for code, _, err in builders + readers:
        assert code == 0 and "Traceback" not in err, err
        assert "damaged" not in err, err
    for _, out, _ in readers:
        assert int(out.split()[1]) >= 300, out


def test_an_item_whose_lock_cannot_be_taken_is_still_read(tmp_path: Path) -> None:
    """A checker that cannot make or lock the item's lock file (read-only media, a full
    disk, a filesystem without locks; here the name is taken by a directory) reads
    the item as before items had locks: its digest still guards it."""
    root = tmp_path / "cache"
    root.mkdir(mode=0o700)
    key = hashlib.sha256(b"no lock").hexdigest()
    c = cache.Cache(root)
    path = c.put(key, "item", b"monitor")
    c.close()
    assert path is not None
    (root / key / "item.lock").unlink()
    (root / key / "item.lock").mkdir()
    c = cache.Cache(root)
    try:
        assert c.read(key, "item") == b"monitor"
    finally:
        c.close()
