"""``safety-supervisor demo``: the thesis's field test (sec. 5.3.2) on this machine,
or (``--example mobile-base``) a mobile base breaking each of its requirements.

The example's simulated robot (:mod:`supervisor.tools.demo.robot`: a perception
feed and safety controller; :mod:`supervisor.tools.demo.base`: a mobile base) and
the supervisor on a copy of the example's shipped config
(:mod:`supervisor.tools.demo.config`, whose table says what each example runs),
each in its own process on a private ROS domain
(:mod:`supervisor.tools.demo.session`); what happens is shown live
(:mod:`supervisor.tools.demo.view`).  On the end of ``--duration``, Ctrl-C,
SIGTERM or an error the processes are stopped in order; then the summary.
"""

from __future__ import annotations

import argparse
import random
import shutil
import signal
import sys
import tempfile
from collections.abc import Container
from pathlib import Path
from typing import TYPE_CHECKING, Any

from supervisor.tools.children import ros_env
from supervisor.tools.demo.config import (
    DEFAULT_EXAMPLE,
    EXAMPLES,
    demo_config,
    requirement_ids,
)
from supervisor.tools.demo.errors import DemoError
from supervisor.tools.demo.state import DemoState
from supervisor.tools.stopping import sigterm_as_interrupt

if TYPE_CHECKING:
    from supervisor.tools.demo.session import Run

DEFAULT_FAULT_RATE = 0.01  # the thesis's 1 % (sec. 5.3.2)
DEFAULT_RATE_HZ = 10.0
ROBOT_OPTIONS = ("fault_rate", "rate_hz")  # options of one example's simulated robot


def _err(text: str) -> None:
    print(f"safety-supervisor demo: {text}", file=sys.stderr, flush=True)


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from e
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, not {text}")
    return v


def _rate(text: str) -> float:
    v = _positive(text)
    # The config's stale_after_ms is 500: a slower feed would be reported stale.
    if not 5 <= v <= 100:
        raise argparse.ArgumentTypeError(f"must be between 5 and 100 Hz, not {text}")
    return v


def _fraction(text: str) -> float:
    try:
        v = float(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from e
    if not 0 <= v <= 1:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1, not {text}")
    return v


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "demo",
        help="a simulated robot and the supervisor on this machine: violations caught and mitigated",
        description=(
            "Starts a simulated robot and the supervisor on the example's shipped config, "
            "each in its own process on a private ROS domain; shows what happens live and "
            "ends with a summary. srobot (the default): a perception feed (a person walking "
            "through the red/yellow/green zones) and the sRobot safety controller with the "
            "thesis's UV-light fault, on config/srobot.yaml. mobile-base: a mobile base "
            "(lidar, odometry, battery, estop, navigation) whose script breaks each "
            "requirement of config/mobile-base.yaml at least once."
        ),
    )
    p.add_argument(
        "--example",
        choices=sorted(EXAMPLES),
        default=DEFAULT_EXAMPLE,
        help=f"the robot and its config (default {DEFAULT_EXAMPLE})",
    )
    p.add_argument("--duration", type=_positive, default=30.0, help="seconds (default 30)")
    p.add_argument(
        "--fault-rate",
        type=_fraction,
        default=None,
        help="srobot: chance per update in state 3 that the UV light sticks on, as in the "
        "thesis (default 0.01)",
    )
    p.add_argument(
        "--seed", type=int, default=None, help="the walk and the faults (default: random)"
    )
    p.add_argument(
        "--rate-hz", type=_rate, default=None, help="srobot: perception rate (default 10)"
    )
    p.add_argument(
        "--log", default=None, metavar="PATH", help="violation log (default: a temp dir)"
    )
    p.add_argument(
        "--no-live", action="store_true", help="one status line per second instead of a live view"
    )
    p.add_argument(
        "--record",
        default=None,
        metavar="DIR",
        help="keep the run in DIR: the supervisor's bags (run --record), the demo's config "
        "and, unless --log says otherwise, the violation log; for logs DIR, replay DIR "
        "and report DIR",
    )


def _robot_options(args: argparse.Namespace, allowed: Container[str]) -> bool:
    """The simulated robot's options: only those of the example's robot (said
    otherwise), the others at their defaults."""
    for option in ROBOT_OPTIONS:  # the other example's robot has no such knob
        if getattr(args, option) is not None and option not in allowed:
            flag = "--" + option.replace("_", "-")
            _err(f"{flag} is not an option of --example {args.example}")
            return False
    if args.fault_rate is None:
        args.fault_rate = DEFAULT_FAULT_RATE
    if args.rate_hz is None:
        args.rate_hz = DEFAULT_RATE_HZ
    return True


def cmd_demo(args: argparse.Namespace) -> int:
    # The session (processes, the log's reader) only when a demo runs: the CLI
    # imports this module for its parser (docs/BENCHMARKS.md, "Start-up").
    from supervisor.tools.demo.session import LogTail, Notify, Run, pick_domain

    example = EXAMPLES[args.example]
    if not _robot_options(args, example.options):
        return 2
    shipped = example.config
    if not shipped.exists():
        _err(f"{shipped} not found (an incomplete installation: reinstall safety-supervisor)")
        return 1
    workdir = Path(tempfile.mkdtemp(prefix="safety-supervisor-demo-"))
    # --record DIR keeps the log beside the bags and the config: DIR is the whole
    # run, for logs DIR, report DIR and replay DIR (supervisor/tools/recording.py).
    home = Path(args.record).resolve() if args.record else workdir
    log = Path(args.log).resolve() if args.log else home / "violations.jsonl"
    seed = args.seed if args.seed is not None else random.SystemRandom().randrange(1_000_000)
    out = sys.stdout
    live = out.isatty() and not args.no_live
    interrupted = False
    run: Run | None = None
    failed: str | None = None
    walked = 0.0

    with sigterm_as_interrupt():  # SIGTERM: the same orderly stop as Ctrl-C
        try:
            log.parent.mkdir(parents=True, exist_ok=True)
            domain = pick_domain()
            env = ros_env(domain, log_dir=workdir / "ros-log")  # ROS's own logs: not ~/.ros
            st = DemoState(args.duration, args.fault_rate, seed, domain, log, args.example)
            config = demo_config(shipped, workdir, log)
            st.requirements = requirement_ids(config)
            if args.record:  # replay needs the config the run used
                Path(args.record).mkdir(parents=True, exist_ok=True)
                shutil.copyfile(config, Path(args.record) / config.name)
            run = Run(
                args, workdir, st, Notify(workdir / "notify.sock"), LogTail(log), out, live, example
            )
            run.start(config, env)
            run.loop()
        except KeyboardInterrupt:
            interrupted = True
        except DemoError as e:
            failed = str(e)
        except OSError as e:
            failed = f"{e.strerror or e}" + (f": {e.filename}" if e.filename else "")
        finally:
            # A second Ctrl-C must not leave a process behind half-way through stopping.
            old_int = signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            try:
                if run is not None:
                    walked = min(run.st.elapsed(), args.duration)
                    run.stop()
                    run.notify.close()
            finally:
                signal.signal(signal.SIGINT, old_int)
    if run is not None and live:
        out.write("\x1b[H\x1b[2J" + example.screen(run.st, True) + "\n\n")
    elif run is not None:
        run.print_events(settle=0)
    if failed is not None or run is None:
        _err(f"{failed} (process output in {workdir})")
        return 1
    out.write(example.summary(run.st, walked, interrupted) + "\n")
    if args.record:
        rec = Path(args.record)
        out.write(
            f"recorded into {rec} (config, violation log and bags); read it with: "
            f"safety-supervisor logs {rec}, replay {rec}, report {rec} -o report.html\n"
        )
    out.flush()
    if args.log is not None or args.record:  # the log is elsewhere: nothing left to keep
        shutil.rmtree(workdir, ignore_errors=True)
    return 130 if interrupted else 0
