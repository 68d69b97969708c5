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


# The longest window whose margin the C monitor keeps, in ticks: a loop-free window
# min/max over N stored margins costs N moves and N comparisons each tick, so longer
# windows fall back to their boolean value (docs/reference/margins.md, "Fallback").
MARGIN_WINDOW_TICKS = 32


def margin_slots(g: Formula) -> int:
    """How many past margins the C monitor stores for the temporal node ``g`` (0: none
    or a fixed few; more than MARGIN_WINDOW_TICKS + 1: ``g``'s margin falls back)."""
    if not isinstance(g, Past | Since) or (isinstance(g, Past) and g.op in ("Y", "Z")):
        return 0
    lo = g.lo or 0
    if g.hi is not None and g.hi < lo:
        return 0  # empty window: a constant
    if g.hi is None:
        return 0 if lo == 0 else lo + 1
    return g.hi + 1


def margin_falls_back(g: Formula) -> bool:
    """Whether ``g``'s window is too long for its margin to be kept (see above)."""
    return margin_slots(g) > MARGIN_WINDOW_TICKS + 1


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
