"""Generated requirement sets for ``bench``'s scaling part: N FRETISH requirements over 50
input variables (bool, int64 and double, one std_msgs topic each), deterministic
from a seed.

Every timing the grammar accepts appears (docs/reference/fretish.md: immediately and
its spellings, at the next timepoint, within/for/after N ticks or ms, until C, before
C, always, eventually, never, finally and its spelling, none), cycled over the
requirements; conditions use every qualifier (upon, when, if, where, whenever,
unless; ``is TRUE``/``is FALSE``, several clauses); about half the requirements have
a scope of one of FRET's kinds (in, not in, only in, after, before, only after, only
before, in their written forms). Bounds are 1..100 ticks; every variable is used.

The bench publishes each input's zero (``plan._nominal``: false, 0, 0.0), so every
requirement is drawn until the reference interpreter finds it satisfied on a
constant zero trace longer than its bound (its verdict at every tick if monotone,
at the last if not): the daemon sees a nominal robot, as with the sRobot config.
Such a set is also consistent (the zero trace satisfies all of it), and with every
variable an input there is no realizability to fail.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

COMPONENT = "Scale"
N_VARIABLES = 50
MAX_BOUND = 100
PERIOD_MS = 10
TOPIC_PREFIX = "/bench/scale/"
MSGS = {
    "bool": "std_msgs/msg/Bool",
    "int64": "std_msgs/msg/Int64",
    "double": "std_msgs/msg/Float64",
}
ZERO: dict[str, Any] = {"bool": False, "int64": 0, "double": 0.0}

# (timing kind, how it is written; "{n}" a bound in ticks, "{ms}" the same in ms,
# "{c}" a condition). Each kind is the formalizer's (Requirement.timing.kind).
TIMINGS: list[tuple[str, str]] = [
    ("immediately", "immediately"),
    ("immediately", "initially"),
    ("immediately", "at the first timepoint"),
    ("immediately", "at the same timepoint"),
    ("next", "at the next timepoint"),
    ("within", "within {n} ticks"),
    ("for", "for {n} ticks"),
    ("after", "after {n} ticks"),
    ("within", "within {ms} ms"),
    ("for", "for {ms} milliseconds"),
    ("until", "until {c}"),
    ("before", "before {c}"),
    ("always", "always"),
    ("eventually", "eventually"),
    ("never", "never"),
    ("finally", "finally"),
    ("finally", "at the last timepoint"),
    ("null", ""),
]
TIMING_KINDS = sorted({k for k, _ in TIMINGS})

# Scopes as written ("{m}" a Boolean variable as mode, "{e}" an expression).
SCOPES: list[tuple[str, str]] = [
    ("in", "in {m} mode"),
    ("in", "in mode {m}"),
    ("in", "in {m}"),
    ("in", "during {m}"),
    ("in", "when in {m}"),
    ("in", "while {e}"),
    ("notin", "when not in {m}"),
    ("notin", "unless in {m}"),
    ("notin", "except while {e}"),
    ("onlyIn", "only in {m}"),
    ("onlyIn", "only while {e}"),
    ("after", "after {e}"),
    ("before", "before {e}"),
    ("onlyAfter", "only after {e}"),
    ("onlyBefore", "only before {e}"),
]
QUALIFIERS = ["upon", "when", "if", "where", "whenever", "unless"]
TRIES = 200


@dataclass
class Var:
    name: str
    type: str


@dataclass
class Generated:
    """A generated config: its YAML text, and what it holds."""

    text: str
    n: int
    variables: list[Var]
    timings: dict[str, int] = field(default_factory=dict)  # kind -> requirements
    scopes: dict[str, int] = field(default_factory=dict)
    qualifiers: dict[str, int] = field(default_factory=dict)

    def write(self, path: Path) -> Path:
        path.write_text(self.text)
        return path


def variables(n: int = N_VARIABLES) -> list[Var]:
    """b00, i01, d02, ...: bool, int64, double in turn."""
    kinds = ("bool", "int64", "double")
    return [Var(f"{kinds[i % 3][0]}{i:02d}", kinds[i % 3]) for i in range(n)]


class _Draw:
    """Atoms true or false at the zero state, drawing unused variables first."""

    def __init__(self, rng: random.Random, vars_: list[Var]) -> None:
        self.rng = rng
        self.vars = vars_
        self.unused = list(vars_)
        rng.shuffle(self.unused)
        self.used: list[Var] = []  # this requirement's

    def var(self, kind: str | None = None) -> Var:
        pool = [v for v in self.unused if kind is None or v.type == kind]
        if pool:
            v = pool[0]
            self.unused.remove(v)
        else:
            v = self.rng.choice([v for v in self.vars if kind is None or v.type == kind])
        self.used.append(v)
        return v

    def atom(self, holds: bool, kind: str | None = None) -> str:
        """An atom that holds (or not) when every variable is zero."""
        v = self.var(kind)
        k = self.rng.randint(1, 99)
        r = self.rng
        if v.type == "bool":
            return f"!{v.name}" if holds else v.name
        if v.type == "int64":
            ops = [f"{v.name} < {k}", f"{v.name} <= {k}", f"{v.name} != {k}", f"{v.name} >= -{k}"]
            if not holds:
                ops = [f"{v.name} > {k}", f"{v.name} >= {k}", f"{v.name} = {k}", f"{v.name} < -{k}"]
            return r.choice(ops)
        x = k + r.choice((0.25, 0.5, 0.75))
        ops = [f"{v.name} < {x}", f"{v.name} > -{x}", f"{v.name} * 2.0 <= {x}"]
        if not holds:
            ops = [f"{v.name} > {x}", f"{v.name} >= {x}", f"{v.name} + {x} < 0.0"]
        return r.choice(ops)

    def expr(self, holds: bool, atoms: int) -> str:
        """``atoms`` atoms joined so the whole holds (or not) at zero."""
        if atoms <= 1:
            return self.atom(holds)
        r = self.rng
        if holds:
            # a conjunction of true atoms, or a disjunction with one true atom
            if r.random() < 0.5:
                parts = [self.atom(True) for _ in range(atoms)]
                return "(" + " & ".join(parts) + ")"
            parts = [self.atom(True)] + [self.atom(r.random() < 0.5) for _ in range(atoms - 1)]
            r.shuffle(parts)
            return "(" + " | ".join(parts) + ")"
        if r.random() < 0.5:
            parts = [self.atom(False) for _ in range(atoms)]
            return "(" + " | ".join(parts) + ")"
        parts = [self.atom(False)] + [self.atom(r.random() < 0.5) for _ in range(atoms - 1)]
        r.shuffle(parts)
        return "(" + " & ".join(parts) + ")"


def _sentence(
    d: _Draw, timing: tuple[str, str], scoped: bool, extra: int
) -> tuple[str, str | None, list[str]]:
    """One sentence: (text, scope kind, qualifiers)."""
    r = d.rng
    kind, written = timing
    parts: list[str] = []
    scope_kind = None
    if scoped:
        scope_kind, form = r.choice(SCOPES)
        mode = d.var("bool").name if "{m}" in form else ""
        parts.append(
            form.format(
                m=mode, e=d.expr(r.random() < 0.5, r.randint(1, 2)) if "{e}" in form else ""
            )
        )
    quals: list[str] = []
    # `after N` fails at any trigger on a constant trace: a condition that never fires.
    if kind == "after" or r.random() < 0.6:
        clauses = []
        for j in range(r.randint(1, 2)):
            q = r.choice(QUALIFIERS)
            quals.append(q)
            fires = r.random() < 0.5 and kind != "after"
            c = d.expr(fires != (q == "unless"), r.randint(1, 2))
            suffix = ""
            if r.random() < 0.2:  # `is FALSE` negates the clause
                suffix = " is FALSE"
                c = d.expr(fires == (q == "unless"), 1)
            elif r.random() < 0.1:
                suffix = " is TRUE"
            join = "" if j == 0 else r.choice(("and ", "or ", ", "))
            clauses.append(f"{join}{q} {c}{suffix}")
        parts.append(" ".join(clauses).replace(" , ", ", "))
    n = r.randint(1, MAX_BOUND)
    t = written.format(
        n=n,
        ms=max(1, n) * PERIOD_MS,
        c=d.expr(False, 1) if "{c}" in written else "",
    )
    holds = kind != "never"
    response = d.expr(holds, 1 + extra + r.randint(0, 1))
    shall = f"{COMPONENT} shall {t} satisfy" if t else f"{COMPONENT} shall satisfy"
    text = ", ".join(parts) + (", " if parts else "") + f"{shall} {response}"
    return text, scope_kind, quals


def _nominal_ok(text: str, zero: dict[str, Any], bound: int = MAX_BOUND + 20) -> bool:
    """The requirement holds on a constant zero trace (the interpreter's verdicts)."""
    from monitors.frontend.formalize import formalize
    from monitors.frontend.parse import parse_requirement
    from monitors.verify.interpret import verdicts

    form = formalize(parse_requirement(text), period_ms=PERIOD_MS)
    trace = [zero] * bound
    v = verdicts(form.formula, trace)
    return all(v) if form.monotone else v[-1]


def generate(n: int, seed: int = 1, n_variables: int = N_VARIABLES) -> Generated:
    """A config of ``n`` requirements over ``n_variables`` inputs."""
    rng = random.Random(seed)
    vars_ = variables(n_variables)
    zero = {v.name: ZERO[v.type] for v in vars_}
    d = _Draw(rng, vars_)
    lines: list[str] = []
    out = Generated("", n, vars_)
    for i in range(n):
        timing = TIMINGS[i % len(TIMINGS)]
        scoped = i % 2 == 1
        left = n - i
        extra = -(-len(d.unused) // left) if d.unused else 0  # spread the unused ones
        unused = list(d.unused)
        for _ in range(TRIES):
            d.unused = list(unused)
            d.used = []
            text, scope, quals = _sentence(d, timing, scoped, extra)
            if _nominal_ok(text, zero):
                break
        else:
            raise RuntimeError(f"no requirement {i} ({timing[1]}) holds at zero in {TRIES} draws")
        out.timings[timing[0]] = out.timings.get(timing[0], 0) + 1
        if scope:
            out.scopes[scope] = out.scopes.get(scope, 0) + 1
        for q in quals:
            out.qualifiers[q] = out.qualifiers.get(q, 0) + 1
        lines.append(f"  - id: r{i:04d}\n    text: {_quote(text)}")
    head = [
        f"# bench (scaling): {n} generated requirements over {n_variables} inputs (seed {seed})",
        f"component: {COMPONENT}",
        "step:",
        "  policy: on_trigger",
        f"  trigger: {vars_[-1].name}",
        f"  period_ms: {PERIOD_MS}",
        "variables:",
    ]
    for v in vars_:
        rng_ = ", range: [-1000, 1000]" if v.type == "int64" else ""
        head.append(
            f"  {v.name}: {{type: {v.type}, topic: {TOPIC_PREFIX}{v.name}, msg: {MSGS[v.type]}{rng_}}}"
        )
    out.text = "\n".join([*head, "requirements:", *lines]) + "\n"
    return out


def _quote(text: str) -> str:
    return "'" + text.replace("'", "''") + "'"
