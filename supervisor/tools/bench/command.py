"""``safety-supervisor bench``: the thesis's overhead and latency experiments.

Prints numbers and asserts nothing (speed goals are benchmarks, not tests).

1. Throughput and overhead (thesis sec. 5.1.1, eq. 1:
   Overhead = (P_standalone - P_monitor) / P_monitor x 100 %, P = messages
   received per second).  Per offered rate, one publisher process spreads the
   rate evenly over the config's input topics (a nominal state that satisfies
   every requirement, the step trigger last in each round); in the same run
   the daemon and a plain rclpy wait-set subscriber (optionally also rclpy's
   default executor) receive the same stream.  The daemon's counts come from
   its ``stop`` record, its drain is watched on ``/diagnostics``.
   With ``--burst N,...`` each rate is run again with a bursty publisher (N rounds
   back to back, then a pause: the same average rate). Every throughput run gives
   the daemon ``WATCHDOG_USEC`` (1 s) and reports the longest gap between its
   ``WATCHDOG=1`` pings during the run, and the messages the daemon counted lost
   (from publication sequence numbers) next to sent - received: they must agree.
2. Latency: the violating message's trigger published -> the halt
   received by another process, over many trials, measured in that one
   process with ``time.monotonic_ns``; first against a bare rclpy echo (the
   DDS round trip alone), then against the daemon, whose violation record is
   fsynced before the halt goes out.  Each trial: the nominal state, the
   violating values, then the trigger alone; before each part the driver
   waits for a handshake on the responder's reset service (served by its
   loop after the messages published before it) and, for the daemon, for the
   reset and mitigation records of the previous trial, so every trial starts
   from an idle responder in a holding state.  The daemon's log adds where
   its time goes (trigger -> violation record, detection -> halt published).
3. Recording overhead (:mod:`~supervisor.tools.bench.recording`): the throughput
   run's daemon at one offered rate without and with ``run --record DIR``.
   The UI load (:mod:`~supervisor.tools.bench.ui`): the same without a UI, with
   ``ui`` and open event streams, and with the UI killed and restarted halfway.
4. Replay throughput (:mod:`~supervisor.tools.bench.replay`): generated bags
   replayed in this process, messages/s per case, and the monitor's ticks/s.
5. With ``--scan`` (:mod:`~supervisor.tools.bench.scan`): a 1,440-reading LaserScan
   at 40 Hz beside the stream, reduced (``reduce: min``) and aged (``age_of``) by the
   daemon: its CPU per message and loss without and with it at ``--scan-rate``, and
   the reduction's own cost per scan, timed in this process.
6. Scaling (:mod:`~supervisor.tools.bench.scale`): generated configs of N
   requirements over 50 inputs (``--scale-sizes``): parse + formalize, ``check``'s wall
   time and what its analyses did, C generation + build, the library's size, the step's
   ns per tick, and the daemon's CPU per message and memory at ``--scale-rate``; the
   daemon's memory on the bench's config beside.
7. Soak (:mod:`~supervisor.tools.bench.soak`): the daemon at ``--soak-rate``
   for ``--soak-seconds``, its RSS and open descriptors sampled: first, last, largest,
   the RSS slope over the second half, and the messages lost.

``--quick`` runs every part short; ``--out DIR`` also writes ``bench.json`` and
``bench.md`` (docs/reference/commands.md#bench).

Every process runs on this machine with localhost-only discovery and a random
ROS_DOMAIN_ID outside the test suite's range; all of them are killed (process
groups, and PR_SET_PDEATHSIG should this process die) on exit, Ctrl-C and errors.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from supervisor import data
from supervisor.tools.bench.errors import BenchError
from supervisor.tools.stopping import sigterm_as_interrupt

DEFAULT_CONFIG = data.example("srobot.yaml")
DEFAULT_RATES = "5000,10000,12500,15000,17500,20000"
# The options left unset, in full and with --quick (every experiment, short: a couple
# of minutes; docs/reference/commands.md#bench).
DEFAULTS: dict[str, dict[str, Any]] = {
    "full": {
        "rates": DEFAULT_RATES,
        "seconds": 5.0,
        "latency_trials": 1000,
        "latency_rounds": 3,
        "record_rates": "20000",
        "ui_rates": "20000",
        # Longer than the throughput runs' 5 s: the kill is halfway, and the restarted
        # UI needs its start (importing rclpy), the clients' retry (1 s) and DDS
        # discovery of the daemon (about 2 s) before status reaches the clients again,
        # all while the publisher is still running.
        "ui_seconds": 10.0,
        "replay_messages": 1_000_000,
        "scan_reductions": 20_000,
        "scale_sizes": "10,100,1000",
        "soak_seconds": 600.0,
    },
    "quick": {
        "rates": "5000,20000",
        "seconds": 2.0,
        "latency_trials": 100,
        "latency_rounds": 1,
        "record_rates": "20000",
        "ui_rates": "20000",
        "ui_seconds": 8.0,
        "replay_messages": 200_000,
        "scan_reductions": 5_000,
        "scale_sizes": "10,100",
        "soak_seconds": 20.0,
    },
}


def _rates(text: str) -> list[float]:
    try:
        rates = [float(r) for r in text.split(",") if r.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma-separated list of rates: {text}") from None
    if not rates or any(r <= 0 for r in rates):
        raise argparse.ArgumentTypeError("rates must be positive messages per second")
    return rates


def _bursts(text: str) -> list[int]:
    try:
        bursts = [int(b) for b in text.split(",") if b.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma-separated list of rounds: {text}") from None
    if not bursts or any(b <= 0 for b in bursts):
        raise argparse.ArgumentTypeError("bursts must be positive numbers of rounds")
    return bursts


def _sizes(text: str) -> list[int]:
    try:
        sizes = [int(n) for n in text.split(",") if n.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma-separated list of sizes: {text}") from None
    if not sizes or any(n <= 0 for n in sizes):
        raise argparse.ArgumentTypeError("sizes must be positive numbers of requirements")
    return sizes


def _positive(kind: type) -> Callable[[str], Any]:
    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text}") from None
        if value <= 0:
            raise argparse.ArgumentTypeError(f"must be positive: {text}")
        return value

    return parse


def _add_arguments(p: argparse.ArgumentParser) -> None:
    # None, resolved later: the installed example's path is this machine's, not the docs'
    p.add_argument("--config", default=None, help="default: config/srobot.yaml")
    p.add_argument(
        "--rates",
        type=_rates,
        default=None,
        metavar="R,R,...",
        help=f"total offered msg/s over all topics (default {DEFAULT_RATES}; --quick 5000,20000)",
    )
    p.add_argument(
        "--seconds", type=_positive(float), default=None, help="per rate (default 5; --quick 2)"
    )
    p.add_argument(
        "--burst",
        type=_bursts,
        default=[],
        metavar="N,N,...",
        help="also run each rate with bursts of N rounds (the thesis: 1; a backlog: 50)",
    )
    p.add_argument(
        "--watchdog-usec",
        type=_positive(int),
        default=1_000_000,
        help="WATCHDOG_USEC given to the daemon (default 1000000: a ping every 0.5 s)",
    )
    p.add_argument(
        "--latency-trials",
        type=_positive(int),
        default=None,
        metavar="N",
        help="default 1000 (--quick 100)",
    )
    p.add_argument(
        "--latency-rounds",
        type=_positive(int),
        default=None,
        metavar="N",
        help="the latency trials taken in N rounds of echo then daemon, pooled: the "
        "machine drifts between runs (default 3, --quick 1)",
    )
    p.add_argument(
        "--record-rates",
        type=_rates,
        default=None,
        metavar="R,R,...",
        help="offered msg/s of the recording overhead runs (default 20000)",
    )
    p.add_argument(
        "--ui-rates",
        type=_rates,
        default=None,
        metavar="R,R,...",
        help="offered msg/s of the UI load runs (default 20000)",
    )
    p.add_argument(
        "--ui-seconds",
        type=_positive(float),
        default=None,
        metavar="S",
        help="per UI load run, the UI killed halfway in the last (default 10; --quick 8)",
    )
    p.add_argument(
        "--ui-clients",
        type=_positive(int),
        default=10,
        metavar="N",
        help="event streams open on the UI (default 10)",
    )
    p.add_argument(
        "--ui-chromium",
        action="store_true",
        help="also one page in headless Chromium on the UI (needs /usr/bin/chromium, playwright)",
    )
    p.add_argument(
        "--replay-messages",
        type=_positive(int),
        default=None,
        metavar="N",
        help="messages per replayed bag (default 1000000; --quick 200000)",
    )
    p.add_argument(
        "--scan",
        action="store_true",
        help="also a 1,440-reading LaserScan at 40 Hz beside the stream, reduced and aged",
    )
    p.add_argument(
        "--scan-rate",
        type=_positive(float),
        default=10_000.0,
        metavar="R",
        help="offered msg/s of the stream beside the scan (default 10000)",
    )
    p.add_argument(
        "--scan-reductions",
        type=_positive(int),
        default=None,
        metavar="N",
        help="scans reduced in this process to time it (default 20000; --quick 5000)",
    )
    p.add_argument(
        "--scale-sizes",
        type=_sizes,
        default=None,
        metavar="N,N,...",
        help="requirements per generated config (default 10,100,1000; --quick 10,100)",
    )
    p.add_argument(
        "--scale-rate",
        type=_positive(float),
        default=10_000.0,
        metavar="R",
        help="offered msg/s over the generated config's 50 topics (default 10000)",
    )
    p.add_argument(
        "--soak-seconds",
        type=_positive(float),
        default=None,
        metavar="S",
        help="default 600 (--quick 20)",
    )
    p.add_argument(
        "--soak-rate",
        type=_positive(float),
        default=20_000.0,
        metavar="R",
        help="offered msg/s of the soak (default 20000)",
    )
    p.add_argument(
        "--quick", action="store_true", help="every experiment, short (a couple of minutes)"
    )
    p.add_argument(
        "--out", type=Path, default=None, metavar="DIR", help="also write bench.json and bench.md"
    )
    p.add_argument("--skip-throughput", action="store_true")
    p.add_argument("--skip-latency", action="store_true")
    p.add_argument("--skip-record", action="store_true", help="leave out the recording overhead")
    p.add_argument("--skip-replay", action="store_true", help="leave out the replay throughput")
    p.add_argument("--skip-ui", action="store_true", help="leave out the UI load")
    p.add_argument(
        "--skip-scale",
        action="store_true",
        help="leave out the generated sets of N requirements (check, compile, step, daemon)",
    )
    p.add_argument(
        "--skip-soak", action="store_true", help="leave out the long run's memory and descriptors"
    )
    p.add_argument(
        "--naive",
        action="store_true",
        help="also measure rclpy's default SingleThreadedExecutor (busy: takes a CPU)",
    )
    p.add_argument(
        "--domain-id",
        type=int,
        default=None,
        help="default: one of 215..232 that no other bench on this host holds",
    )
    p.add_argument("--json", action="store_true", help="one JSON document instead of tables")
    p.add_argument(
        "--startup",
        action="store_true",
        help="only the start-up times: --help, check and run to READY=1, cold and warm cache",
    )
    p.add_argument(
        "--predict",
        action="store_true",
        help="only the predictions: recall, lead times and false predictions per hour "
        "over labelled scenarios, replayed in this process (docs/reference/prediction.md)",
    )
    p.add_argument(
        "--predict-ahead-ms",
        type=_positive(float),
        default=500.0,
        metavar="X",
        help="--predict's recall counts violations predicted at least X ms ahead (default 500)",
    )
    p.add_argument(
        "--startup-runs",
        type=_positive(int),
        default=5,
        metavar="N",
        help="runs of each start-up figure (default 5)",
    )


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "bench", help="the thesis's overhead and latency experiment, with and without the daemon"
    )
    _add_arguments(p)


def resolve(args: argparse.Namespace) -> argparse.Namespace:
    """The options left unset get the defaults of a full or a --quick run."""
    for key, value in DEFAULTS["quick" if args.quick else "full"].items():
        if getattr(args, key) is None:
            parse = (
                _rates
                if key.endswith("rates")
                else _sizes
                if key == "scale_sizes"
                else (lambda v: v)
            )
            setattr(args, key, parse(value))
    if args.config is None:
        args.config = str(DEFAULT_CONFIG)
    return args


def cmd_bench(args: argparse.Namespace) -> int:
    # The experiments load only when a bench runs: `--help` stays light.
    from supervisor.tools.bench.experiments import run
    from supervisor.tools.bench.predict import format_predict, run_predict
    from supervisor.tools.bench.startup import format_startup, run_startup

    resolve(args)
    progress = None if args.json else _progress
    # SIGTERM unwinds like Ctrl-C, so the finally blocks kill the children.
    with sigterm_as_interrupt():
        try:
            if args.predict:
                results = run_predict(args, progress)
            elif args.startup:
                results = run_startup(
                    Path(args.config), args.startup_runs, args.domain_id, progress
                )
            else:
                results = run(args, progress=progress)
        except BenchError as e:
            print(f"safety-supervisor bench: {e}", file=sys.stderr, flush=True)
            return 1
        except KeyboardInterrupt:
            print("safety-supervisor bench: interrupted", file=sys.stderr, flush=True)
            return 130
    if args.json:
        print(json.dumps(results, indent=2), flush=True)
    elif args.predict:
        print(format_predict(results), flush=True)
    elif args.startup:
        print(format_startup(results), flush=True)
    else:
        from supervisor.tools.bench.report import format_results

        print(format_results(results), flush=True)
    if args.out is not None:
        try:
            written = (
                write_json(args.out, "predict.json", results)
                if args.predict
                else write_startup(args.out, results)
                if args.startup
                else write_out(args.out, results)
            )
        except OSError as e:
            print(f"safety-supervisor bench: --out {args.out}: {e}", file=sys.stderr, flush=True)
            return 1
        _progress(f"wrote {', '.join(str(p) for p in written)}")
    return 0


def write_out(out: Path, results: dict[str, Any]) -> list[Path]:
    """``bench.json`` (every figure) and ``bench.md`` (the tables) in ``out``."""
    from supervisor.tools.bench.report import format_markdown

    out.mkdir(parents=True, exist_ok=True)
    js, md = out / "bench.json", out / "bench.md"
    js.write_text(json.dumps(results, indent=2) + "\n")
    md.write_text(format_markdown(results))
    return [js, md]


def write_startup(out: Path, results: dict[str, Any]) -> list[Path]:
    """``startup.json`` in ``out``: the figures of ``--startup``."""
    out.mkdir(parents=True, exist_ok=True)
    js = out / "startup.json"
    js.write_text(json.dumps(results, indent=2) + "\n")
    return [js]


def write_json(out: Path, name: str, results: dict[str, Any]) -> list[Path]:
    """``name`` in ``out``: one part's figures (``--predict``)."""
    out.mkdir(parents=True, exist_ok=True)
    js = out / name
    js.write_text(json.dumps(results, indent=2) + "\n")
    return [js]


def _progress(text: str) -> None:
    print(f"  ... {text}", file=sys.stderr, flush=True)
