"""Load a monitor library built by build.py and drive it from Python.

Hot path: ``LoadedMonitor.tick(values)`` packs the inputs with one
``struct.pack`` and makes ONE C call (``ss_tick``) that sets every input,
steps the monitor and collects the handler calls into a flag array.

Values, in ``spec.inputs`` order: ``bool`` inputs take any Python object
(its truth value, 1 byte); ``int64`` inputs take ``int`` (or bool / objects
with ``__index__``) in [-2**63, 2**63) exactly; ``double`` inputs take
``float`` or ``int`` (converted to IEEE double).  A wrong type or an
out-of-range int raises TypeError.

Resets: a native monitor has reset functions in C (O(1), no loops).  A
monitor without them (Copilot generates none) is reset by loading a fresh
copy of its library: the ``.so`` is copied to a new file in a per-process
temporary directory and imported again under the same module name.  A new
``dlopen`` of a different file (a different inode) maps a new instance with
fresh static state, and CPython caches extension modules by (path, name), so
PyInit runs again.  Each such reset costs a file copy and a ``dlopen``
(milliseconds) and leaves the old copy mapped (Python never unloads extension
modules); the copies are kept until the process exits so that a reused inode
number can never make ``dlopen`` hand back an old instance.  The same copy
mechanism makes every LoadedMonitor own its state even when one library path
is loaded twice.
"""

from __future__ import annotations

import atexit
import itertools
import shutil
import struct
import tempfile
import threading
from collections.abc import Sequence
from importlib.machinery import ExtensionFileLoader
from importlib.util import module_from_spec, spec_from_loader
from pathlib import Path
from types import ModuleType

from monitors.backends.build import STRUCT_CODES, layout
from monitors.errors import UserError
from monitors.ir.spec import MonitorSpec

_lock = threading.Lock()
_loaded: set[str] = set()  # resolved paths already dlopen'ed in this process
_copy_dir: Path | None = None
_copies = itertools.count()


def _private_dir() -> Path:
    global _copy_dir
    if _copy_dir is None:
        _copy_dir = Path(tempfile.mkdtemp(prefix="ss-monitor-copies-"))
        atexit.register(shutil.rmtree, _copy_dir, True)
    return _copy_dir


def _import(path: Path) -> ModuleType:
    """Import the extension at ``path``; a private copy if that file is already loaded."""
    name = path.name.split(".", 1)[0]
    with _lock:
        real = str(path.resolve())
        if real in _loaded:
            copy_dir = _private_dir() / str(next(_copies))
            copy_dir.mkdir()
            path = copy_dir / path.name
            shutil.copyfile(real, path)  # a new inode: dlopen maps a fresh instance
            real = str(path.resolve())
        loader = ExtensionFileLoader(name, real)
        mod = module_from_spec(spec_from_loader(name, loader))
        loader.exec_module(mod)
        _loaded.add(real)
    return mod


class LoadedMonitor:
    """A monitor instance in this process (see the module docstring)."""

    def __init__(self, path: Path, spec: MonitorSpec) -> None:
        self.path = Path(path)
        self.spec = spec
        self.input_names: tuple[str, ...] = tuple(v.name for v in spec.inputs)
        self.requirement_ids: tuple[str, ...] = tuple(r.id for r in spec.requirements)
        self._index = {rid: i for i, rid in enumerate(self.requirement_ids)}
        self._pack = struct.Struct("=" + "".join(STRUCT_CODES[v.type] for v in spec.inputs)).pack
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
        self._reset = getattr(lib, "ss_reset", None)
        self._reset_req = getattr(lib, "ss_reset_req", None)

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
