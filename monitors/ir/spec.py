"""What a monitor is made of, independent of how it is compiled.

The config stage produces a MonitorSpec; the C99 and Copilot backends turn it
into C with the contract's interface; the reference interpreter evaluates it.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from monitors.ir.formula import Formula, Past, Since, Var, map_children

# Formula-level types.  Message fields of other widths are converted to these
# by the daemon when it copies a field into a monitor input.
TYPES = ("bool", "int64", "double")
C_TYPES = {"bool": "bool", "int64": "int64_t", "double": "double"}
TYPE_ALIASES = {
    "bool": "bool",
    "boolean": "bool",
    "int": "int64",
    "int64": "int64",
    "int64_t": "int64",
    "integer": "int64",
    "double": "double",
    "real": "double",
    "float64": "double",
}


@dataclass(frozen=True)
class VarDecl:
    name: str
    type: str  # one of TYPES


@dataclass(frozen=True)
class Define:
    """An internal variable: a name for an expression over inputs (FRET's
    'Internal' variables, e.g. dgt_7 = distance_to_target > 7)."""

    name: str
    type: str
    expr: Formula


@dataclass(frozen=True)
class RequirementSpec:
    id: str
    formula: Formula  # may mention Define names

    @property
    def handler(self) -> str:
        """Copilot/OGMA's handler naming: handler<ID>."""
        return "handler" + self.id


@dataclass(frozen=True)
class MonitorSpec:
    component: str
    inputs: tuple[VarDecl, ...]
    requirements: tuple[RequirementSpec, ...]
    defines: tuple[Define, ...] = ()
    prefix: str = ""  # step function is '<prefix>_step' when set, else 'step'
    meta: dict = field(default_factory=dict, compare=False, hash=False)
    # The step also computes each requirement's margin (docs/reference/margins.md);
    # bool_margin is a boolean atom's margin when it holds (its negation when not).
    margins: bool = False
    bool_margin: float = math.inf

    @property
    def step_name(self) -> str:
        return f"{self.prefix}_step" if self.prefix else "step"

    @property
    def reset_name(self) -> str:
        return f"{self.prefix}_reset" if self.prefix else "monitor_reset"

    def expanded(self, req: RequirementSpec) -> Formula:
        """The requirement's formula over inputs only (defines substituted)."""
        return expand_defines(req.formula, self.defines)


# How much of a window's past the C monitor keeps for its margin, in ticks
# (docs/reference/margins.md, "Cost, and the fallback for long windows").  A loop-free
# min/max over N stored margins is N comparisons every tick, and a bounded S updates
# each of its N candidates every tick, so those are bounded by MARGIN_WINDOW_TICKS; a
# lower bound of O/H only delays (a ring: one read and one write a tick, 8 bytes a
# tick of state), bounded by MARGIN_DELAY_TICKS.  Longer ones fall back to their
# boolean value.
MARGIN_WINDOW_TICKS = 32
MARGIN_DELAY_TICKS = 1024


def margin_falls_back(g: Formula) -> bool:
    """Whether the temporal node ``g``'s window is too long for its margin to be kept."""
    if not isinstance(g, Past | Since) or (isinstance(g, Past) and g.op in ("Y", "Z")):
        return False
    lo = g.lo or 0
    if g.hi is not None and g.hi < lo:
        return False  # empty window: a constant
    if isinstance(g, Past):  # O, H: delayed by lo, then hi - lo + 1 margins compared
        return lo > MARGIN_DELAY_TICKS or (g.hi is not None and g.hi - lo > MARGIN_WINDOW_TICKS)
    # S, T: every candidate of the last hi (or lo, unbounded) ticks updated each tick
    return (lo if g.hi is None else g.hi) > MARGIN_WINDOW_TICKS


def expand_defines(f: Formula, defines: tuple[Define, ...] | list[Define]) -> Formula:
    table = {d.name: d.expr for d in defines}

    def go(g: Formula) -> Formula:
        if isinstance(g, Var) and g.name in table:
            return go(table[g.name])
        return map_children(g, go)

    return go(f)


C_KEYWORDS = frozenset(
    """auto break case char const continue default do double else enum extern float for goto
    if inline int long register restrict return short signed sizeof static struct switch
    typedef union unsigned void volatile while _Bool _Complex _Imaginary bool true false
    step main NULL""".split()
)


def c_name(name: str) -> str:
    """A C identifier for a variable name: C keywords and odd characters are mangled
    (manifest.json records the mapping)."""
    safe = re.sub(r"[^A-Za-z0-9_]", "_", name)
    if not safe or safe[0].isdigit():
        safe = "v_" + safe
    if safe in C_KEYWORDS:
        safe = safe + "_"
    return safe
