"""Count the daemon's stops by outcome: exit status, shared-memory ports, and how long
its node stayed in another node's graph (docs/reference/faults.md, "Stop").

    python tests/support/stop_loop.py N --mode bench|kill|flood [--env K=V ...]

``bench``: the latency daemon of ``safety-supervisor bench`` and its driver; the
driver is SIGKILLed after its trials, then the daemon SIGTERMed (where Fast DDS's
shared-memory crash was seen).  ``kill``: two robot nodes flood the daemon's inputs
and are SIGKILLed, then the daemon SIGTERMed.  ``flood``: the daemon is SIGTERMed
under the flood (the goodbye's loss rate).  ``--env FASTDDS_BUILTIN_TRANSPORTS=DEFAULT``
gives the daemon Fast DDS's own transports (shared memory under LOCALHOST), as before
supervisor/daemon/transport.py.  One JSON line per stop, then a summary.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

GONE_S = 10.0  # as tests/system/test_daemon_stop.py: longer is a lost goodbye
GHOST_S = 40.0


def shm_ports(pid: int) -> int:
    """How many Fast DDS shared-memory ports the process has mapped."""
    maps = Path(f"/proc/{pid}/maps").read_text().splitlines()
    return len({line.split()[-1] for line in maps if "/dev/shm/fastrtps_port" in line})


def bench_loop(n: int, env: dict[str, str], trials: int) -> list[dict[str, Any]]:
    from supervisor import data
    from supervisor.tools.bench.plan import LATENCY_REQUIREMENT, SROBOT_VIOLATING, Plan
    from supervisor.tools.bench.session import session

    os.environ.update(env)  # the bench's children inherit it
    plan = Plan(data.example("srobot.yaml"))
    halt_topic, halt_msg = plan.halt
    args = ["--spec", json.dumps(plan.topics), "--trigger", plan.trigger]
    args += ["--halt-topic", halt_topic, "--halt-msg", halt_msg]
    args += ["--nominal", json.dumps(plan.nominal), "--violating", json.dumps(SROBOT_VIOLATING)]
    args += ["--trials", str(trials), "--warmup", "2"]
    out: list[dict[str, Any]] = []
    with session(None) as s:
        for i in range(n):
            work = s.tmp / f"c{i}"
            work.mkdir()
            config = plan.write_config(work / "config.yaml", work / "v.jsonl", latency=True)
            d = s.daemon(config, work)
            try:
                d.wait_ready(90)
                ports = shm_ports(d.pid)
                log_args = ["--log", str(d.log), "--requirement", LATENCY_REQUIREMENT]
                driver = s.child("driver", "driver", *args, *log_args, workdir=work)
                try:
                    driver.wait_event("result", 120, (d, driver))
                finally:
                    driver.kill()
                d.terminate()
                d.wait(10)
                out.append({"i": i, "rc": d.returncode, "shm_ports": ports})
            finally:
                d.kill()
            print(json.dumps(out[-1]), flush=True)
    return out


def _stepping(d: Any) -> bool:
    """The daemon's STATUS= says it steps on every input."""
    note = d.recv(0.2)
    return bool(note and "ticks=" in note and "waiting_for=" not in note)


def ros_loop(n: int, env: dict[str, str], kill_peers: bool) -> list[dict[str, Any]]:
    import rosutil
    from rosutil import Daemon, ros_node, variant, wait_until

    from supervisor.tools.children import Child, ros_env

    name = f"safety_supervisor_loop_{os.getpid()}"
    tmp = Path(tempfile.mkdtemp(prefix="stop-loop-"))  # kept if a stop failed
    # Its own control socket: the default one is per ROS_DOMAIN_ID, which another
    # run on this machine may have drawn too.
    own = f"component: sRobot\ncontrol:\n  socket: {tmp}/control.sock\nros:\n  node_name: {name}"
    config = variant(tmp, ("component: sRobot", own))
    flood = [sys.executable, str(Path(__file__).resolve().parent / "flood.py")]
    out: list[dict[str, Any]] = []
    with ros_node("stop_loop_observer") as observer:

        def daemons() -> int:
            return sum(1 for m, _ in observer.get_node_names_and_namespaces() if m == name)

        for i in range(n):
            work = tmp / f"c{i}"
            work.mkdir()
            d = Daemon(work, config, env=env)
            peers = [
                Child(
                    f"flood{k}",
                    flood,
                    env=ros_env(rosutil.DOMAIN_ID),
                    cwd=rosutil.ROOT,
                    stderr=work / f"flood{k}.stderr",
                )
                for k in range(2 if kill_peers else 1)
            ]
            try:
                d.wait_notify("READY=1", timeout=90)
                wait_until("the daemon's node", lambda: daemons() == 1, 60)

                wait_until("the daemon to step on the flood", lambda d=d: _stepping(d), 60)
                ports = shm_ports(d.proc.pid)
                if kill_peers:
                    for p in peers:
                        p.kill()
                t0 = time.monotonic()
                d.proc.send_signal(signal.SIGTERM)
                d.proc.wait(timeout=30)
                t_exit = time.monotonic()
                deadline = t_exit + GHOST_S
                while daemons() and time.monotonic() < deadline:
                    time.sleep(0.02)  # polling the graph, as the stop test does
                gone = time.monotonic() - t_exit if not daemons() else None
                out.append(
                    {
                        "i": i,
                        "rc": d.proc.returncode,
                        "shm_ports": ports,
                        "stop_s": round(t_exit - t0, 3),
                        "gone_s": gone,
                    }
                )
            finally:
                for p in peers:
                    p.kill()
                d.close()
            print(json.dumps(out[-1]), flush=True)
    if all(r["rc"] == 0 for r in out):
        shutil.rmtree(tmp, ignore_errors=True)
    else:
        print(f"the failed stops' stderr: {tmp}/c*/daemon.stderr", flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("n", type=int)
    ap.add_argument("--mode", choices=["bench", "kill", "flood"], default="bench")
    ap.add_argument("--env", action="append", default=[], metavar="K=V", help="for the daemon")
    ap.add_argument("--trials", type=int, default=10, help="bench: the driver's trials")
    a = ap.parse_args()
    env = dict(kv.split("=", 1) for kv in a.env)
    if a.mode == "bench":
        out = bench_loop(a.n, env, a.trials)
    else:
        out = ros_loop(a.n, env, a.mode == "kill")
    gone = [r["gone_s"] for r in out if "gone_s" in r]
    summary = {
        "stops": len(out),
        "exit": dict(Counter(r["rc"] for r in out)),
        "shm_ports": dict(Counter(r["shm_ports"] for r in out)),
        "lingering_s": [round(g, 1) for g in gone if g is not None and g > GONE_S],
        "ghosts": sum(1 for g in gone if g is None),
    }
    print("summary", json.dumps(summary), flush=True)


if __name__ == "__main__":
    main()
