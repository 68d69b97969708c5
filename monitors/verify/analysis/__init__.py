"""Formal analysis of a requirement set by bounded model checking with z3.

For safety engineers, before a monitor is deployed: can all requirements hold
together (consistency), which smallest set cannot (conflicts), can a controller
meet the guarantees whatever the sensed inputs do (realizability), which
requirement can never be triggered (vacuity) or is implied by the others
(redundancy), and which are non-monotone.

Semantics (the same as the monitor's, through ``monitors.verify.bmc``): a trace of
``k`` ticks satisfies a monotone requirement when its formula holds at every
tick, and a non-monotone one (a pending obligation) when it holds at the last
tick.  Variable ranges are constraints too: on inputs they are assumptions, on
outputs they limit what the controller may choose.

Realizability is a game: the environment picks inputs allowed by the
assumptions and input ranges, the controller picks outputs, and at each tick t,
if the assumptions held up to t, the guarantees must hold at t.

- When every requirement is a pure invariant (``H p``, p without temporal
  operators) the game has no memory: "for every allowed input at one tick there
  are outputs" is checked once and proves realizability for all time.
- Otherwise it is bounded to k ticks.  "Causal" means the outputs at tick t may
  depend on inputs up to t only (forall i0 exists o0 forall i1 exists o1 ...);
  that is what a controller can do and what is reported as realizable.  The
  weaker "clairvoyant" check (for every whole input sequence there are outputs,
  which may depend on future inputs) is what finds a concrete defeating input
  sequence; when only it could be decided, the report says so.  Requirements
  that share no variable are solved as separate games, and comparisons over
  numbers are abstracted into Booleans when none mixes inputs with outputs
  (exact, see ``arena.abstract_arena``).

Every trace reported in a finding is re-evaluated with the reference
interpreter (``monitors.verify.interpret``) and must agree with what z3 claimed; a
disagreement raises ``AssertionError`` (an encoding bug, never hidden).

The modules, one job each: ``requirements`` (what is analysed), ``results``
(what is reported), ``context`` (the shared solver), ``solvers`` (every solver
within the memory limit), ``consistency`` and
``conflicts``, ``realizability`` with ``game``, ``arena`` and ``exists_forall``,
``vacuity``, ``redundancy``, ``examples`` (example traces for the report) with
``readable`` (readable values in them), and
``run`` (``analyse``, all of them in order)."""

from monitors.verify.analysis.requirements import (
    DEFAULT_RLIMIT,
    DEFAULT_TIMEOUT_S,
    Req,
    VarInfo,
    activation,
    default_k,
    range_formula,
)
from monitors.verify.analysis.results import (
    SEVERITIES,
    Analysis,
    Example,
    Finding,
    Limit,
    Remedy,
    Skip,
    Trace,
)

# The solver (z3) loads when the analyses run, not when their results are read: a
# start from the start-up cache never imports it (docs/BENCHMARKS.md, "Start-up").


def __getattr__(name: str) -> object:
    if name == "analyse":
        from monitors.verify.analysis.run import analyse

        return analyse
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "DEFAULT_RLIMIT",
    "DEFAULT_TIMEOUT_S",
    "SEVERITIES",
    "Analysis",
    "Example",
    "Finding",
    "Limit",
    "Remedy",
    "Req",
    "Skip",
    "Trace",
    "VarInfo",
    "activation",
    "analyse",
    "default_k",
    "range_formula",
]
