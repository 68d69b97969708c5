"""How the supervisor scales with the number of requirements (``bench --scale``).

For each size N a config of N generated requirements over 50 inputs
(:mod:`~supervisor.tools.bench.scalegen`, seed 1), and:

a. parse + formalize: :func:`supervisor.pipeline.project_for` (``ros=False``: the
   message types are not imported), in this process;
b. ``safety-supervisor check FILE`` as a user runs it (a subprocess, default limits):
   its wall time, exit status, peak memory (``wait4``'s ru_maxrss) and the lines of
   its analysis report (did they run, what was skipped and why);
c. C generation + build + load: :func:`supervisor.pipeline.compile_project`, in this
   process, and d. the shared library's size;
e. the monitor's step: :func:`monitors.backends.throughput.tick_rate` (one cffi call
   per tick, random inputs, the daemon's path): ns per tick and per tick and requirement;
f. the daemon on the config under the throughput experiment's stream (one publisher,
   the offered rate spread over the 50 topics, every value zero, the trigger last:
   one tick per round) with the wait-set baseline beside it: its CPU per message, loss,
   violations, the time from its spawn to READY=1 (it builds its monitor), and its
   memory (VmRSS and VmHWM of /proc/PID/status) once ready and at the end.

The same daemon run on the bench's own config (sRobot by default) gives its memory
for comparison.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from supervisor.children import child_env, start
from supervisor.tools.bench.errors import BenchError
from supervisor.tools.bench.numbers import shown as _f
from supervisor.tools.bench.plan import Plan
from supervisor.tools.bench.scalegen import N_VARIABLES, generate
from supervisor.tools.bench.session import Session
from supervisor.tools.bench.throughput import daemon_summary, throughput

SEED = 1
CHECK_TIMEOUT_S = 1800.0
READY_TIMEOUT_S = 900.0  # the daemon builds its monitor before READY=1
ANALYSIS_PREFIXES = ("analysis:", "  consistency:", "  realizability:", "  findings:", "  skipped:")


def proc_memory(pid: int) -> dict[str, int | None]:
    """VmRSS and VmHWM of ``pid`` in kB (None when gone)."""
    out: dict[str, int | None] = {"rss_kb": None, "hwm_kb": None}
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return out
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            out["rss_kb" if key == "VmRSS" else "hwm_kb"] = int(value.split()[0])
    return out


def fd_count(pid: int) -> int | None:
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None


def run_check(config: Path, timeout: float = CHECK_TIMEOUT_S) -> dict[str, Any]:
    """``safety-supervisor check CONFIG`` in a subprocess: wall time, exit status, peak
    RSS, the analysis report's lines and the last line."""
    argv = [sys.executable, "-m", "supervisor", "check", str(config)]
    t0 = time.perf_counter()
    p = start(
        argv, env=child_env(), cwd=config.parent, stdout=subprocess.PIPE, stderr=subprocess.STDOUT
    )
    timer = threading.Timer(timeout, p.kill)
    timer.start()
    try:
        assert p.stdout is not None
        out = p.stdout.read().decode(errors="replace")
        p.stdout.close()
        # wait4: this child's own rusage (its peak RSS), not the largest of every child
        _, status, usage = os.wait4(p.pid, 0)
    finally:
        timer.cancel()
    wall = time.perf_counter() - t0
    p.returncode = os.waitstatus_to_exitcode(status)
    killed = p.returncode == -9 and wall >= timeout
    lines = out.splitlines()
    analysis = [ln.rstrip() for ln in lines if ln.startswith(ANALYSIS_PREFIXES)]
    return {
        "wall_s": wall,
        "exit": p.returncode,
        "timeout": killed,
        "maxrss_kb": usage.ru_maxrss,
        "analysis": analysis,
        "warnings": sum(1 for ln in lines if ln.startswith("warning")),
        "last": lines[-1] if lines else "",
    }


def _monitor(config: Path, work: Path) -> dict[str, Any]:
    """a, c, d, e: in this process."""
    from monitors.backends.load import load_monitor
    from monitors.backends.throughput import tick_rate
    from supervisor.pipeline import compile_project, project_for

    t0 = time.perf_counter()
    project = project_for(config, ros=False)
    parse_s = time.perf_counter() - t0
    err = project.first_error()
    if err is not None:
        raise BenchError(f"{config}: {err}")
    n_ok = sum(1 for r in project.requirements if r.ok)
    out_dir = work / "build"
    t0 = time.perf_counter()
    manifest = compile_project(project, out_dir)
    compile_s = time.perf_counter() - t0
    lib = out_dir / manifest["library"]
    c_bytes = sum(p.stat().st_size for p in out_dir.glob("*.c"))
    mon = load_monitor(lib, project.spec())
    rate = tick_rate(mon, ticks=20_000, min_seconds=1.0)
    ns = 1e9 / rate
    return {
        "formalized": n_ok,
        "parse_formalize_s": parse_s,
        "compile_s": compile_s,
        "library_bytes": lib.stat().st_size,
        "c_source_bytes": c_bytes,
        "tick_ns": ns,
        "tick_ns_per_requirement": ns / max(1, n_ok),
    }


def daemon_run(
    s: Session, plan: Plan, rate: float, seconds: float, wd_usec: int | None
) -> dict[str, Any]:
    """f: the throughput run with the daemon's memory once ready and at the end."""
    mem: dict[str, Any] = {}
    t0 = time.monotonic()

    def ready(pid: int) -> None:
        mem["pid"] = pid
        mem["ready_s"] = time.monotonic() - t0
        mem["start"] = proc_memory(pid)

    def end() -> None:
        mem["end"] = proc_memory(mem["pid"])

    row = throughput(
        s,
        plan,
        rate,
        seconds,
        False,
        wd_usec=wd_usec,
        on_ready=ready,
        before_stop=end,
        ready_timeout=READY_TIMEOUT_S,
    )
    d = row["receivers"]["daemon"]
    ws = row["receivers"].get("rclpy wait-set") or {}
    return {
        "offered": rate,
        "seconds": row["seconds"],
        "topics": len(plan.topics),
        **daemon_summary(row),
        "cpu_us_per_msg_to_exit": d["cpu_us_per_msg_to_exit"],
        "waitset_cpu_us_per_msg": ws.get("cpu_us_per_msg"),
        "ready_s": mem.get("ready_s"),
        "rss_start_kb": mem.get("start", {}).get("rss_kb"),
        "hwm_start_kb": mem.get("start", {}).get("hwm_kb"),
        "rss_end_kb": mem.get("end", {}).get("rss_kb"),
        "hwm_end_kb": mem.get("end", {}).get("hwm_kb"),
    }


def scale_bench(
    s: Session,
    plan: Plan,
    sizes: list[int],
    rate: float,
    seconds: float,
    say: Callable[[str], None],
    *,
    wd_usec: int | None = None,
    seed: int = SEED,
) -> dict[str, Any]:
    rows = []
    for n in sizes:
        work = s.tmp / f"scale-{n}"
        work.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        gen = generate(n, seed)
        gen_s = time.perf_counter() - t0
        config = gen.write(work / "config.yaml")
        say(f"scale {n}: generated in {gen_s:.1f} s; parse, formalize, compile, step")
        row: dict[str, Any] = {
            "requirements": n,
            "variables": N_VARIABLES,
            "generate_s": gen_s,
            "timings": gen.timings,
            "scopes": gen.scopes,
            "qualifiers": gen.qualifiers,
            **_monitor(config, work),
        }
        say(f"scale {n}: safety-supervisor check (default limits)")
        row["check"] = run_check(config)
        c = row["check"]
        say(
            f"scale {n}: check {_f(c['wall_s'])} s (exit {c['exit']}); daemon at {rate:g} msg/s "
            f"for {seconds:g} s"
        )
        row["daemon"] = daemon_run(s, Plan(config), rate, seconds, wd_usec)
        d = row["daemon"]
        say(
            f"scale {n}: parse {row['parse_formalize_s']:.2f} s, compile {row['compile_s']:.2f} s, "
            f"{row['library_bytes']} bytes, {row['tick_ns']:.0f} ns/tick; daemon "
            f"{_f(d['cpu_us_per_msg'], '.1f')} us/msg, RSS {d['rss_start_kb']} -> "
            f"{d['rss_end_kb']} kB"
        )
        rows.append(row)
    say(f"scale: the daemon on {plan.path.name} at {rate:g} msg/s for {seconds:g} s (its memory)")
    reference = daemon_run(s, plan, rate, seconds, wd_usec)
    return {
        "seed": seed,
        "offered": rate,
        "seconds": seconds,
        "sizes": sizes,
        "rows": rows,
        "reference": {"config": str(plan.path), **reference},
    }
