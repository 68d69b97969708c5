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
            boolean: dict[str, float] = {}
            for label, trace in (("random inputs", rows), ("quiet robot", quiet)):
                r = bench(mon, trace)
                boolean[label] = r["median_ns"]
                print(
                    f"    {label:14s} {r['median_ns']:6.0f} ns/tick median ({r['best_ns']:.0f} "
                    f"best), {r['violating']:.0%} of ticks violating; Python call and input "
                    "packing included"
                )
            if name == "native":
                _bench_margins(spec, mon, rows, quiet, boolean, Path(tmp))


def _bench_margins(
    spec: MonitorSpec,
    plain: LoadedMonitor,
    rows: list,
    quiet: list,
    boolean: dict[str, float],
    tmp: Path,
) -> None:
    """The margins rows: the same ticks with ``spec.margins`` on, against ``boolean``
    (``plain``'s), through Python and in C alone (``tick_batch``)."""
    from monitors.backends.c99 import margin_state
    from monitors.backends.throughput import batch_rate

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
    for label, trace in (("random inputs", rows), ("quiet robot", quiet)):
        for read in (False, True):
            r = bench(mon, trace, read_margins=read)
            what = "tick + margins()" if read else "tick"
            print(
                f"    {label:14s} {r['median_ns']:6.0f} ns/{what} median ({r['best_ns']:.0f} "
                f"best), {r['median_ns'] / boolean[label]:.2f}x the boolean tick"
            )
    # the step alone: one C call for 10,000 random rows (flags, and margins copied out)
    n = 10_000
    off, on = (1e9 / max(batch_rate(m, n) for _ in range(3)) for m in (plain, mon))
    print(
        f"    C step alone (tick_batch of {n} rows): {off:.0f} ns/tick boolean, {on:.0f} "
        f"ns/tick with margins, {on / off:.2f}x"
    )


if __name__ == "__main__":
    main()
