"""The ``functions:`` section: definitions of the functions FRET passes through.

Each entry names its parameters and defines the value in formula syntax, as a
variable's ``define:`` does::

    functions:
      mag:
        params: [x, y]
        define: sqrt(x * x + y * y)

Calls are expanded by monitors/ir/functions.py (docs/reference/config.md,
"functions").
"""

from __future__ import annotations

from monitors.errors import UserError
from monitors.ir.formula import name_problem
from monitors.ir.functions import BUILT_IN, Function, check_definition
from supervisor.config.fields import as_mapping, check_keys, error_at
from supervisor.config.variables import parse_define
from supervisor.config.yamlload import LineDict

FUNCTION_KEYS = {"params", "define"}
_IDENTIFIER = "a letter or '_', then letters, digits or '_'"


def load_functions(doc: LineDict) -> dict[str, Function]:
    raw = doc.get("functions")
    if raw is None:
        return {}
    section = as_mapping(raw, doc, "functions", "functions")
    out: dict[str, Function] = {}
    for name, spec in section.items():
        name = str(name)
        what = f"function '{name}'"
        if not name.isidentifier() or not name.isascii():
            raise error_at(f"'{name}' is not a usable function name", section, name, _IDENTIFIER)
        if name in BUILT_IN:
            raise error_at(
                f"'{name}' is a built-in function and cannot be redefined", section, name
            )
        spec = as_mapping(spec, section, what, name)
        check_keys(spec, FUNCTION_KEYS, what)
        missing = sorted(FUNCTION_KEYS - set(spec))
        if missing:
            raise error_at(f"{what} needs '{missing[0]}:'", section, name)
        params = spec["params"]
        if not isinstance(params, list) or not all(isinstance(p, str) for p in params):
            raise error_at(f"{what}: params must be a list of names, e.g. [x, y]", spec, "params")
        for p in params:
            why = name_problem(p)
            if why is not None:
                raise error_at(f"{what}: '{p}' is not a usable parameter name", spec, "params", why)
        if len(set(params)) != len(params):
            raise error_at(f"{what} names a parameter twice", spec, "params")
        body = parse_define(str(spec["define"]), getattr(spec, "file", ""), spec.key_line("define"))
        out[name] = Function(name, tuple(params), body)
    for name, fn in out.items():
        try:
            check_definition(fn, out)
        except UserError as e:
            raise error_at(e.message, section, name, e.hint) from None
    return out
