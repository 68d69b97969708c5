"""Arrays made one value (``reduce:``; docs/reference/config.md, "reduce").

NaN is never a reading.  Over a LaserScan's ``ranges`` (REP 117) infinite
readings and those outside ``[range_min, range_max]`` are not readings either.
With no reading left: min is +inf, max -inf, mean NaN, sum 0, count 0; ``len``
counts every element.
"""

from __future__ import annotations

from typing import Any

from mitigations.rosmsg import INT_TYPES, REAL_TYPES
from monitors.errors import UserError

REDUCTIONS = ("min", "max", "mean", "sum", "count", "len", "any", "all")


def reduction_type(how: str, element: str, path: str, var_type: str) -> None:
    """A ``var_type`` variable may hold ``how`` over elements of ROS type
    ``element``, or a UserError says why not."""
    if how in ("len", "count"):
        wants, why = {"int64", "double"}, "a count"
    elif how in ("any", "all"):
        if element != "boolean":
            raise UserError(f"reduce: {how} needs an array of booleans; '{path}' holds {element}")
        wants, why = {"bool"}, "true or false"
    else:
        if element not in REAL_TYPES | INT_TYPES:
            raise UserError(f"reduce: {how} needs an array of numbers; '{path}' holds {element}")
        ints = element in INT_TYPES and how != "mean"
        wants, why = ({"int64", "double"} if ints else {"double"}), f"{how} of {element}"
    if var_type not in wants:
        raise UserError(
            f"reduce: {how} over '{path}' gives {why}, which cannot feed a {var_type} variable"
        )


def reduce_values(values: Any, how: str, bounds: tuple[float, float] | None = None) -> Any:
    """``how`` over an array's elements; ``bounds`` are a LaserScan's
    range_min..range_max (REP 117)."""
    if how == "len":
        return len(values)
    if how in ("any", "all"):
        flags = [bool(x) for x in values]
        return any(flags) if how == "any" else all(flags)
    if len(values) and isinstance(values[0], bytes):  # rclpy's byte/octet: b'\x02'
        values = [x[0] for x in values]
    import numpy as np  # on first use: the CLI and check do not load it (docs/BENCHMARKS.md)

    arr = np.asarray(values)
    integral = arr.dtype.kind in "iu" or (arr.size == 0 and how not in ("mean",))
    if arr.dtype.kind == "f":
        keep = ~np.isnan(arr)
        if bounds is not None:
            keep &= np.isfinite(arr) & (arr >= bounds[0]) & (arr <= bounds[1])
        arr = arr[keep]
        integral = False
    if how == "count":
        return int(arr.size)
    if arr.size == 0:
        return {"min": float("inf"), "max": float("-inf"), "mean": float("nan"), "sum": 0.0}[how]
    with np.errstate(all="ignore"):  # inf - inf is NaN, as in C: said by the value
        result = {"min": arr.min, "max": arr.max, "mean": arr.mean, "sum": arr.sum}[how]()
    return int(result) if integral and how != "mean" else float(result)
