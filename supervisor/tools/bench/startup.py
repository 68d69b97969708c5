"""``bench --startup``: how long the robot waits for its supervisor.

Measured as systemd sees it, over several runs each (min, median, max):

- ``import supervisor.cli`` as ``python -X importtime`` counts it (the module's
  cumulative time, without the interpreter's own start): what every command imports
  before it parses its arguments;
- ``safety-supervisor --help``, the lightest command (the imports every command pays);
- ``check CONFIG`` (ExecStartPre) with an empty start-up cache (cold) and with the
  cache a previous check filled (warm);
- ``run CONFIG`` from the process start to ``READY=1`` on a NOTIFY_SOCKET of the
  bench's own (what ``systemctl start`` waits for), cold and warm;
- ``replay`` of a 10-message bag with a one-requirement config of the bench's own,
  from the process start to its exit, with an empty and with a filled user cache
  (``XDG_CACHE_HOME``, supervisor/cache.py ``Cache.open_user``).

Each cold run gets a new, empty ``STATE_DIRECTORY`` (supervisor/cache.py); the warm
runs share one that a first run filled.  docs/BENCHMARKS.md, "Start-up", has the
figures and the goals.
"""

from __future__ import annotations

import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from supervisor import children
from supervisor.tools.bench.errors import BenchError
from supervisor.tools.bench.session import Daemon, session

GOALS_S = {
    "import_cli": 0.15,
    "help": 0.3,
    "run_warm": 1.0,
    "run_cold": 3.0,
    "replay_warm": 1.5,
}
READY_TIMEOUT_S = 120.0


def _cli() -> list[str]:
    """The installed ``safety-supervisor`` script beside this interpreter, as a
    robot runs it; ``python -m supervisor`` where there is none."""
    script = Path(sys.executable).parent / "safety-supervisor"
    return [str(script)] if script.exists() else [sys.executable, "-m", "supervisor"]


def _timed(argv: list[str], env: dict[str, str]) -> float:
    t0 = time.perf_counter()
    # No trampoline: its own Python start would be counted in the figure.
    r = children.run(argv, env=env, timeout=600, parent_death_signal=None)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        last = (r.stderr.strip().splitlines() or r.stdout.strip().splitlines() or ["?"])[-1]
        raise BenchError(f"{' '.join(argv[-2:])} failed (exit {r.returncode}): {last}")
    return dt


def cli_import_seconds(env: dict[str, str]) -> float:
    """``import supervisor.cli``'s cumulative time by ``python -X importtime``."""
    argv = [sys.executable, "-X", "importtime", "-c", "import supervisor.cli"]
    r = children.run(argv, env=env, timeout=600, parent_death_signal=None)
    # stderr lines: "import time: <self us> | <cumulative us> | <indented module>"
    for line in r.stderr.splitlines():
        fields = line.split("|")
        if len(fields) == 3 and fields[2].strip() == "supervisor.cli":
            return int(fields[1]) / 1e6
    last = (r.stderr.strip().splitlines() or ["?"])[-1]
    raise BenchError(f"import supervisor.cli failed (exit {r.returncode}): {last}")


def _summary(samples: list[float]) -> dict[str, Any]:
    return {
        "runs": len(samples),
        "min_s": min(samples),
        "median_s": statistics.median(samples),
        "max_s": max(samples),
        "samples_s": samples,
    }


def run_startup(
    config: Path, runs: int, domain_id: int | None, progress: Callable[[str], None] | None
) -> dict[str, Any]:
    """Every figure of ``bench --startup``; see the module's description."""
    say = progress or (lambda _text: None)
    config = config.resolve()  # the daemon runs in a directory of its own
    cli = _cli()
    out: dict[str, Any] = {"config": str(config), "runs": runs, "goals_s": GOALS_S}
    with session(domain_id) as s:
        # As installed from a wheel, with bytecode (pip compiles it; a venv made with
        # PYTHONDONTWRITEBYTECODE=1 has none and compiles every module at every start).
        env = {k: v for k, v in s.env.items() if k != "PYTHONDONTWRITEBYTECODE"}
        warm_up = {**env, "STATE_DIRECTORY": str(Path(tempfile.mkdtemp(dir=s.tmp)))}
        _timed([*cli, "check", str(config)], warm_up)  # not counted: writes the bytecode

        def state(name: str) -> Path:
            d = Path(tempfile.mkdtemp(prefix=f"{name}-", dir=s.tmp))
            d.chmod(0o700)
            return d

        say(f"import supervisor.cli x{runs}")
        out["import_cli"] = _summary([cli_import_seconds(env) for _ in range(runs)])
        say(f"--help x{runs}")
        out["help"] = _summary([_timed([*cli, "--help"], env) for _ in range(runs)])

        say(f"check cold x{runs}")
        check = [*cli, "check", str(config)]
        cold = [_timed(check, {**env, "STATE_DIRECTORY": str(state("cold"))}) for _ in range(runs)]
        out["check_cold"] = _summary(cold)
        warm_state = state("warm")
        _timed(check, {**env, "STATE_DIRECTORY": str(warm_state)})  # fills the cache
        say(f"check warm x{runs}")
        warm = [_timed(check, {**env, "STATE_DIRECTORY": str(warm_state)}) for _ in range(runs)]
        out["check_warm"] = _summary(warm)

        def to_ready(state_dir: Path, n: int) -> float:
            work = s.tmp / f"run-{state_dir.name}-{n}"
            t0 = time.perf_counter()
            d = Daemon(config, work, {**env, "STATE_DIRECTORY": str(state_dir)})
            s.children.append(d)
            try:
                d.wait_ready(READY_TIMEOUT_S)
                dt = time.perf_counter() - t0
                d.stop_cleanly()
            finally:
                d.kill()
                s.children.remove(d)
            shutil.rmtree(work, ignore_errors=True)
            return dt

        say(f"run to READY=1 cold x{runs}")
        out["run_cold"] = _summary([to_ready(state("run-cold"), n) for n in range(runs)])
        say(f"run to READY=1 warm x{runs}")
        run_state = state("run-warm")
        to_ready(run_state, -1)  # fills the cache
        out["run_warm"] = _summary([to_ready(run_state, n) for n in range(runs)])

        replay = [*cli, "replay", *_tiny_replay(s.tmp / "replay"), "--quiet"]
        say(f"replay of 10 messages cold x{runs}")
        out["replay_cold"] = _summary(
            [_timed(replay, {**env, "XDG_CACHE_HOME": str(state("xdg-cold"))}) for _ in range(runs)]
        )
        say(f"replay of 10 messages warm x{runs}")
        xdg = {**env, "XDG_CACHE_HOME": str(state("xdg-warm"))}
        _timed(replay, xdg)  # fills the cache
        out["replay_warm"] = _summary([_timed(replay, xdg) for _ in range(runs)])
    return out


TINY_CONFIG = """\
component: bench
step: {policy: on_message}
variables:
  speed: {type: double, topic: /speed, msg: std_msgs/msg/Float64}
requirements:
  - id: limit
    text: bench shall always satisfy speed <= 2.0
    on_violation: [note]
mitigations:
  note: {log: {message: too fast}}
"""


def _tiny_replay(directory: Path) -> list[str]:
    """A config and a 10-message MCAP bag in ``directory``: the arguments of replay."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    directory.mkdir()
    config = directory / "tiny.yaml"
    config.write_text(TINY_CONFIG)
    store = get_typestore(Stores.ROS2_JAZZY)
    msgtype = "std_msgs/msg/Float64"
    with Writer(directory / "bag", version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conn = w.add_connection("/speed", msgtype, typestore=store)
        for i in range(10):
            msg = store.types[msgtype](data=0.5 * i)
            w.write(conn, 10**9 + i * 10**8, bytes(store.serialize_cdr(msg, msgtype)))
    return [str(config), str(directory / "bag")]


ROWS = (
    ("import_cli", "import supervisor.cli", "import_cli"),
    ("help", "--help", "help"),
    ("check_cold", "check, empty cache", None),
    ("check_warm", "check, cache filled", None),
    ("run_cold", "run to READY=1, empty cache", "run_cold"),
    ("run_warm", "run to READY=1, cache filled", "run_warm"),
    ("replay_cold", "replay 10 msgs, empty cache", None),
    ("replay_warm", "replay 10 msgs, cache filled", "replay_warm"),
)


def format_startup(results: dict[str, Any]) -> str:
    """The table ``bench --startup`` prints (seconds)."""
    lines = [
        f"start-up: {results['config']}, {results['runs']} runs each (seconds)",
        f"  {'':30} {'min':>6} {'median':>7} {'max':>6}  goal",
    ]
    for key, label, goal in ROWS:
        r = results.get(key)
        if r is None:  # a startup.json written before the figure existed
            continue
        g = results["goals_s"].get(goal) if goal else None
        verdict = "" if g is None else f"<= {g:g} {'met' if r['median_s'] <= g else 'NOT met'}"
        lines.append(
            f"  {label:30} {r['min_s']:6.2f} {r['median_s']:7.2f} {r['max_s']:6.2f}  {verdict}"
        )
    return "\n".join(lines)
