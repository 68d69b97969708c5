"""Compile monitor C (native or Copilot-generated) into a cffi extension module.

One shared object per monitor, built in cffi's API (compiled) mode: no libffi
closures at run time, so it loads under systemd's ``MemoryDenyWriteExecute``.
It contains

- the monitor's own C files (``monitor.c`` or Copilot's ``<name>.c``);
- a generated host shim (``ss_host.c``) that *defines* the inputs and the
  ``handler<ID>`` functions the monitor declares ``extern``; each handler sets
  its requirement's slot in a caller-supplied flag array, so Python never runs
  a callback;
- the cffi wrapper module, exporting only ``PyInit_<module>``.

C names the shim uses (a Copilot spec must use the same): input ``v`` is
``c_name(v.name)`` of C type ``bool`` / ``int64_t`` / ``double``; requirement
``r``'s handler is ``c_name(r.handler)``; the step function is
``spec.step_name``; with ``reset=True`` the monitor defines ``spec.reset_name``
and with ``reset_each=True`` ``reset_each_name(spec, r)`` for every requirement.

Functions the shim exposes to Python (see load.py):
  ``int ss_tick(const char *in, uint8_t *flags)``: copies the packed inputs
      (``spec.inputs`` order, native byte order, no padding: bool 1 byte,
      int64 8 bytes, double 8 bytes) into the globals, clears ``flags``, calls
      the step function once, returns the number of violated requirements;
  ``size_t ss_tick_batch(const char *in, size_t n, uint8_t *flags, size_t *rows)``:
      ``ss_tick`` for ``n`` rows packed one after another (stride: the row
      size), ONE call for a recorded trace (``replay``; the daemon steps one
      tick at a time).  ``flags`` receives ``n`` rows of one byte per
      requirement; ``rows`` (``n`` slots, or NULL) receives the indices of
      the rows with a violation, ascending; returns how many there are;
  ``size_t ss_tick_until(const char *in, size_t n, uint8_t *flags)``: ``ss_tick``
      for rows in order up to and including the first with a violation; returns
      the rows stepped, ``flags`` holds the last one's;
  ``void ss_reset(void)`` / ``void ss_reset_req(int i)`` when available;
  with ``spec.margins``: ``const double *ss_margins(void)``, the monitor's array of
      the requirements' margins after the last step, and ``size_t
      ss_tick_batch_m(in, n, flags, rows, margins)``, ``ss_tick_batch`` that also
      copies each row's margins into ``margins`` (``n`` rows of one double per
      requirement);
  ``const char *ss_layout(void)``: the input/requirement layout and the row
      size, so that a library is never driven with another spec's packing.

Linking: every object is compiled with ``-fvisibility=hidden
-fno-semantic-interposition`` and linked with ``-Wl,-Bsymbolic``, so the
monitor's ``step`` binds to itself and not to glibc's legacy ``step`` symbol,
and helpers that Copilot does not make ``static`` (``s0_get`` ...) never
collide between monitors in one process.  The module name is a hash of all
sources and flags, so different monitors get different names; the library is
reused when the same sources are built again into the same ``out_dir``.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import re
import shutil
import subprocess
import sysconfig
from collections.abc import Iterator
from importlib.machinery import EXTENSION_SUFFIXES
from pathlib import Path

from monitors.backends.c99 import margins_name, reset_each_name
from monitors.errors import UserError
from monitors.ir.spec import MonitorSpec, c_name

# Values are packed with Python's struct module in this format (load.py).
STRUCT_CODES = {"bool": "?", "int64": "q", "double": "d"}
_SIZES = {"bool": 1, "int64": 8, "double": 8}
_C_TYPES = {"bool": "bool", "int64": "int64_t", "double": "double"}

CDEF = """
int ss_tick(const char *in, uint8_t *flags);
size_t ss_tick_batch(const char *in, size_t n, uint8_t *flags, size_t *rows);
size_t ss_tick_until(const char *in, size_t n, uint8_t *flags);
const char *ss_layout(void);
"""
CDEF_RESET = "void ss_reset(void);\n"
CDEF_RESET_EACH = "void ss_reset_req(int i);\n"
CDEF_MARGINS = """const double *ss_margins(void);
size_t ss_tick_batch_m(const char *in, size_t n, uint8_t *flags, size_t *rows, double *margins);
"""

# Every object: symbols bound inside the library (see module docstring).
# -ffp-contract=off: no fused multiply-add, so double results equal the interpreter's
# on every target (FMA skips a rounding step).
# -O1: on 1,000 generated requirements gcc takes 4.7 s instead of 12.4 s at -O2, and
# the step is as fast or faster (18-19 ns against 20-21 ns per requirement per tick;
# docs/BENCHMARKS.md, "Scaling"): straight-line code gains nothing from -O2's passes.
_CFLAGS = [
    "-O1",
    "-fPIC",
    "-fvisibility=hidden",
    "-fno-semantic-interposition",
    "-ffp-contract=off",
]
_LDFLAGS = ["-shared", "-Wl,-Bsymbolic", "-Wl,-z,noexecstack"]


def row_size(spec: MonitorSpec) -> int:
    """Bytes of one packed input row (no padding): ss_tick_batch's stride."""
    return sum(_SIZES[v.type] for v in spec.inputs)


def layout(spec: MonitorSpec) -> str:
    """The packing contract between the shim and load.py, as text."""
    ins = ",".join(f"{STRUCT_CODES[v.type]}{c_name(v.name)}" for v in spec.inputs)
    reqs = ",".join(c_name(r.handler) for r in spec.requirements)
    margins = f";margins={spec.bool_margin!r}" if spec.margins else ""
    return f"in={ins};row={row_size(spec)};out={reqs}{margins}"


def host_source(spec: MonitorSpec, *, reset: bool, reset_each: bool) -> str:
    """The generated host shim (plain C99, no Python headers, so that input
    names such as ``log`` or ``time`` cannot meet libc declarations)."""
    out = [
        *_host_declarations(spec, reset=reset, reset_each=reset_each),
        *_host_load_and_tick(spec),
        *_host_batches(spec),
        f'const char *ss_layout(void) {{ return "{layout(spec)}"; }}',
    ]
    if spec.margins:
        out += _host_margins(spec)
    if reset:
        out.append(f"void ss_reset(void) {{ {spec.reset_name}(); }}")
    if reset_each:
        out += ["void ss_reset_req(int i)", "{", "    switch (i) {"]
        for i, r in enumerate(spec.requirements):
            out.append(f"    case {i}: {reset_each_name(spec, r)}(); break;")
        out += ["    default: break;", "    }", "}"]
    return "\n".join(out) + "\n"


def _host_declarations(spec: MonitorSpec, *, reset: bool, reset_each: bool) -> list[str]:
    """The shim's includes, the monitor's inputs and functions, the entry points,
    and the handlers that flag their requirement."""
    out = [
        "/* Host shim generated by safety-supervisor: defines the monitor's inputs and",
        "   handlers and the entry points used from Python (one tick, or a batch). */",
        "#include <stdbool.h>",
        "#include <stddef.h>",
        "#include <stdint.h>",
        "#include <string.h>",
        "",
    ]
    for v in spec.inputs:
        out.append(f"{_C_TYPES[v.type]} {c_name(v.name)};")
    out.append(f"void {spec.step_name}(void);")
    if reset:
        out.append(f"void {spec.reset_name}(void);")
    if reset_each:
        for r in spec.requirements:
            out.append(f"void {reset_each_name(spec, r)}(void);")
    out += [
        "int ss_tick(const char *ss_in, uint8_t *ss_flags);",
        "size_t ss_tick_batch(const char *ss_in, size_t ss_n, uint8_t *ss_flags, size_t *ss_rows);",
        "size_t ss_tick_until(const char *ss_in, size_t ss_n, uint8_t *ss_flags);",
        "const char *ss_layout(void);",
        "void ss_reset(void);",
        "void ss_reset_req(int i);",
        "",
        "static uint8_t *ss__out;",
        "static int ss__count;",
        "",
    ]
    for i, r in enumerate(spec.requirements):
        out.append(f"void {c_name(r.handler)}(void);")
        out.append(f"void {c_name(r.handler)}(void) {{ ss__out[{i}] = 1u; ss__count++; }}")
    return out


def _host_margins(spec: MonitorSpec) -> list[str]:
    """``ss_margins`` and ``ss_tick_batch_m`` (see the module docstring)."""
    nreq = max(1, len(spec.requirements))
    name = margins_name(spec)
    return [
        f"extern double {name}[{nreq}];",
        "const double *ss_margins(void);",
        f"const double *ss_margins(void) {{ return {name}; }}",
        "size_t ss_tick_batch_m(const char *ss_in, size_t ss_n, uint8_t *ss_flags, "
        "size_t *ss_rows, double *ss_margins_out);",
        "size_t ss_tick_batch_m(const char *ss_in, size_t ss_n, uint8_t *ss_flags, "
        "size_t *ss_rows, double *ss_margins_out)",
        "{",
        "    size_t ss_i, ss_found = 0;",
        f"    if (ss_n != 0) memset(ss_flags, 0, ss_n * {len(spec.requirements)}u);",
        "    for (ss_i = 0; ss_i < ss_n; ss_i++) {",
        f"        ss__out = ss_flags + ss_i * {len(spec.requirements)}u;",
        "        ss__count = 0;",
        f"        ss__load(ss_in + ss_i * {row_size(spec)}u);",
        f"        {spec.step_name}();",
        f"        memcpy(ss_margins_out + ss_i * {len(spec.requirements)}u, {name}, "
        f"{8 * len(spec.requirements)}u);",
        "        if (ss__count != 0) {",
        "            if (ss_rows != NULL) ss_rows[ss_found] = ss_i;",
        "            ss_found++;",
        "        }",
        "    }",
        "    return ss_found;",
        "}",
    ]


def _host_load_and_tick(spec: MonitorSpec) -> list[str]:
    """``ss__load`` (one packed row into the input globals) and ``ss_tick``."""
    # One row of packed inputs into the globals; shared by both entry points so
    # that a batch steps exactly as ss_tick does.  Parameters and locals are
    # ss_-prefixed (a reserved prefix) so that no input name can shadow them.
    out = ["", "static void ss__load(const char *ss_in)", "{"]
    off = 0
    for v in spec.inputs:
        name = c_name(v.name)
        if v.type == "bool":
            out.append(f"    {name} = ss_in[{off}] != 0;")
        else:
            out.append(f"    memcpy(&{name}, ss_in + {off}, 8);")
        off += _SIZES[v.type]
    if not spec.inputs:
        out.append("    (void)ss_in;")
    out += ["}", ""]
    out += ["int ss_tick(const char *ss_in, uint8_t *ss_flags)", "{"]
    out += ["    ss__out = ss_flags;", "    ss__count = 0;"]
    out += [f"    ss_flags[{i}] = 0u;" for i in range(len(spec.requirements))]
    out += ["    ss__load(ss_in);", f"    {spec.step_name}();", "    return ss__count;", "}", ""]
    return out


def _host_batches(spec: MonitorSpec) -> list[str]:
    """``ss_tick_batch`` and ``ss_tick_until``: the shim may loop (the monitor's step
    stays loop-free, see docs/reference/c-interface.md); no allocation, flags
    cleared once up front."""
    nreq = len(spec.requirements)
    out = [
        "size_t ss_tick_batch(const char *ss_in, size_t ss_n, uint8_t *ss_flags, size_t *ss_rows)",
        "{",
        "    size_t ss_i, ss_found = 0;",
    ]
    if nreq:
        out.append(f"    if (ss_n != 0) memset(ss_flags, 0, ss_n * {nreq}u);")
    else:
        out.append("    (void)ss_flags;")
    out += [
        "    for (ss_i = 0; ss_i < ss_n; ss_i++) {",
        f"        ss__out = ss_flags + ss_i * {nreq}u;" if nreq else "        ss__out = ss_flags;",
        "        ss__count = 0;",
        f"        ss__load(ss_in + ss_i * {row_size(spec)}u);",
        f"        {spec.step_name}();",
        "        if (ss__count != 0) {",
        "            if (ss_rows != NULL) ss_rows[ss_found] = ss_i;",
        "            ss_found++;",
        "        }",
        "    }",
        "    return ss_found;",
        "}",
        "",
        # Up to and including the first row with a violation: replay hands that
        # tick to the policies with the monitor's state exactly after it.
        "size_t ss_tick_until(const char *ss_in, size_t ss_n, uint8_t *ss_flags)",
        "{",
        "    size_t ss_i;",
        "    ss__out = ss_flags;",
        "    for (ss_i = 0; ss_i < ss_n; ss_i++) {",
        "        ss__count = 0;",
    ]
    out += [f"        ss_flags[{i}] = 0u;" for i in range(nreq)]
    out += [
        f"        ss__load(ss_in + ss_i * {row_size(spec)}u);",
        f"        {spec.step_name}();",
        "        if (ss__count != 0) return ss_i + 1;",
        "    }",
        "    return ss_n;",
        "}",
        "",
    ]
    return out


def _cdef(reset: bool, reset_each: bool, margins: bool = False) -> str:
    return (
        CDEF
        + (CDEF_RESET if reset else "")
        + (CDEF_RESET_EACH if reset_each else "")
        + (CDEF_MARGINS if margins else "")
    )


def _compiler() -> str:
    return os.environ.get("CC") or shutil.which("cc") or "gcc"


def build_identity(spec: MonitorSpec, *, reset: bool, reset_each: bool) -> str:
    """Everything besides the monitor's own C that decides the library built for
    ``spec``: the compiler (resolved path and ``--version``), the flags, the host
    shim, cffi's version and the Python ABI.  The start-up cache keys on it
    (supervisor/cache.py), so a new compiler, cffi or Python rebuilds."""
    import sys
    from importlib.metadata import version

    cc = _compiler()
    path = shutil.which(cc) or cc
    try:
        r = subprocess.run([cc, "--version"], capture_output=True, text=True, timeout=30)
        cc_version = (r.stdout.splitlines() or [f"exit {r.returncode}"])[0]
    except (OSError, subprocess.SubprocessError) as e:
        cc_version = f"unavailable: {e}"
    parts = [
        f"cc={cc} {os.path.realpath(path)} {cc_version}",
        f"cflags={_CFLAGS} ldflags={_LDFLAGS}",
        f"cffi={version('cffi')}",
        f"python={sys.implementation.cache_tag} {EXTENSION_SUFFIXES[0]} {sys.version}",
        f"include={sysconfig.get_paths()['include']}",
        host_source(spec, reset=reset, reset_each=reset_each),
        _cdef(reset, reset_each, spec.margins),
    ]
    return "\n".join(parts)


def _first_error(stderr: str) -> tuple[str, str | None, int | None, int | None]:
    """The compiler's first error line, split into (message, file, line, col)."""
    lines = stderr.splitlines()
    errors = [x for x in lines if re.search(r":\s*(fatal )?error:", x)]
    line = (errors or [x for x in lines if "error" in x.lower()] or lines or ["unknown error"])[0]
    m = re.match(r"^(.*?):(\d+):(?:(\d+):)?\s*(?:fatal )?error:\s*(.*)$", line)
    if m:
        return m.group(4), m.group(1), int(m.group(2)), int(m.group(3)) if m.group(3) else None
    return line.strip(), None, None, None


@contextlib.contextmanager
def building(where: Path) -> Iterator[None]:
    """A build's own writes (its C, its objects, its library): a full disk or a place
    this user cannot write is one line naming the build's directory, not a bug."""
    try:
        yield
    except OSError as e:
        # mkdir of a path that is a file says "File exists": the user would look for a
        # file to delete, not for the directory they meant
        why = "not a directory" if isinstance(e, FileExistsError) else e.strerror or e
        raise UserError(
            f"cannot build the monitor here: {why}",
            file=str(where),
            hint="TMPDIR, --build-dir or -o: a directory with room that this user can write",
        ) from None


def _start(cmd: list[str]) -> subprocess.Popen[str]:
    """The compiler ``cmd[0]`` started, or one line: a robot's image often has none."""
    try:
        return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    except OSError as e:
        raise UserError(
            f"cannot run the C compiler: {e.strerror or e}",
            file=cmd[0],
            hint="install one (apt-get install gcc) or set CC to a C compiler",
        ) from None


def _run(cmd: list[str], what: str) -> None:
    with _start(cmd) as p:
        out, err = p.communicate()
    if p.returncode != 0:
        msg, file, line, col = _first_error(err or out)
        raise UserError(
            f"C compiler failed on {what}: {msg}", file=file or what, line=line, col=col
        )


def build_library(
    spec: MonitorSpec,
    c_files: list[Path],
    include_dir: Path,
    out_dir: Path,
    *,
    reset: bool,
    reset_each: bool,
) -> Path:
    """Compile ``c_files`` plus the host shim into a cffi extension in ``out_dir``.

    ``reset``/``reset_each``: whether the C defines ``spec.reset_name`` and the
    per-requirement reset functions (the native backend does, Copilot does not).
    Returns the path of the extension module (``_ssmon_<hash><EXT_SUFFIX>``).
    Compiler errors become UserError carrying the compiler's first error line.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if reset_each and not reset:
        raise ValueError("reset_each needs reset")
    host = host_source(spec, reset=reset, reset_each=reset_each)
    cdef = _cdef(reset, reset_each, spec.margins)
    cc = _compiler()
    digest = hashlib.sha256()
    for part in [cc, *_CFLAGS, *_LDFLAGS, host, cdef, str(Path(include_dir).resolve())]:
        digest.update(part.encode() + b"\0")
    for f in c_files:
        digest.update(Path(f).read_bytes() + b"\0")
    for h in sorted(Path(include_dir).glob("*.h")):
        digest.update(h.name.encode() + h.read_bytes() + b"\0")
    module = "_ssmon_" + digest.hexdigest()[:20]
    target = out_dir / (module + EXTENSION_SUFFIXES[0])
    if target.exists():
        return target

    work = out_dir / f"{module}.{os.getpid()}.build"  # concurrent builders never share files
    work.mkdir(exist_ok=True)
    try:
        (work / "ss_host.c").write_text(host)
        from cffi import FFI  # only to build: a cached library needs no cffi module

        ffi = FFI()
        ffi.cdef(cdef)
        ffi.set_source(module, "#include <stddef.h>\n#include <stdint.h>\n" + cdef)
        with contextlib.redirect_stdout(io.StringIO()):  # cffi prints "generating ..."
            ffi.emit_c_code(str(work / f"{module}.c"))

        py_include = sysconfig.get_paths()["include"]
        objects: list[Path] = []
        jobs: list[tuple[list[str], str]] = []
        for src in [*map(Path, c_files), work / "ss_host.c"]:
            obj = work / (src.stem + f".{len(objects)}.o")
            objects.append(obj)
            cmd = [cc, "-std=c99", *_CFLAGS, "-I", str(include_dir), "-c", str(src), "-o", str(obj)]
            jobs.append((cmd, src.name))
        obj = work / f"{module}.o"
        objects.append(obj)
        jobs.append(
            (
                [cc, *_CFLAGS, "-I", py_include, "-c", str(work / f"{module}.c"), "-o", str(obj)],
                "cffi module",
            )
        )
        # Compile in parallel: the Python.h translation unit dominates build time.
        procs: list[tuple[subprocess.Popen[str], str]] = []
        try:
            for cmd, what in jobs:
                procs.append((_start(cmd), what))
        except UserError:  # none left running behind the error
            for p, _ in procs:
                p.kill()
                p.communicate()
            raise
        for p, what in procs:
            _, err = p.communicate()
            if p.returncode != 0:
                msg, file, line, col = _first_error(err)
                raise UserError(
                    f"C compiler failed on {what}: {msg}", file=file or what, line=line, col=col
                )
        tmp = target.with_name(f"{target.name}.{os.getpid()}.tmp")
        _run([cc, *_LDFLAGS, *map(str, objects), "-lm", "-o", str(tmp)], "link")
        tmp.replace(target)  # atomic: a concurrent loader never sees half a library
        return target
    finally:  # its C and objects: the library is the build's one product
        shutil.rmtree(work, ignore_errors=True)
