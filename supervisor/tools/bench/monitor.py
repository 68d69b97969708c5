"""Monitor overhead benchmark: ``python -m supervisor.tools.bench.monitor [CONFIG.yaml | EXPORT.json]``.

Builds the sRobot monitor (by default from the shipped config/srobot.yaml;
a FRET project export's ``ptLTL`` strings also work) with every available
backend (native, and Copilot where GHC + Copilot are installed) and prints
the whole compile time of the config (parse, formalize, generate C, build),
and the cost of one tick through cffi, Python call and input packing
included.  Prints numbers; asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import random
import statistics
import tempfile
import time
from collections.abc import Callable
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


def bench(mon: LoadedMonitor, rows: list, repeats: int = 5) -> dict[str, float]:
    """ns per tick (median and best of ``repeats`` passes over ``rows``) and the
    share of ticks with a violation (those also copy the flags out)."""
    tick = mon.tick
    per: list[float] = []
    for _ in range(repeats):
        mon.reset()
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
    args = ap.parse_args(argv)
    backends = _backends()
    start = time.perf_counter()
    if args.source.suffix == ".json":
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


if __name__ == "__main__":
    main()
