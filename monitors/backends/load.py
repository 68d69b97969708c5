"""Load a monitor library built by build.py and drive it from Python.

Hot path: ``LoadedMonitor.tick(values)`` packs the inputs with one
``struct.pack`` and makes ONE C call (``ss_tick``) that sets every input,
steps the monitor and collects the handler calls into a flag array.

Batch path (``replay``; the daemon does not use it): ``tick_batch(rows)``
steps the monitor over ``n`` packed rows in ONE C call (``ss_tick_batch``)
and returns the flags of every row and the indices of the rows with a
violation, so that Python only works on those.  ``pack_columns`` packs one
array per input into such rows (a numpy structured array whose dtype,
``row_dtype``, is the ``=``-packed layout of ``tick``'s ``struct``).  numpy
is imported on first use, so the daemon never loads it.

Values, in ``spec.inputs`` order: ``bool`` inputs take any Python object
(its truth value, 1 byte); ``int64`` inputs take ``int`` (or bool / objects
with ``__index__``) in [-2**63, 2**63) exactly; ``double`` inputs take
``float`` or ``int`` (converted to IEEE double).  A wrong type or an
out-of-range int raises TypeError.

Margins (``spec.margins``, native backend; docs/reference/margins.md): after each
``tick``, ``margins()`` is each requirement's margin at that tick (spec order; after
``tick_batch`` or ``tick_until``, at the last row stepped; 0.0 before a fresh
monitor's first tick, and a reset leaves them until the next tick), and
``tick_batch`` returns every row's margins as well.

Resets: a native monitor has reset functions in C (O(1), no loops).  A
monitor without them (Copilot generates none) is reset by loading a fresh
copy of its library: the ``.so`` is copied to a new file beside it (in the
temporary directory when that place is read-only: a hardened robot mounts /tmp
``noexec``, where a copy could not be mapped) and imported again under the same
module name.  A new
``dlopen`` of a different file (a different inode) maps a new instance with
fresh static state, and CPython caches extension modules by (path, name), so
PyInit runs again.  Each such reset costs a file copy and a ``dlopen``
(milliseconds) and leaves the old copy mapped (Python never unloads extension
modules).  A copy's file is removed as soon as it is loaded: a process that is
killed runs no exit handler, and every killed daemon or fleet worker used to leave
its copies in the temporary directory.  Its inode stays taken while it is mapped,
that is for the rest of the process, so no later copy can get its number and be
taken by ``dlopen`` (which knows a loaded file by device and inode) for an old
instance.  The same copy mechanism makes every LoadedMonitor own its state even
when one library path is loaded twice.
"""

from __future__ import annotations

import numbers
import operator
import os
import shutil
import struct
import tempfile
import threading
from collections.abc import Iterable, Sequence
from importlib.machinery import ExtensionFileLoader
from importlib.util import module_from_spec, spec_from_loader
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, NamedTuple

from monitors.backends.build import STRUCT_CODES, layout, row_size
from monitors.errors import UserError
from monitors.ir.spec import MonitorSpec

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

_I64_MAX = (1 << 63) - 1
# numpy type of each input type in a packed row ("=": native order, no padding).
_NP_CODES = {"bool": "?", "int64": "=i8", "double": "=f8"}

_lock = threading.Lock()
_loaded: set[str] = set()  # resolved paths already dlopen'ed in this process


def _import(path: Path) -> ModuleType:
    """Import the extension at ``path``; a private copy if that file is already loaded."""
    name = path.name.split(".", 1)[0]  # PyInit_<name>, whatever the file is called
    with _lock:
        real = str(path.resolve())
        if real not in _loaded:
            mod = _exec(name, real)
            _loaded.add(real)
            return mod
        try:  # beside the library: a place that can map it, where /tmp may be noexec
            fd, copy = tempfile.mkstemp(prefix=".ss-copy-", suffix=".so", dir=path.parent)
        except OSError:  # a read-only place
            fd, copy = tempfile.mkstemp(prefix="ss-monitor-copy-", suffix=".so")
        try:
            with os.fdopen(fd, "wb") as out, open(real, "rb") as src:
                shutil.copyfileobj(src, out)  # a new inode: dlopen maps a fresh instance
            return _exec(name, copy)
        finally:
            os.unlink(copy)  # mapped, it needs no name (module docstring)


def _exec(name: str, file: str) -> ModuleType:
    loader = ExtensionFileLoader(name, file)
    try:
        mod = module_from_spec(spec_from_loader(name, loader))  # the dlopen
        loader.exec_module(mod)
    except ImportError:
        where = os.path.dirname(file)
        try:
            noexec = bool(os.statvfs(where).f_flag & os.ST_NOEXEC)
        except OSError:
            noexec = False
        if not noexec:
            raise  # a library we built wrong: the internal error it is
        raise UserError(
            "the monitor library cannot be loaded from here: its filesystem is mounted noexec",
            file=where,
            hint="set TMPDIR, --build-dir or -o to a directory whose filesystem allows "
            "executable mappings (the shipped unit builds in its state directory)",
        ) from None
    return mod


class Batch(NamedTuple):
    """What ``LoadedMonitor.tick_batch`` returns."""

    flags: np.ndarray  # uint8, shape (n, requirements): 1 where violated at that row
    violating: np.ndarray  # intp, ascending: the rows with at least one flag
    # float64, shape (n, requirements): each row's margins (None without margins)
    margins: np.ndarray | None = None


def row_dtype(spec: MonitorSpec) -> np.dtype:
    """The numpy structured dtype of one packed input row: fields named like the
    inputs, in ``spec.inputs`` order, no padding (``ss_layout``'s ``row=``)."""
    import numpy as np

    dtype = np.dtype(
        {
            "names": [v.name for v in spec.inputs],
            "formats": [_NP_CODES[v.type] for v in spec.inputs],
        }
    )
    if dtype.itemsize != row_size(spec):
        raise AssertionError(f"row dtype {dtype} is not {row_size(spec)} bytes")
    return dtype


def _column(values: Any, typ: str, name: str, n: int | None) -> npt.NDArray[Any]:
    """One input's column as a numpy array of its row type, converted exactly as
    ``tick``'s ``struct.pack`` converts (TypeError where it would refuse)."""
    import numpy as np

    try:
        a = np.asarray(values)
    except (OverflowError, ValueError):  # Python ints beyond 64 bits
        a = np.array(list(values), dtype=object)
    if a.ndim != 1 or (n is not None and len(a) != n):
        raise ValueError(f"input {name}: expected a sequence of {n} values, got shape {a.shape}")
    if len(a) == 0:  # np.asarray([]) is float64, whatever the input's type
        return np.empty(0, dtype=_NP_CODES[typ])
    kind = a.dtype.kind
    if typ == "bool":
        if kind == "b":
            return a
        if kind in "iuf":
            return a != 0  # NaN is true, as bool(nan)
        return np.fromiter(map(bool, a), dtype=np.bool_, count=len(a))
    if typ == "int64":
        if kind in "bi":
            return a.astype(np.int64)
        if kind == "u":
            if len(a) and int(a.max()) > _I64_MAX:
                raise TypeError(f"input {name}: a value is out of the int64 range")
            return a.astype(np.int64)
        if kind == "O":
            try:
                return np.fromiter(map(operator.index, a), dtype=np.int64, count=len(a))
            except OverflowError:
                raise TypeError(f"input {name}: a value is out of the int64 range") from None
            except TypeError as e:
                raise TypeError(f"input {name}: int64 needs integers ({e})") from None
        raise TypeError(f"input {name}: int64 needs integers, got {a.dtype}")
    if kind in "biuf":
        return a.astype(np.float64)
    if kind == "O" and all(isinstance(x, numbers.Real) for x in a):
        return np.fromiter(map(float, a), dtype=np.float64, count=len(a))
    raise TypeError(f"input {name}: double needs numbers, got {a.dtype}")


class LoadedMonitor:
    """A monitor instance in this process (see the module docstring)."""

    def __init__(self, path: Path, spec: MonitorSpec) -> None:
        self.path = Path(path)
        self.spec = spec
        self.input_names: tuple[str, ...] = tuple(v.name for v in spec.inputs)
        self.requirement_ids: tuple[str, ...] = tuple(r.id for r in spec.requirements)
        self._index = {rid: i for i, rid in enumerate(self.requirement_ids)}
        packing = struct.Struct("=" + "".join(STRUCT_CODES[v.type] for v in spec.inputs))
        self._pack = packing.pack
        # One packed row: what ss_tick reads and ss_tick_batch's stride.
        self.row_size: int = packing.size
        if self.row_size != row_size(spec):
            raise AssertionError(f"struct packing {packing.format} is not {row_size(spec)} bytes")
        self._row_dtype: np.dtype | None = None
        self._zeros = bytes(len(self.requirement_ids))
        self._bind(_import(self.path))

    def _bind(self, mod: ModuleType) -> None:
        ffi, lib = mod.ffi, mod.lib
        got = ffi.string(lib.ss_layout()).decode()
        if got != layout(self.spec):
            raise UserError(
                f"monitor library does not match the spec (library: {got})", file=str(self.path)
            )
        self._module = mod
        self._flags = ffi.new("uint8_t[]", max(1, len(self.requirement_ids)))
        self._flag_view = ffi.buffer(self._flags, len(self.requirement_ids))
        self._tick = lib.ss_tick
        self._tick_batch = lib.ss_tick_batch
        self._tick_until = lib.ss_tick_until
        self._reset = getattr(lib, "ss_reset", None)
        self._reset_req = getattr(lib, "ss_reset_req", None)
        if self.spec.margins:
            n = len(self.requirement_ids)
            self._margin_view = memoryview(ffi.buffer(lib.ss_margins(), 8 * n)).cast("B").cast("d")
            self._tick_batch_m = lib.ss_tick_batch_m

    @property
    def has_margins(self) -> bool:
        """True when the step computes margins (``spec.margins``)."""
        return self.spec.margins

    def margins(self) -> list[float]:
        """Each requirement's margin at the last tick (requirement order); valid
        after each ``tick`` (docs/reference/margins.md)."""
        if not self.spec.margins:
            raise UserError(
                "this monitor computes no margins",
                file=str(self.path),
                hint="build it from a spec with margins on",
            )
        return self._margin_view.tolist()

    @property
    def has_reset(self) -> bool:
        """True when reset() is an O(1) C call (native backend)."""
        return self._reset is not None

    @property
    def has_reset_each(self) -> bool:
        """True when reset_requirement() is available (native backend)."""
        return self._reset_req is not None

    def tick(self, values: Sequence[bool | int | float]) -> bytes:
        """One monitor step.  Returns one byte per requirement (requirement
        order): 1 where the requirement is violated at this tick, else 0."""
        try:
            packed = self._pack(*values)
        except struct.error as e:
            raise TypeError(f"monitor inputs {self.input_names}: {e}") from None
        if self._tick(packed, self._flags) == 0:
            return self._zeros
        return self._flag_view[:]

    @property
    def row_dtype(self) -> np.dtype:
        """numpy dtype of one packed row (see the module docstring)."""
        if self._row_dtype is None:
            self._row_dtype = row_dtype(self.spec)
        return self._row_dtype

    def pack_rows(self, rows: Iterable[Sequence[bool | int | float]]) -> bytes:
        """Rows of values (each as ``tick`` takes them) packed for ``tick_batch``."""
        try:
            return b"".join([self._pack(*values) for values in rows])
        except struct.error as e:
            raise TypeError(f"monitor inputs {self.input_names}: {e}") from None

    def pack_columns(self, columns: Sequence[Any]) -> np.ndarray:
        """One sequence or 1-D array per input (``spec.inputs`` order, equal
        lengths) packed into rows for ``tick_batch``: a structured array of
        ``row_dtype``.  Converts as ``tick`` does; TypeError where it would refuse."""
        import numpy as np

        if len(columns) != len(self.input_names):
            raise ValueError(
                f"expected {len(self.input_names)} columns {self.input_names}, got {len(columns)}"
            )
        if not columns:
            raise ValueError("a monitor without inputs has no columns: give tick_batch n rows")
        n = len(columns[0])
        out = np.empty(n, dtype=self.row_dtype)
        for v, col in zip(self.spec.inputs, columns, strict=True):
            out[v.name] = _column(col, v.type, v.name, n)
        return out

    def tick_batch(self, rows: Any) -> Batch:
        """Step the monitor once per row, in order, in ONE C call: the same
        flags as calling ``tick`` row by row, and the state carries over to the
        next call.  ``rows``: a ``row_dtype`` array (``pack_columns``) or packed
        bytes (``pack_rows``; any buffer of ``n * row_size`` bytes).  Not for two
        threads at once (one monitor state, as ``tick``)."""
        import numpy as np

        ffi = self._module.ffi
        if isinstance(rows, np.ndarray):
            if rows.dtype != self.row_dtype:
                raise TypeError(f"rows have dtype {rows.dtype}, expected {self.row_dtype}")
            if rows.ndim != 1:
                raise ValueError(f"rows must be 1-D, got shape {rows.shape}")
            rows = np.ascontiguousarray(rows)
            n = len(rows)
        else:
            nbytes = memoryview(rows).nbytes
            if self.row_size == 0:
                raise ValueError("a monitor without inputs takes its rows as a row_dtype array")
            n, extra = divmod(nbytes, self.row_size)
            if extra:
                raise ValueError(
                    f"{nbytes} bytes is not a whole number of {self.row_size}-byte rows"
                )
        nreq = len(self.requirement_ids)
        flags = np.empty((n, nreq), dtype=np.uint8)
        found = np.empty(n, dtype=np.uintp)  # size_t
        if self.spec.margins:
            margins = np.empty((n, nreq), dtype=np.float64)
            count = self._tick_batch_m(
                ffi.from_buffer("char[]", rows),
                n,
                ffi.from_buffer("uint8_t[]", flags, require_writable=True),
                ffi.from_buffer("size_t[]", found, require_writable=True),
                ffi.from_buffer("double[]", margins, require_writable=True),
            )
            return Batch(flags, found[:count].astype(np.intp), margins)
        count = self._tick_batch(
            ffi.from_buffer("char[]", rows),
            n,
            ffi.from_buffer("uint8_t[]", flags, require_writable=True),
            ffi.from_buffer("size_t[]", found, require_writable=True),
        )
        return Batch(flags, found[:count].astype(np.intp))

    def tick_until(self, rows: Any) -> tuple[int, bytes]:
        """Step row by row in ONE C call up to and including the first row with a
        violation: (rows stepped, that last row's flags).  The state is exactly
        after the last row stepped, so its violation can be handed to the policies
        before the next row (``replay``)."""
        import numpy as np

        if not isinstance(rows, np.ndarray) or rows.dtype != self.row_dtype or rows.ndim != 1:
            raise TypeError(f"rows must be a 1-D array of {self.row_dtype}")
        rows = np.ascontiguousarray(rows)
        ffi = self._module.ffi
        flags = self._module.ffi.new("uint8_t[]", max(1, len(self.requirement_ids)))
        n = self._tick_until(ffi.from_buffer("char[]", rows), len(rows), flags)
        return int(n), bytes(ffi.buffer(flags, len(self.requirement_ids)))

    def reset(self) -> None:
        """Every requirement back to tick 0 (as if freshly loaded)."""
        if self._reset is not None:
            self._reset()
        else:
            self._bind(_import(self.path))  # fresh copy: see module docstring

    def reset_requirement(self, req: int | str) -> None:
        """Only requirement ``req`` (index or id) back to tick 0; the others keep
        their state.  Needs a native monitor (has_reset_each)."""
        i = self._index[req] if isinstance(req, str) else int(req)
        if not 0 <= i < len(self.requirement_ids):
            raise IndexError(f"no requirement {req!r}")
        if self._reset_req is None:
            raise UserError(
                f"cannot reset requirement {self.requirement_ids[i]} alone: this monitor has "
                "no per-requirement reset",
                file=str(self.path),
                hint="use the native backend, or reset() the whole monitor",
            )
        self._reset_req(i)


def load_monitor(path: Path, spec: MonitorSpec) -> LoadedMonitor:
    """Load the extension built by ``build_library(spec, ...)``."""
    return LoadedMonitor(path, spec)


def compile_spec(spec: MonitorSpec, out_dir: Path) -> LoadedMonitor:
    """Native backend in one call: write monitor.c/.h, build and load them."""
    from monitors.backends.build import build_library
    from monitors.backends.c99 import write_c

    out_dir = Path(out_dir)
    c_path, _ = write_c(spec, out_dir)
    lib = build_library(spec, [c_path], out_dir, out_dir, reset=True, reset_each=True)
    return load_monitor(lib, spec)
