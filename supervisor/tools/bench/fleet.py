"""The fleet bench: ``python -m supervisor.tools.bench.fleet``.

An archive of generated rosbag2 bags (``--bags`` of ``--robots`` simulated robots, the
bench's config, MCAP and sqlite3, some with violations, some zstd-compressed per file,
some damaged) replayed by ``fleet replay`` as a user runs it (the real CLI, a child
process each run): ``--jobs 1``, ``--jobs 2`` and ``--engine ray`` on a local cluster of
2 CPUs.  Per run: wall time, messages per second, the peak RSS of each worker (VmHWM
from /proc), and the load average.  Then a run killed halfway and resumed: how many
bags the resumed run read again that the killed one had finished (the goal: none).
Last, one bag of each kind timed in this process part by part (hashing, reading and
decoding, stepping, the Arrow table, writing), as the per-core figure for a fleet on
paper (docs/BENCHMARKS.md, "Fleet").

Prints numbers with their goals beside them and asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from supervisor import data
from supervisor.tools.bench.plan import Plan
from supervisor.tools.bench.replay import violating_state, write_rounds

GOALS = {
    "speedup": 1.8,  # --jobs 2 against --jobs 1
    "ray_within": 0.15,  # Ray's wall time against the pool's, on one machine
    "worker_mb": 300,  # peak RSS of one worker
}
VIOLATING_EVERY = 5  # every 5th bag has a violating round every VIOLATE_ROUNDS rounds
VIOLATE_ROUNDS = 200
COMPRESSED_EVERY = 7  # every 7th bag compressed per file (zstd), as rosbag2 leaves it
DAMAGED_EVERY = 50  # every 50th bag damaged: its storage file cut off halfway


def make_archive(
    root: Path, config: Path, bags: int, robots: int, messages: int, say: Callable[[str], None]
) -> dict[str, int]:
    """``bags`` bags under ``root/robot-NN/bag-NNNN``; what was made of each kind."""
    import zstandard

    plan = Plan(config)
    violating = violating_state(plan)
    k = len(plan.topics)
    kinds = {"mcap": 0, "sqlite3": 0, "violating": 0, "compressed": 0, "damaged": 0}
    t0 = time.monotonic()
    for i in range(bags):
        storage = "mcap" if i % 2 == 0 else "sqlite3"
        path = root / f"robot-{i % robots:02d}" / f"bag-{i:04d}"
        bad = violating if i % VIOLATING_EVERY == 0 else None
        # each bag one round longer than the one before: no two bags have the same
        # content (a copy would be skipped by its content hash, not replayed)
        write_rounds(path, plan, messages + i * k, storage, violating=bad, every=VIOLATE_ROUNDS)
        kinds[storage] += 1
        kinds["violating"] += bad is not None
        (storage_file,) = [p for p in path.iterdir() if p.suffix in (".mcap", ".db3")]
        if i % DAMAGED_EVERY == DAMAGED_EVERY - 1:
            with storage_file.open("r+b") as f:
                f.truncate(storage_file.stat().st_size // 2)
            kinds["damaged"] += 1
        elif storage == "mcap" and i % COMPRESSED_EVERY == 3:
            _compress(path, storage_file, zstandard.ZstdCompressor())
            kinds["compressed"] += 1
        if i % 100 == 99:
            say(f"fleet: {i + 1}/{bags} bags written ({time.monotonic() - t0:.0f} s)")
    return kinds


def _compress(bag: Path, plain: Path, zstd: Any) -> None:
    """The storage file compressed per file, as rosbag2's zstd file compressor leaves it."""
    packed = plain.with_name(plain.name + ".zstd")
    packed.write_bytes(zstd.compress(plain.read_bytes()))
    plain.unlink()
    meta = bag / "metadata.yaml"
    text = meta.read_text().replace(plain.name, packed.name)
    text = text.replace("compression_format: ''", "compression_format: zstd")
    meta.write_text(text.replace("compression_mode: ''", "compression_mode: FILE"))


# --- the runs -------------------------------------------------------------------


def _children(pid: int) -> dict[int, list[int]]:
    out: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue  # self, thread-self and the kernel's files
        try:
            ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue  # not a process, or one that has just exited
        out.setdefault(ppid, []).append(int(d.name))
    return out


def _workers(pid: int) -> dict[int, int]:
    """The run's worker processes (a pool's, forked by its fork server; Ray's ``ray::``
    task workers) below ``pid``, each with its peak RSS so far in kB (VmHWM)."""
    children = _children(pid)
    todo: list[tuple[int, bytes]] = [(pid, b"")]
    out: dict[int, int] = {}
    while todo:
        parent, parent_cmd = todo.pop()
        for c in children.get(parent, []):
            try:
                cmd = Path(f"/proc/{c}/cmdline").read_bytes()
                todo.append((c, cmd))
                pool = b"forkserver" in cmd and b"forkserver" in parent_cmd  # not the server
                if not (cmd.startswith(b"ray::") or pool):
                    continue
                status = Path(f"/proc/{c}/status").read_text()
            except OSError:
                continue
            for line in status.splitlines():
                if line.startswith("VmHWM:"):
                    out[c] = int(line.split()[1])
    return out


def _children_cpu() -> float:
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _load() -> float:
    return float(Path("/proc/loadavg").read_text().split()[0])


def run_fleet(
    config: Path, archive: Path, dataset: Path, args: list[str], *, stop_after: int | None = None
) -> dict[str, Any]:
    """``fleet replay`` as a child, its workers' peak RSS sampled every 0.1 s.
    ``stop_after``: killed (SIGKILL, the whole process group) once that many bags are
    finished in the dataset."""
    from supervisor import children

    argv = [sys.executable, "-m", "supervisor", "fleet", "replay", str(config), str(archive)]
    argv += ["-o", str(dataset), *args]
    load = _load()
    cpu0 = _children_cpu()
    t0 = time.monotonic()
    proc = children.start(argv, env=children.child_env(), stdout=-1, stderr=-1)
    peaks: dict[int, int] = {}
    # workers alive at once: a pool started for the configs' check and replaced for
    # the tasks (a resume's finished bags differ) shows more processes over the run
    most = 0
    killed = False
    # the sampling period; finer when a kill waits for the bags finished: a small
    # archive's second half can take less than 0.1 s
    period = 0.1 if stop_after is None else 0.005
    while True:
        try:
            proc.wait(timeout=period)
            break
        except subprocess.TimeoutExpired:  # still running
            alive = _workers(proc.pid)
            most = max(most, len(alive))
            for pid, kb in alive.items():
                peaks[pid] = max(peaks.get(pid, 0), kb)
            if stop_after is not None and _finished(dataset) >= stop_after:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
                killed = True
                break
    wall = time.monotonic() - t0
    # the CPU of the run's processes that have been waited for: the command and its
    # pool (Ray's raylet waits its own workers; its daemons are counted too)
    cpu = _children_cpu() - cpu0
    out = proc.stdout.read().decode() if proc.stdout else ""
    err = proc.stderr.read().decode() if proc.stderr else ""
    summary = next((ln for ln in out.splitlines() if ln.startswith("fleet replay:")), "")
    messages = _number(summary, r"([\d,]+) messages in")
    return {
        "args": " ".join(args),
        "wall_s": wall,
        "messages": messages,
        "rate": messages / wall if wall > 0 else 0.0,
        "cpu_s": cpu,
        "cores_used": cpu / wall if wall > 0 else 0.0,
        "workers": most,
        "peak_worker_mb": max(peaks.values(), default=0) / 1024,
        "load": load,
        "killed": killed,
        "exit": proc.returncode,
        "summary": summary,
        "stderr": err.strip()[-500:],
    }


def _number(text: str, pattern: str) -> int:
    import re

    m = re.search(pattern, text)
    return int(m.group(1).replace(",", "")) if m else 0


def _finished(dataset: Path) -> int:
    d = dataset / "bags"
    try:
        return sum(1 for p in d.iterdir() if p.suffix == ".parquet")
    except OSError:
        return 0


def _finished_rows(dataset: Path) -> dict[str, int]:
    """bag path -> its row's finished_ts, for every finished bag."""
    import pyarrow.parquet as pq

    out = {}
    for f in (dataset / "bags").glob("*.parquet"):
        t = pq.read_table(f)
        stamps = t.column("finished_ts").cast("int64").to_pylist()
        out.update(zip(t.column("bag").to_pylist(), stamps, strict=True))
    return out


def resume_after_kill(config: Path, archive: Path, dataset: Path, bags: int) -> dict[str, Any]:
    """A ``--jobs 2`` run killed halfway, then resumed: the bags finished before the
    kill that the resumed run wrote again (read again) should be none."""
    killed = run_fleet(config, archive, dataset, ["--jobs", "2"], stop_after=bags // 2)
    before = _finished_rows(dataset)
    resumed = run_fleet(config, archive, dataset, ["--jobs", "2"])
    after = _finished_rows(dataset)
    again = sum(1 for bag, ts in before.items() if after.get(bag) != ts)
    return {
        "finished_at_kill": len(before),
        "read_again": again,
        "resumed": resumed,
        "killed": killed,
        "all_finished": len(after),
    }


def split(config: Path, bags: list[Path], where: Path) -> dict[str, Any]:
    """Where one task's CPU goes, bag after bag in this process (the config compiled
    once, as a worker has it): hashing the bag's bytes (reading), reading and
    decoding its messages into columns, the rest of the task (the session, stepping
    the monitor, the violations' Arrow table), and the write of the result into the
    dataset (a pool's worker's, Ray's parent's).  CPU time (``time.process_time``), not wall: on a loaded
    machine the wall time is the other processes' as much as ours; the writes' fsync
    waits are not CPU and are left out."""
    from monitors.errors import UserError
    from supervisor.tools.fleet.archive import content_hash, fingerprint
    from supervisor.tools.fleet.dataset import Dataset
    from supervisor.tools.fleet.task import BagTask, _compiled, run_task
    from supervisor.tools.replay.sources import open_recordings

    prepared = _compiled(str(config))
    cfg = prepared.project.config
    dataset = Dataset(where)
    parts = {"hash": 0.0, "read_decode": 0.0, "task": 0.0, "write": 0.0}
    messages = n = 0
    for bag in bags:
        # one untimed read first: the task reads with the worker's warm caches (its
        # type store kept per definitions), so the timed read must too, or the
        # stepping (task minus reading) comes out short, even below zero
        try:
            for _batch in open_recordings([bag], cfg, None).batches():
                pass
        except UserError:
            continue  # a damaged bag: its time is not a task's usual
        t0 = time.process_time()
        content_hash(bag)
        t1 = time.process_time()
        try:
            for _batch in open_recordings([bag], cfg, None).batches():
                pass
        except UserError:
            continue  # a damaged bag: its time is not a task's usual
        t2 = time.process_time()
        result = run_task(BagTask(str(bag), "r", str(config), cfg.sha256))
        t3 = time.process_time()
        dataset.write(result, "r", fingerprint(bag)[1])
        t4 = time.process_time()
        parts["hash"] += t1 - t0
        parts["read_decode"] += t2 - t1
        parts["task"] += t3 - t2
        parts["write"] += t4 - t3
        messages += result.messages
        n += 1
    # the task reads and decodes the bag again itself: the rest is session and stepping
    step = parts["task"] - parts["hash"] - parts["read_decode"]
    per_msg = {k: v / messages * 1e9 if messages else 0.0 for k, v in parts.items()}
    per_msg["step"] = step / messages * 1e9 if messages else 0.0
    return {"bags": n, "messages": messages, "seconds": parts, "ns_per_message": per_msg}


# --- the command ------------------------------------------------------------------


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m supervisor.tools.bench.fleet",
        description="fleet replay over a generated archive: --jobs 1, --jobs 2, Ray on a "
        "local 2-CPU cluster, resume after a kill, and one task's time part by part",
    )
    p.add_argument("--config", default=None, help="default: the sRobot example config")
    p.add_argument("--bags", type=int, default=1000, help="bags in the archive (default 1000)")
    p.add_argument("--robots", type=int, default=10, help="simulated robots (default 10)")
    p.add_argument(
        "--messages", type=int, default=4000, help="messages per bag, about (default 4000)"
    )
    p.add_argument(
        "--split-messages",
        type=int,
        default=1_000_000,
        help="messages of the large bags timed part by part (default 1000000)",
    )
    p.add_argument("--skip-ray", action="store_true", help="leave out the Ray run")
    p.add_argument(
        "--split-only", action="store_true", help="only the part-by-part times of one task"
    )
    p.add_argument("--tmp", default=None, help="where the archive is written (default: TMPDIR)")
    p.add_argument("--json", default=None, metavar="FILE", help="also write the numbers as JSON")
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    if not (1 <= args.bags <= 100_000 and 1 <= args.robots <= args.bags):
        parser().error("--bags from 1 to 100000, --robots from 1 to --bags")
    config = Path(args.config) if args.config else data.example("srobot.yaml")

    def say(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    tmp = Path(tempfile.mkdtemp(prefix="fleet-bench-", dir=args.tmp))
    try:
        out = _bench(config, tmp, args, say)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(format_results(out))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    return 0


def _bench(config: Path, tmp: Path, args: argparse.Namespace, say: Callable[[str], None]) -> dict:
    archive = tmp / "archive"
    t0 = time.monotonic()
    kinds = make_archive(archive, config, args.bags, args.robots, args.messages, say)
    out: dict[str, Any] = {"bags": args.bags, "robots": args.robots, "kinds": kinds}
    out["generate_s"] = time.monotonic() - t0
    out["cpus"] = os.cpu_count()
    # the config's monitor built once before any timed run (the runs find it cached)
    if not args.split_only:
        run_fleet(config, archive, tmp / "warm", ["--jobs", "1"])
        shutil.rmtree(tmp / "warm", ignore_errors=True)
    runs = [] if args.split_only else [["--jobs", "1"], ["--jobs", "2"]]
    if not args.skip_ray and not args.split_only:
        runs.append(["--jobs", "2", "--engine", "ray"])
    out["runs"] = []
    for i, extra in enumerate(runs):
        say(f"fleet: fleet replay {' '.join(extra)}")
        out["runs"].append(run_fleet(config, archive, tmp / f"ds{i}", extra))
    if not args.split_only:
        say("fleet: --jobs 2 killed halfway, then resumed")
        out["resume"] = resume_after_kill(config, archive, tmp / "ds-resume", args.bags)
    say("fleet: one task's time part by part")
    sample = sorted(archive.glob("*/*"))[:: max(1, args.bags // 100)]
    out["split"] = split(config, sample, tmp / "ds-split")
    # and in bags as a robot records them (minutes each): the per-bag costs fade
    plan = Plan(config)
    for storage in ("mcap", "sqlite3"):
        say(f"fleet: a {args.split_messages:,}-message {storage} bag part by part")
        big = tmp / "big" / storage
        write_rounds(big, plan, args.split_messages, storage, violating=violating_state(plan))
        out[f"split_{storage}"] = split(config, [big], tmp / f"ds-split-{storage}")
    return out


def format_results(out: dict[str, Any]) -> str:
    k = out["kinds"]
    lines = [
        f"Fleet: {out['bags']:,} bags of {out['robots']} robots ({k['mcap']} MCAP, "
        f"{k['sqlite3']} sqlite3; {k['violating']} with violations, {k['compressed']} "
        f"zstd-compressed, {k['damaged']} damaged), written in {out['generate_s']:.0f} s; "
        f"{out['cpus']} CPUs",
        "",
        "| run | wall s | messages/s | CPU s | cores used | workers | peak RSS per worker "
        "| load (1 min) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in out["runs"]:
        lines.append(
            f"| {r['args']} | {r['wall_s']:.1f} | {r['rate']:,.0f} | {r['cpu_s']:.1f} | "
            f"{r['cores_used']:.2f} | {r['workers']} | {r['peak_worker_mb']:.0f} MB | "
            f"{r['load']:.2f} |"
        )
    by = {r["args"]: r for r in out["runs"]}
    one, two = by.get("--jobs 1"), by.get("--jobs 2")
    ray = by.get("--jobs 2 --engine ray")
    lines.append("")
    if one and two:
        lines.append(
            f"speed-up from --jobs 1 to 2: {one['wall_s'] / two['wall_s']:.2f}x "
            f"(goal >= {GOALS['speedup']}x)"
        )
    if two and ray:
        lines.append(
            f"Ray against the pool: {ray['wall_s'] / two['wall_s'] - 1:+.0%} wall time "
            f"(goal within {GOALS['ray_within']:.0%})"
        )
    peak = max((r["peak_worker_mb"] for r in out["runs"]), default=0)
    lines.append(f"largest worker: {peak:.0f} MB (goal <= {GOALS['worker_mb']} MB)")
    res = out.get("resume")
    if res is not None:
        lines.append(
            f"resume after a kill: {res['finished_at_kill']} bags finished before the kill, "
            f"{res['read_again']} of them read again (goal 0); {res['all_finished']} "
            f"finished after the resumed run ({res['resumed']['summary']})"
        )
    names = [("split", "the archive's bags")]
    names += [
        (f"split_{k}", f"one large {k} bag") for k in ("mcap", "sqlite3") if f"split_{k}" in out
    ]
    lines += [
        "",
        "one task part by part, CPU ns per message (the config compiled once):",
        "| part | "
        + " | ".join(f"{label} ({out[k]['messages']:,} msgs)" for k, label in names)
        + " |",
        "|---|" + "---:|" * len(names),
    ]
    for part, label in (
        ("hash", "reading (the bag's bytes hashed)"),
        ("read_decode", "reading and decoding into columns"),
        ("step", "stepping (session, monitor, violations table)"),
        ("write", "writing (the bag's Parquet files, fsynced)"),
        ("task", "whole task in the worker"),
    ):
        cells = " | ".join(f"{out[k]['ns_per_message'][part]:.0f}" for k, _ in names)
        lines.append(f"| {label} | {cells} |")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
