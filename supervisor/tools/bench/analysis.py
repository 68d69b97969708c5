"""Time the formal analyses: ``python -m supervisor.tools.bench.analysis [CONFIG ...]``.

Prints the time of every analysis for the shipped sRobot config (``check`` runs
them, so they must take seconds) and for a generated set of 60 requirements with
time bounds up to 20 ticks (target: under a minute).  Extra arguments are
config files analysed the same way.  Each line also gives the most z3 resource
units one query took, what ``analysis.rlimit`` must allow for the analyses to
decide everything (docs/BENCHMARKS.md, "Analyses"); z3's count for a query
depends on what it solved before in the same process, so compare configs one per
run.
"""

from __future__ import annotations

import argparse
import random
import sys
import time
from pathlib import Path

from monitors.frontend.formalize import formalize
from monitors.frontend.parse import parse_requirement
from monitors.verify.analysis import (
    DEFAULT_TIMEOUT_S,
    Analysis,
    Req,
    VarInfo,
    activation,
    analyse,
)
from supervisor import data


def generated(
    n_channels: int = 15, max_bound: int = 20, seed: int = 6
) -> tuple[list[Req], list[VarInfo]]:
    """A realistic, consistent and realizable set of 4 requirements per sensor
    channel (timed responses, holds, modes) plus its variables."""
    rng = random.Random(seed)
    reqs: list[Req] = []
    vars_: list[VarInfo] = []
    for j in range(n_channels):
        vars_ += [
            VarInfo(f"s{j}", "int64", "input", (0, 100)),
            VarInfo(f"trig{j}", "bool", "input"),
            VarInfo(f"alarm{j}", "bool", "output"),
            VarInfo(f"stop{j}", "bool", "output"),
            VarInfo(f"level{j}", "int64", "output", (0, 3)),
        ]
        hi, lo = rng.randint(50, 90), rng.randint(5, 40)
        texts = [
            f"upon s{j} > {hi} R shall within {rng.randint(1, max_bound)} ticks satisfy alarm{j}",
            f"whenever s{j} < {lo} R shall immediately satisfy !stop{j}",
            f"upon trig{j} R shall for {rng.randint(1, max_bound)} ticks satisfy level{j} >= 1",
            f"while level{j} = 0 R shall always satisfy !alarm{j} & !stop{j}",
        ]
        if j == 0:  # the maximal bound occurs
            texts[0] = f"upon s{j} > {hi} R shall within {max_bound} ticks satisfy alarm{j}"
        for i, text in enumerate(texts):
            req = parse_requirement(text)
            form = formalize(req)
            reqs.append(
                Req(
                    f"ch{j}_r{i}",
                    form.formula,
                    monotone=form.monotone,
                    activation=activation(req),
                    note=form.note,
                    text=text,
                )
            )
    return reqs, vars_


def from_config(
    path: str | Path,
) -> tuple[list[Req], list[VarInfo], int | None, float, int]:
    from supervisor.pipeline import project_for
    from supervisor.validation import project_requirements

    project = project_for(path, ros=False)
    reqs, vars_ = project_requirements(project)
    settings = project.config.analysis
    return reqs, vars_, settings.k, settings.timeout_s, settings.rlimit


def report(name: str, a: Analysis, wall: float) -> None:
    parts = ", ".join(f"{k} {v:.2f} s" for k, v in a.seconds.items() if k != "total")
    print(f"{name}: {len(a.requirements)} requirements, k = {a.k}: {wall:.2f} s ({parts})")
    print(f"  z3 resource units of the largest query: {a.max_steps}")
    print(f"  consistency:   {a.consistency}")
    print(f"  realizability: {a.realizability}")
    print(f"  findings:      {len(a.errors)} errors, {len(a.warnings)} warnings")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m supervisor.tools.bench.analysis", description=__doc__
    )
    p.add_argument("configs", nargs="*", help="more configs to time")
    p.add_argument("--timeout-s", type=float, default=None, help="per z3 query (default: config)")
    p.add_argument(
        "--rlimit", type=int, default=None, help="z3 resource units per query (default: config)"
    )
    args = p.parse_args(argv)
    for path in [data.example("srobot.yaml"), *args.configs]:
        reqs, vars_, k, timeout, rlimit = from_config(path)
        t = time.perf_counter()
        a = analyse(
            reqs, vars_, k=k, timeout_s=args.timeout_s or timeout, rlimit=args.rlimit or rlimit
        )
        report(str(path), a, time.perf_counter() - t)
    reqs, vars_ = generated()
    limit = {"rlimit": args.rlimit} if args.rlimit else {}
    t = time.perf_counter()
    a = analyse(reqs, vars_, timeout_s=args.timeout_s or DEFAULT_TIMEOUT_S, **limit)
    report("generated (60 requirements, bounds up to 20 ticks)", a, time.perf_counter() - t)
    return 0


if __name__ == "__main__":
    sys.exit(main())
