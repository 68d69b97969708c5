"""Monitor overhead benchmark: ``python -m supervisor.tools.bench.monitor [CONFIG.yaml | EXPORT.json]``.

Builds the sRobot monitor (by default from the shipped config/srobot.yaml;
a FRET project export's ``ptLTL`` strings also work) with every available
backend (native, and Copilot where GHC + Copilot are installed) and prints
the whole compile time of the config (parse, formalize, generate C, build),
and the cost of one tick through cffi, Python call and input packing
included; for the native backend also with margins on (``step.margins``,
docs/reference/margins.md), with and without reading them.  ``--generated N``
benchmarks a generated set of N requirements (scalegen.py) instead of a config.
Prints numbers; asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import math
import random
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from monitors.backends.load import LoadedMonitor, compile_spec
from monitors.ir.formula import parse_formula
from monitors.ir.spec import TYPE_ALIASES, Define, MonitorSpec, RequirementSpec, VarDecl
from supervisor import data

DEFAULT_CONFIG = data.example("srobot.yaml")


def _backends() -> dict[str, Callable[[MonitorSpec, Path], LoadedMonitor]]:
    """Backend name -> build(spec, out_dir) -> LoadedMonitor."""
    from monitors.backends.copilot import build_copilot_monitor, copilot_available

    found: dict[str, Callable[[MonitorSpec, Path], LoadedMonitor]] = {"native": compile_spec}
    if copilot_available():
        found["copilot"] = build_copilot_monitor
    return found


def spec_from_config(path: Path) -> MonitorSpec:
    """The monitor of a safety-supervisor config, through the whole pipeline."""
    from supervisor.pipeline import project_for

    project = project_for(path, ros=False)
    err = project.first_error()
    if err is not None:
        raise SystemExit(str(err))
    return project.spec()


def spec_from_fret_export(path: Path) -> MonitorSpec:
    """A MonitorSpec from a FRET export: ``Other_variables`` are the inputs,
    ``Internal_variables`` the defines, ``Requirements[].ptLTL`` the formulas."""
    data = json.loads(Path(path).read_text())
    (component, body), *_ = data.items()
    component = component.removesuffix("Spec")
    inputs = tuple(VarDecl(v["name"], TYPE_ALIASES[v["type"]]) for v in body["Other_variables"])
    defines = tuple(
        Define(v["name"], TYPE_ALIASES[v["type"]], parse_formula(v["assignmentCopilot"]))
        for v in body["Internal_variables"]
    )
    reqs = tuple(
        RequirementSpec(r["name"], parse_formula(r["ptLTL"])) for r in body["Requirements"]
    )
    return MonitorSpec(component, inputs, reqs, defines)


def _rows(spec: MonitorSpec, n: int) -> list[list[bool | int | float]]:
    """Plausible sRobot inputs (small ints, both booleans) so every branch runs."""
    rnd = random.Random(1)
    pick = {
        "bool": lambda: rnd.random() < 0.5,
        "int64": lambda: rnd.randint(0, 9),
        "double": lambda: rnd.uniform(0, 10),
    }
    return [[pick[v.type]() for v in spec.inputs] for _ in range(n)]


def bench(
    mon: LoadedMonitor, rows: list, repeats: int = 5, read_margins: bool = False
) -> dict[str, float]:
    """ns per tick (median and best of ``repeats`` passes over ``rows``) and the
    share of ticks with a violation (those also copy the flags out); with
    ``read_margins``, each tick also reads the margins into Python."""
    tick = mon.tick
    per: list[float] = []
    for _ in range(repeats):
        mon.reset()
        if read_margins:
            read = mon.margins
            start = time.perf_counter_ns()
            for row in rows:
                tick(row)
                read()
        else:
            start = time.perf_counter_ns()
            for row in rows:
                tick(row)
        per.append((time.perf_counter_ns() - start) / len(rows))
    mon.reset()
    violating = sum(any(tick(row)) for row in rows) / len(rows)
    return {"median_ns": statistics.median(per), "best_ns": min(per), "violating": violating}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        prog="python -m supervisor.tools.bench.monitor", description=__doc__
    )
    ap.add_argument(
        "source", nargs="?", type=Path, default=DEFAULT_CONFIG, help="config or FRET export"
    )
    ap.add_argument("--ticks", type=int, default=200_000)
    ap.add_argument("--backend", action="append", choices=["native", "copilot"])
    ap.add_argument("--generated", type=int, metavar="N", help="a generated set of N requirements")
    args = ap.parse_args(argv)
    backends = _backends()
    start = time.perf_counter()
    if args.generated:
        from supervisor.tools.bench.scalegen import generate

        with tempfile.TemporaryDirectory(prefix="ss-bench-") as tmp:
            spec = spec_from_config(generate(args.generated).write(Path(tmp) / "scale.yaml"))
    elif args.source.suffix == ".json":
        spec = spec_from_fret_export(args.source)
    else:
        spec = spec_from_config(args.source)
    front_s = time.perf_counter() - start
    rows = _rows(spec, args.ticks)
    zero = {"bool": False, "int64": 0, "double": 0.0}
    quiet = [[zero[v.type] for v in spec.inputs]] * args.ticks
    print(
        f"{spec.component}: {len(spec.requirements)} requirements, {len(spec.inputs)} inputs, "
        f"{args.ticks} ticks per pass"
    )
    print(f"  load config, parse and formalize: {front_s * 1000:.0f} ms")
    for name in args.backend or list(backends):
        if name not in backends:
            print(f"  {name}: not available (install ghc and libghc-copilot-dev)")
            continue
        with tempfile.TemporaryDirectory(prefix="ss-bench-") as tmp:
            start = time.perf_counter()
            mon = backends[name](spec, Path(tmp))
            build_s = time.perf_counter() - start
            print(f"  {name}: generate + compile + load {build_s * 1000:.0f} ms")
            for label, trace in (("random inputs", rows), ("quiet robot", quiet)):
                r = bench(mon, trace)
                print(
                    f"    {label:14s} {r['median_ns']:6.0f} ns/tick median ({r['best_ns']:.0f} "
                    f"best), {r['violating']:.0%} of ticks violating; Python call and input "
                    "packing included"
                )
            if name == "native":
                _bench_margins(spec, mon, rows, quiet, Path(tmp))


def _bench_margins(
    spec: MonitorSpec, plain: LoadedMonitor, rows: list, quiet: list, tmp: Path
) -> None:
    """The margins rows: the same ticks with ``spec.margins`` on against ``plain``
    (the boolean monitor), through Python and in C alone (``tick_batch``).  The
    monitors alternate and each keeps its best pass in this process's CPU time, so
    that other processes on the machine do not decide the ratios."""
    from monitors.backends.c99 import margin_state
    from monitors.backends.throughput import random_columns

    spec = replace(spec, margins=True)
    start = time.perf_counter()
    mon = compile_spec(spec, tmp / "margins")
    build_s = time.perf_counter() - start
    state = margin_state(spec)
    fallbacks = sum(1 for m in state.values() if m.fallbacks)
    print(
        f"  native, margins on: generate + compile + load {build_s * 1000:.0f} ms; "
        f"{sum(m.bytes for m in state.values())} bytes of margin state, {fallbacks} of "
        f"{len(state)} requirements with a window kept boolean"
    )

    def ticks(m: LoadedMonitor, trace: list, read: bool) -> None:
        tick, margins = m.tick, m.margins
        for row in trace:
            tick(row)
            if read:
                margins()

    for label, trace in (("random inputs", rows), ("quiet robot", quiet)):
        trace = trace[:50_000]
        runs = {
            "boolean tick": lambda t=trace: ticks(plain, t, False),
            "tick": lambda t=trace: ticks(mon, t, False),
            "tick + margins()": lambda t=trace: ticks(mon, t, True),
        }
        best = _best_cpu(runs, 5, len(trace))
        base = best.pop("boolean tick")
        print(f"    {label:14s} boolean tick {base:.0f} ns (best CPU time, Python call included)")
        for what, ns in best.items():
            print(f"    {'':14s} {what:16s} {ns:5.0f} ns, {ns / base:.2f}x the boolean tick")
    # the step alone: one C call for 10,000 random rows (flags, and margins copied out)
    n = 10_000
    packed = plain.pack_columns(random_columns(spec, n))
    best = _best_cpu(
        {"off": lambda: plain.tick_batch(packed), "on": lambda: mon.tick_batch(packed)}, 20, n
    )
    off, on = best["off"], best["on"]
    print(
        f"    C step alone (tick_batch of {n} rows): {off:.0f} ns/tick boolean, "
        f"{on:.0f} ns/tick with margins, {on / off:.2f}x"
    )


def _best_cpu(runs: dict[str, Callable[[], object]], repeats: int, per: int) -> dict[str, float]:
    """Each run's best of ``repeats`` (alternating) in CPU ns, divided by ``per``."""
    best = dict.fromkeys(runs, math.inf)
    for _ in range(repeats):
        for name, run in runs.items():
            start = time.process_time_ns()
            run()
            best[name] = min(best[name], (time.process_time_ns() - start) / per)
    return best


if __name__ == "__main__":
    main()
