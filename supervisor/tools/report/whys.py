"""Why each violation fired: the why-engine (monitors/verify/why.py) on a window.

The interpreter judges only the window it is given. When the window starts later
than the history the monitor judged (the record's ``recent`` is short, or the page's
cap cut it), the formula may hold at the violating tick in the window: the page
says so rather than explain a verdict the window does not show.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from monitors.errors import UserError
from monitors.verify.why import WhyNode, explain, formula_for_record, missing_inputs, why_tree
from supervisor.tools.report.inputs import Window


@dataclass
class Why:
    window: Window | None
    tree: WhyNode | None = None
    sentence: str = ""
    problem: str | None = None  # why there is no tree, or why it does not explain


def why_of(record: dict[str, Any], window: Window | None) -> Why:
    if window is None or not window.trace:
        return Why(window, problem="the record has no recent ticks to judge")
    try:
        formula = formula_for_record(record)
    except (ValueError, UserError) as e:
        return Why(window, problem=f"the record's formula cannot be read: {e}")
    missing = missing_inputs(formula, window.trace)
    if missing:
        return Why(
            window,
            problem=f"the window lacks {', '.join(missing)} (the formula reads internal "
            "variables and the record has no formula_inputs)",
        )
    last = len(window.trace) - 1
    try:
        tree = why_tree(formula, window.trace, last)
        sentence = explain(formula, window.trace, last, first_tick=window.ticks[0])
    except (ValueError, TypeError, KeyError, UserError) as e:
        return Why(window, problem=f"the interpreter cannot judge this window: {e}")
    if bool(tree.values[last]):
        return Why(
            window,
            tree,
            problem=f"over these {len(window.trace)} ticks the formula holds at tick "
            f"{record.get('tick')}: the window is too short to show why the monitor, which "
            "judged a longer history, flagged it (give --bag and --config for a longer one)",
        )
    return Why(window, tree, sentence)
