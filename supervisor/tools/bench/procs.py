"""The processes ``safety-supervisor bench`` runs besides the daemon.

``python -m supervisor.tools.bench.procs ROLE --spec JSON ...``; every role talks to
the bench on stdout, one JSON object per line, and stops on SIGTERM:

- ``publisher`` (:mod:`~supervisor.tools.bench.publisher`): publishes ``--rate``
  msg/s over the spec's topics, then relays the daemon's per-input counts;
- ``waitset`` and ``executor`` (:mod:`~supervisor.tools.bench.receivers`): plain
  rclpy subscribers, the throughput experiment's baselines;
- ``echo`` (:mod:`~supervisor.tools.bench.echo`): the latency experiment's bare-DDS
  baseline, halting as the daemon would;
- ``driver`` (:mod:`~supervisor.tools.bench.driver`): the latency experiment's robot.

The bench starts them with :mod:`supervisor.tools.children` (own process group,
SIGTERM should the bench die).
"""

from __future__ import annotations

import argparse
import json
import signal

from supervisor.names import NODE_NAME, RESET_SERVICE
from supervisor.tools.bench.driver import run_driver
from supervisor.tools.bench.echo import run_echo
from supervisor.tools.bench.helper import emit, load_topics, on_term
from supervisor.tools.bench.plan import LATENCY_REQUIREMENT
from supervisor.tools.bench.publisher import run_publisher
from supervisor.tools.bench.receivers import run_executor, run_waitset


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m supervisor.tools.bench.procs")
    sub = p.add_subparsers(dest="role", required=True)
    for role in ("publisher", "waitset", "executor", "echo", "driver"):
        r = sub.add_parser(role)
        r.add_argument("--spec", required=True, help="JSON list of {name, topic, msg, field}")
        r.add_argument("--publisher-node", default="bench_publisher")
        r.add_argument("--match-timeout", type=float, default=60.0)
    pub = sub.choices["publisher"]
    pub.add_argument("--values", required=True, help="JSON {name: value}")
    pub.add_argument("--rate", type=float, required=True)
    pub.add_argument("--seconds", type=float, required=True)
    pub.add_argument("--receivers", type=int, required=True)
    pub.add_argument("--node-name", default="bench_publisher")
    pub.add_argument("--diagnostics", action="store_true")
    pub.add_argument("--daemon-node", default=NODE_NAME)
    pub.add_argument("--burst", type=int, default=0, help="rounds per burst (0: even pacing)")
    pub.add_argument("--scan", default=None, help="JSON: a LaserScan beside (plan.ScanPlan.scan)")
    for role in ("echo", "driver"):
        r = sub.choices[role]
        r.add_argument("--sync-service", default=RESET_SERVICE)
        r.add_argument("--trigger", required=True)
        r.add_argument("--halt-topic", required=True)
        r.add_argument("--halt-msg", default="std_msgs/msg/Bool")
    sub.choices["echo"].add_argument("--when", required=True, help="NAME=INT: violating state")
    drv = sub.choices["driver"]
    drv.add_argument("--nominal", required=True)
    drv.add_argument("--violating", required=True)
    drv.add_argument("--trials", type=int, default=1000)
    drv.add_argument("--warmup", type=int, default=10)
    drv.add_argument("--timeout", type=float, default=1.0)
    drv.add_argument("--log", default=None, help="the daemon's violation log")
    drv.add_argument(
        "--requirement", default=LATENCY_REQUIREMENT, help="whose records --log counts"
    )
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    signal.signal(signal.SIGTERM, on_term)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the bench decides when we stop
    try:
        topics = load_topics(args.spec)
        if args.role == "publisher":
            run_publisher(args, topics, json.loads(args.values))
        elif args.role == "waitset":
            run_waitset(topics, args.publisher_node)
        elif args.role == "executor":
            run_executor(topics, args.publisher_node)
        elif args.role == "echo":
            run_echo(args, topics)
        else:
            run_driver(args, topics)
    except Exception as e:  # noqa: BLE001 - one line for the bench, never a traceback
        emit(event="error", error=f"{args.role}: {type(e).__name__}: {e}")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
