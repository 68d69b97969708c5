"""The native C99 backend against the reference interpreter, with real gcc and cffi.

Random formulas over every operator and random traces with edge values: the
compiled monitor's handler flags must equal ``not verdict`` at every tick, also
after a full reset and after resetting one requirement mid-trace.  Plus the
hard real-time properties of the generated C and the linking guarantees.
"""

from __future__ import annotations

import ctypes
import math
import re
import shutil
import subprocess
import tempfile
import textwrap
from pathlib import Path

import pytest
from harness import BOOLS, I64_MAX, I64_MIN, INPUTS, INTS, REALS, make_trace, oracle, run  # noqa: E402
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from monitors.backends.build import build_library, host_source
from monitors.backends.c99 import generate, write_c
from monitors.backends.load import compile_spec, load_monitor
from monitors.errors import UserError
from monitors.ir.formula import (
    ARITH_FUNCTIONS,
    BinOp,
    Call,
    Const,
    Formula,
    Neg,
    Not,
    Past,
    Since,
    Var,
    parse_formula,
)
from monitors.ir.spec import Define, MonitorSpec, RequirementSpec, VarDecl, c_name

# a non-temporal define (a C local) and a temporal one (expanded per requirement)
DEFINES = (
    Define("big", "bool", parse_formula("i0 > 3")),
    Define("rose", "bool", parse_formula("b0 & (Y (! b0))")),
)
SETTINGS = settings(
    max_examples=100,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


# ------------------------------------------------------------------ formulas


def bounds(draw: st.DrawFn, max_bound: int) -> tuple[int | None, int | None]:
    kind = draw(st.integers(0, 9))
    if kind < 2:
        return None, None
    lo = draw(st.integers(0, max_bound))
    if kind < 4:
        return lo, None  # [lo, inf]
    if kind == 4:
        return lo, max(0, lo - draw(st.integers(1, 3)))  # empty window
    return lo, lo + draw(st.integers(0, max_bound))


@st.composite
def num_f(draw: st.DrawFn, depth: int, real: bool) -> Formula:
    if depth <= 0 or draw(st.integers(0, 3)) == 0:
        k = draw(st.integers(0, 5))
        if k == 0:
            return Var(draw(st.sampled_from(BOOLS)))  # bools count as 0/1
        if k == 1:
            if real:
                return Const(draw(st.sampled_from([0.0, -0.0, 0.5, 3.0, -2.5, 1e300, 1e999])))
            return Const(draw(st.sampled_from([0, 1, -1, 3, 7, I64_MIN, I64_MAX])))
        if real and draw(st.booleans()):
            return Var(draw(st.sampled_from(REALS)))
        return Var(draw(st.sampled_from(INTS)))
    k = draw(st.integers(0, 7))
    if k == 0:
        return Neg(draw(num_f(depth - 1, real)))
    if k == 1:
        base = draw(num_f(depth - 1, real))
        if real and draw(st.booleans()):
            exponent = draw(
                st.sampled_from(
                    [Var("d0"), Var("d1"), Const(0.5), Const(2.0), Const(-1.0), Const(-0.0)]
                )
            )
            return BinOp("^", base, exponent)
        return BinOp("^", base, Const(draw(st.integers(0, 63))))
    if k == 2:
        name = draw(st.sampled_from(sorted(ARITH_FUNCTIONS)))
        args = [draw(num_f(depth - 1, real)) for _ in range(ARITH_FUNCTIONS[name])]
        return Call(name, tuple(args))
    op = draw(st.sampled_from(["+", "-", "*", "/", "mod"]))
    return BinOp(op, draw(num_f(depth - 1, real)), draw(num_f(depth - 1, real)))


@st.composite
def bool_f(draw: st.DrawFn, depth: int, max_bound: int = 12) -> Formula:
    if depth <= 0 or draw(st.integers(0, 4)) == 0:
        k = draw(st.integers(0, 9))
        if k == 0:
            return Const(draw(st.booleans()))
        if k == 1:
            return Var(draw(st.sampled_from(["big", "rose"])))
        if k < 4:
            real = draw(st.booleans())
            op = draw(st.sampled_from(["=", "!=", "<", "<=", ">", ">="]))
            return BinOp(op, draw(num_f(2, real)), draw(num_f(2, real)))
        return Var(draw(st.sampled_from(BOOLS)))
    k = draw(st.integers(0, 9))
    sub = bool_f(depth - 1, max_bound)
    if k == 0:
        return Not(draw(sub))
    if k < 3:
        op = draw(st.sampled_from(["&", "|", "xor", "->", "<->"]))
        return BinOp(op, draw(sub), draw(sub))
    if k < 7:
        op = draw(st.sampled_from(["Y", "Z", "H", "O"]))
        lo, hi = bounds(draw, max_bound) if op in "HO" else (None, None)
        return Past(op, draw(sub), lo, hi)
    lo, hi = bounds(draw, max_bound)
    return Since(draw(st.sampled_from(["S", "T"])), draw(sub), draw(sub), lo, hi)


# a FRET 'within 5 ticks' response: a pending obligation for the reset tests
WITHIN = parse_formula("H ((O[5,5] ((b1 & (Y (! b1))) | (b1 & FTP))) -> (O[0,5] b2))")


def make_spec(formulas: list[Formula], prefix: str = "") -> MonitorSpec:
    reqs = tuple(RequirementSpec(f"R{i}", f) for i, f in enumerate(formulas))
    return MonitorSpec("test", INPUTS, reqs, DEFINES, prefix=prefix)


def assert_same(
    got: list[list[bool]], want: list[list[bool]], spec: MonitorSpec, trace: list, what: str
) -> None:
    for i, (g, w) in enumerate(zip(got, want, strict=True)):
        if g != w:
            tick = next(t for t in range(len(g)) if g[t] != w[t])
            raise AssertionError(
                f"{what}: requirement {spec.requirements[i].id} = {spec.expanded(spec.requirements[i])}"
                f"\n  first difference at tick {tick}: C violated={g[tick]}, interpreter violated={w[tick]}"
                f"\n  trace[{max(0, tick - 3)}:{tick + 1}] = {trace[max(0, tick - 3) : tick + 1]}"
            )


# ------------------------------------------------------------------ property tests


@pytest.mark.slow
@SETTINGS
@given(
    formulas=st.lists(bool_f(4), min_size=10, max_size=16),
    seed=st.integers(0, 2**32),
    n=st.integers(1, 300),
    cut=st.floats(0, 1),
    victim=st.integers(0, 15),
)
def test_compiled_monitor_matches_interpreter(
    tmp_path_factory, formulas, seed, n, cut, victim
) -> None:
    formulas = [*formulas, WITHIN]
    spec = make_spec(formulas)
    trace = make_trace(seed, n)
    mon = compile_spec(spec, tmp_path_factory.mktemp("mon"))
    full = oracle(spec, trace)

    # fresh monitor over the whole trace
    assert_same(run(mon, spec, trace), full, spec, trace, "fresh")

    # monitor_reset mid-trace: like a fresh monitor on the rest of the trace
    k = int(cut * n)
    mon.reset()
    assert_same(run(mon, spec, trace[:k]), [w[:k] for w in full], spec, trace, "prefix")
    mon.reset()
    rest = oracle(spec, trace[k:])
    assert_same(run(mon, spec, trace[k:]), rest, spec, trace[k:], "after reset")

    # reset one requirement mid-trace: it restarts, the others (WITHIN among them) do not
    v = victim % len(formulas)
    mon.reset()
    run(mon, spec, trace[:k])
    mon.reset_requirement(spec.requirements[v].id)
    want = [rest[i] if i == v else w[k:] for i, w in enumerate(full)]
    assert_same(run(mon, spec, trace[k:]), want, spec, trace[k:], f"after resetting R{v}")


@pytest.mark.slow
@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    formulas=st.lists(bool_f(3, max_bound=150), min_size=8, max_size=12),
    seed=st.integers(0, 2**32),
    n=st.integers(150, 400),
)
def test_long_bounds_use_ring_buffers_correctly(tmp_path_factory, formulas, seed, n) -> None:
    # bounds above 64 ticks take the ring-buffer delay line instead of the shift register
    formulas = [*formulas, parse_formula("O[70,90] b0"), parse_formula("b1 S[100,140] b0")]
    spec = make_spec(formulas)
    trace = make_trace(seed, n)
    mon = compile_spec(spec, tmp_path_factory.mktemp("long"))
    assert_same(run(mon, spec, trace), oracle(spec, trace), spec, trace, "long bounds")
    k = n // 3
    mon.reset()
    run(mon, spec, trace[:k])
    mon.reset()
    assert_same(run(mon, spec, trace[k:]), oracle(spec, trace[k:]), spec, trace[k:], "reset")


# ------------------------------------------------------------------ resets


def _row(b1: bool = False, b2: bool = False, b0: bool = False) -> list:
    return [b0, b1, b2, 0, 0, 0.0, 0.0]


def test_resetting_one_requirement_keeps_anothers_pending_within(tmp_path) -> None:
    spec = make_spec([parse_formula("H b0"), WITHIN])
    mon = compile_spec(spec, tmp_path)
    assert mon.tick(_row(b1=True)) == b"\x01\x00"  # R0 violated; R1: trigger at tick 0
    for _ in range(2):
        assert mon.tick(_row(b0=True)) == b"\x01\x00"  # H b0 stays latched
    mon.reset_requirement("R0")  # must not cancel R1's running 5-tick timer
    flags = [mon.tick(_row(b0=True)) for _ in range(4)]
    assert flags == [b"\x00\x00", b"\x00\x00", b"\x00\x01", b"\x00\x01"]  # deadline at tick 5


def test_reset_restores_tick_zero(tmp_path) -> None:
    spec = make_spec([parse_formula("Y b0"), parse_formula("! (Z b0)"), parse_formula("O[2,4] b0")])
    mon = compile_spec(spec, tmp_path)
    first = [mon.tick(_row(b0=True)) for _ in range(6)]
    mon.reset()
    assert [mon.tick(_row(b0=True)) for _ in range(6)] == first
    assert first[0] == b"\x01\x01\x01"  # Y false, Z true at tick 0


def test_monitor_without_reset_functions_resets_by_fresh_copy(tmp_path) -> None:
    # what a Copilot monitor looks like to build/load: no reset functions in the C
    spec = make_spec([parse_formula("Y b0"), parse_formula("H b0")])
    c_path, _ = write_c(spec, tmp_path / "src")
    lib = build_library(spec, [c_path], tmp_path / "src", tmp_path, reset=False, reset_each=False)
    mon = load_monitor(lib, spec)
    other = load_monitor(lib, spec)  # same file again: must get its own state
    assert not mon.has_reset and not mon.has_reset_each
    assert mon.tick(_row(b0=False)) == b"\x01\x01"
    assert mon.tick(_row(b0=True)) == b"\x01\x01"  # H latched
    mon.reset()
    assert mon.tick(_row(b0=True)) == b"\x01\x00"  # fresh: Y false at tick 0, H not latched
    assert mon.tick(_row(b0=True)) == b"\x00\x00"
    assert other.tick(_row(b0=True)) == b"\x01\x00"  # untouched by mon's ticks and reset
    with pytest.raises(UserError, match="per-requirement reset"):
        mon.reset_requirement(0)


def test_a_fresh_copy_leaves_no_file_behind(tmp_path) -> None:
    # A copy is mapped for the rest of the process (CPython never unloads an extension),
    # and a process that is killed runs no exit handler: a copy's file that outlived its
    # dlopen was left in the temporary directory by every killed daemon and fleet worker.
    spec = make_spec([parse_formula("Y b0")])
    c_path, _ = write_c(spec, tmp_path / "src")
    lib = build_library(spec, [c_path], tmp_path / "src", tmp_path, reset=False, reset_each=False)
    mon = load_monitor(lib, spec)
    load_monitor(lib, spec)  # a second instance: a copy
    mon.reset()  # and a fresh one: another copy
    assert mon.tick(_row(b0=True)) == b"\x01"  # fresh: Y false at tick 0
    content = lib.read_bytes()
    mapped = {
        line.split(maxsplit=5)[5].rstrip("\n")
        for line in Path("/proc/self/maps").read_text().splitlines(keepends=True)
        if len(line.split(maxsplit=5)) == 6
    }
    copies = [m for m in mapped if m.endswith("(deleted)") and Path(m).name != lib.name]
    alive = [
        m for m in mapped
        if Path(m) != lib and Path(m).is_file() and Path(m).stat().st_size == len(content)
        and Path(m).read_bytes() == content
    ]  # fmt: skip
    assert len(copies) >= 2 and alive == [], (copies, alive)


def _copilot_like(tmp_path: Path) -> tuple[Path, object]:
    """A library without reset functions (as Copilot's): its reset loads a fresh copy."""
    spec = make_spec([parse_formula("Y b0")])
    c_path, _ = write_c(spec, tmp_path / "src")
    lib = build_library(spec, [c_path], tmp_path / "src", tmp_path, reset=False, reset_each=False)
    return lib, spec


def test_a_fresh_copy_is_made_beside_its_library_not_in_the_temporary_directory(
    tmp_path, monkeypatch
) -> None:
    # A hardened robot mounts /tmp noexec (and the unit's PrivateTmp keeps that): a copy
    # there cannot be mapped, so an operator's reset failed. The library's own directory
    # could map the library itself.
    lib, spec = _copilot_like(tmp_path)
    mon = load_monitor(lib, spec)
    assert mon.tick(_row(b0=True)) == b"\x01"
    assert mon.tick(_row(b0=True)) == b"\x00"
    before = sorted(lib.parent.iterdir())
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "no-such-directory"))
    mon.reset()
    assert mon.tick(_row(b0=True)) == b"\x01"  # fresh: Y false at tick 0
    assert sorted(lib.parent.iterdir()) == before  # and the copy's file gone


def test_a_fresh_copy_of_a_library_in_a_read_only_place_is_made_in_the_temporary_directory(
    tmp_path,
) -> None:
    lib, spec = _copilot_like(tmp_path)
    mon = load_monitor(lib, spec)
    assert mon.tick(_row(b0=True)) == b"\x01"
    shut = lib.parent
    shut.chmod(0o555)  # read-only to a user; to root only when immutable as well
    subprocess.run(["chattr", "+i", str(shut)], capture_output=True, check=False)
    try:
        with pytest.raises(OSError):
            (shut / "probe").touch()
        mon.reset()
        assert mon.tick(_row(b0=True)) == b"\x01"  # fresh: Y false at tick 0
    finally:
        subprocess.run(["chattr", "-i", str(shut)], capture_output=True, check=False)
        shut.chmod(0o755)


@pytest.mark.parametrize("cc", ["no-such-cc", "/nonexistent/cc", "/etc/hostname"])
def test_a_missing_or_unrunnable_compiler_is_one_clear_error(tmp_path, monkeypatch, cc) -> None:
    # A robot's image often has no gcc: the build ended in an internal error (exit 3)
    # from subprocess's FileNotFoundError (or PermissionError for a file that is not a
    # program).
    spec = make_spec([parse_formula("Y b0")])
    c_path, _ = write_c(spec, tmp_path / "src")
    monkeypatch.setenv("CC", cc)
    with pytest.raises(UserError) as e:
        build_library(spec, [c_path], tmp_path / "src", tmp_path, reset=True, reset_each=True)
    assert e.value.file == cc and "C compiler" in e.value.message, e.value
    assert e.value.hint and "CC" in e.value.hint


def test_a_build_leaves_its_library_and_not_its_work(tmp_path) -> None:
    # compile -o DIR left the cffi module's C and every object file in DIR
    spec = make_spec([parse_formula("Y b0")])
    c_path, _ = write_c(spec, tmp_path / "src")
    lib = build_library(spec, [c_path], tmp_path / "src", tmp_path, reset=True, reset_each=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([lib.name, "src"])


# ------------------------------------------------------------------ processes, names, linking


def test_two_monitors_in_one_process_are_independent(tmp_path) -> None:
    a = make_spec([parse_formula("H (b0 -> (O[0,3] b1))"), parse_formula("i0 < i1")])
    b = make_spec([parse_formula("Y b0"), parse_formula("b1 S b0"), parse_formula("d0 >= 1.5")])
    ma, mb = compile_spec(a, tmp_path / "a"), compile_spec(b, tmp_path / "b")
    assert ma.path.name != mb.path.name
    trace = make_trace(7, 120)
    names = [v.name for v in INPUTS]
    got_a, got_b = [], []
    for row in trace:  # interleaved
        got_a.append(ma.tick([row[x] for x in names]))
        got_b.append(mb.tick([row[x] for x in names]))
    for spec, got in ((a, got_a), (b, got_b)):
        flags = [[bool(t[i]) for t in got] for i in range(len(spec.requirements))]
        assert_same(flags, oracle(spec, trace), spec, trace, "interleaved")


def test_keyword_variable_names_compile(tmp_path) -> None:
    spec = MonitorSpec(
        "kw",
        (VarDecl("auto", "int64"), VarDecl("int", "bool"), VarDecl("log", "double")),
        (RequirementSpec("int", parse_formula("H ((int & for) -> (auto > 2))")),),
        (Define("for", "bool", parse_formula("log < 0.5")),),
        prefix="sRobot",
    )
    c_text, h_text = generate(spec)
    assert "extern int64_t auto_;" in h_text and "void sRobot_step(void);" in h_text
    mon = compile_spec(spec, tmp_path)
    assert [mon.tick(v) for v in ([1, True, 0.0], [3, True, 0.0], [0, False, 9.0])] == [
        b"\x01",
        b"\x01",
        b"\x01",  # H latched
    ]


def test_library_exports_only_the_module_init(tmp_path) -> None:
    # glibc exports a legacy 'step'; the monitor's own must be bound locally, not exported
    nm = shutil.which("nm")
    if nm is None:
        pytest.skip("nm missing (install Debian's binutils)")
    mon = compile_spec(make_spec([parse_formula("Y b0")]), tmp_path)
    out = subprocess.run(
        [nm, "-D", "--defined-only", str(mon.path)], capture_output=True, text=True
    )
    exported = {line.split()[-1] for line in out.stdout.splitlines() if line.strip()}
    assert exported == {f"PyInit_{mon.path.name.split('.')[0]}"}
    # calling step through the library works (glibc's step would crash or do nothing)
    assert [mon.tick(_row(b0=True)) for _ in range(2)] == [b"\x01", b"\x00"]


def test_naive_link_calls_glibcs_step(tmp_path) -> None:
    """The hazard the link flags guard against: the same sources built as a plain
    shared library resolve 'step' to glibc's.  (Proves the check above can fail.)
    Read from the address the library's own code takes for 'step', never by calling
    it: glibc's step on our globals crashes or loops."""
    if subprocess.run(["sh", "-c", "nm -D /lib/*/libc.so.6 | grep -qw step"]).returncode != 0:
        pytest.skip("this libc exports no 'step'")
    spec = make_spec([parse_formula("b0")])
    c_path, _ = write_c(spec, tmp_path)
    (tmp_path / "host.c").write_text(
        textwrap.dedent("""\
        #include <stdbool.h>
        #include <stdint.h>
        bool b0, b1, b2; int64_t i0, i1; double d0, d1;
        void handlerR0(void) {}
        void step(void);
        void *step_called(void) { return (void *)&step; }
        """)
    )
    so = tmp_path / "naive.so"
    subprocess.run(
        ["cc", "-shared", "-fPIC", "-O2", str(c_path), str(tmp_path / "host.c"), "-o", str(so)],
        check=True,
    )
    naive = ctypes.CDLL(str(so))
    naive.step_called.restype = ctypes.c_void_p
    own = ctypes.cast(naive.step, ctypes.c_void_p).value  # dlsym in the library itself
    assert _defined_in(own) == ("naive.so", "step")
    # glibc's step is a compat symbol (step@GLIBC_...), out of dlsym's reach: dladdr
    # names the object the library's call goes to.
    assert _defined_in(naive.step_called()) == ("libc.so.6", "step")


class _DlInfo(ctypes.Structure):
    _fields_ = [
        ("dli_fname", ctypes.c_char_p),
        ("dli_fbase", ctypes.c_void_p),
        ("dli_sname", ctypes.c_char_p),
        ("dli_saddr", ctypes.c_void_p),
    ]


def _defined_in(address: int | None) -> tuple[str, str]:
    """(file name of the loaded object, symbol) that ``address`` lies in (dladdr(3))."""
    dladdr = ctypes.CDLL(None).dladdr
    dladdr.argtypes = [ctypes.c_void_p, ctypes.POINTER(_DlInfo)]
    info = _DlInfo()
    assert dladdr(address, ctypes.byref(info)), hex(address or 0)
    return Path(info.dli_fname.decode()).name, (info.dli_sname or b"").decode()


# ------------------------------------------------------------------ the generated C itself

RICH = [
    parse_formula(t)
    for t in [
        "H ((i0 / i1 > 2) -> ((i0 mod 3) = (i1 ^ 3)))",
        "(d0 ^ d1) < (d0 mod 2.5)",
        "(- i0) <= d0",
        "(b0 S[2,9] b1) | (b1 T[0,4] b2) | (b2 S b0) | (b0 T b1)",
        "(H[3,200] b0) | (O[70,inf] b1) | (Y b2) | (Z b0) | (O[0,5] big) | rose",
        "(i0 * i1 + 1) != -7",
        "d0 / 0.0 = 1e999",
    ]
]


def _strip_comments(c: str) -> str:
    return re.sub(r"/\*.*?\*/", "", c, flags=re.S)


def test_generated_c_is_loop_free_strict_c99(tmp_path: Path) -> None:
    assert_hard_real_time_c(make_spec(RICH), tmp_path)


def assert_hard_real_time_c(spec: MonitorSpec, tmp_path: Path) -> None:
    """The spec's C is strict C99 without loops or allocation, every stack frame is
    static and the call graph acyclic (also used for the shipped configs' monitors,
    tests/supervisor/test_shipped_monitors.py)."""
    c_path, _ = write_c(spec, tmp_path)
    code = _strip_comments(c_path.read_text())
    assert not re.search(r"\b(for|while|do|goto|malloc|calloc|realloc|free|alloca)\b", code)
    r = subprocess.run(
        ["cc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2", "-fstack-usage"]
        + ["-fcallgraph-info=su", "-c", str(c_path), "-o", str(tmp_path / "m.o")],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert r.returncode == 0, r.stderr
    # every function's stack frame is fixed ("static"), none dynamic or bounded-dynamic
    su = (tmp_path / "m.su").read_text().splitlines()
    assert su and all(line.endswith("\tstatic") for line in su), su
    # call graph: acyclic; the step calls its requirements' functions, which call
    # only handlers and libm
    ci = (tmp_path / "m.ci").read_text()
    edges = re.findall(r'edge: \{ sourcename: "(\w+)" targetname: "(\w+)"', ci)
    assert edges
    handlers = {c_name(r.handler) for r in spec.requirements}
    for src, dst in edges:
        assert (
            dst in handlers
            or dst in ("pow", "fmod", "hypot", "sqrt", "fabs")
            or dst.startswith(("ss__step_r", "monitor_reset"))
        ), (src, dst)
        assert not dst.startswith("monitor_reset") or src == "monitor_reset"
        assert not dst.startswith("ss__step_r") or src == spec.step_name, (src, dst)


def test_host_shim_is_strict_c99(tmp_path) -> None:
    spec = make_spec(RICH)
    mon = compile_spec(spec, tmp_path)
    shim = tmp_path / "ss_host.c"  # the build's own copy is removed with its work
    shim.write_text(host_source(spec, reset=True, reset_each=True))
    r = subprocess.run(
        ["cc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-fsyntax-only", str(shim)],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    # the shared object pulls in no allocator
    nm = subprocess.run(
        ["nm", "-D", "--undefined-only", str(mon.path)], capture_output=True, text=True
    )
    undefined = {line.split()[-1].split("@")[0] for line in nm.stdout.splitlines()}
    assert not undefined & {
        "malloc",
        "calloc",
        "realloc",
        "free",
        "aligned_alloc",
        "posix_memalign",
    }


def test_compiler_errors_become_user_errors(tmp_path) -> None:
    bad = tmp_path / "bad.c"
    bad.write_text("void step(void) { int x = ; }\n")
    spec = make_spec([parse_formula("b0")])
    with pytest.raises(UserError) as e:
        build_library(spec, [bad], tmp_path, tmp_path / "out", reset=False, reset_each=False)
    assert e.value.file.endswith("bad.c") and e.value.line == 1 and "expected" in str(e.value)


def test_unsupported_integer_power_is_a_user_error() -> None:
    with pytest.raises(UserError, match="constant exponent"):
        generate(make_spec([parse_formula("i0 ^ i1 > 2")]))
    with pytest.raises(UserError, match="int64"):
        generate(make_spec([parse_formula("i0 > 99999999999999999999")]))


def test_inputs_are_checked_and_libraries_match_their_spec(tmp_path) -> None:
    spec = make_spec([parse_formula("i0 < 3")])
    mon = compile_spec(spec, tmp_path)
    exact = [False, False, False, I64_MAX, 0, 0.0, 0.0]
    assert mon.tick(exact) == b"\x01"  # int64 passed exactly, not through a double
    assert mon.tick([False, False, False, 2, 0, 0.0, 0.0]) == b"\x00"
    with pytest.raises(TypeError):
        mon.tick([False, False, False, 2.5, 0, 0.0, 0.0])  # a float for an int64
    with pytest.raises(TypeError):
        mon.tick([False, False])  # too few values
    other = make_spec([parse_formula("i0 < 3"), parse_formula("b0")])
    with pytest.raises(UserError, match="does not match"):
        load_monitor(mon.path, other)


# Each arithmetic function at its edge values: NaN and infinities, domain errors,
# poles, INT64_MIN, -0.0 (the interpreter defines C's results where Python raises).
FUNCTION_CASES = [
    "abs(i0) = i1",
    "abs(d0) = d1",
    "min(i0, i1) < 0",
    "max(d0, i1) >= d1",
    "min(d0, d1) = d0",
    "max(d0, d1) = d1",
    *(
        f"{fn}(d0) {rel} d1"
        for fn in ("sqrt", "exp", "log", "sin", "cos", "tan", "asin", "acos", "atan")
        for rel in ("<", "=")
    ),
    "floor(d0) = ceil(d1)",
    "hypot(d0, d1) <= d1",
    "hypot(d0, d1) = hypot(d1, d0)",
    "hypot(i0, d1) > 1.0",
    "floor(i0) < i1",
    "sqrt(i0) >= 3",
    "ite(b0, i0, d0) < d1",
    "ite(b1, i0, i1) = 3",
    "ite(d0 > 1.0, b1, b2)",
]


def test_arithmetic_functions_match_interpreter(tmp_path) -> None:
    spec = make_spec([parse_formula(text) for text in FUNCTION_CASES])
    mon = compile_spec(spec, tmp_path)
    edges = [math.nan, math.inf, -math.inf, 0.0, -0.0, -1.0, 1.0, 2.0, 0.5, 1e308, -1e-310]
    trace = make_trace(7, 400)
    for k, row in enumerate(trace):
        row["d0"] = edges[k % len(edges)]
        row["d1"] = edges[(k // len(edges)) % len(edges)] if k % 3 else row["d1"]
        if k % 5 == 0:
            row["i0"] = I64_MIN
    assert_same(run(mon, spec, trace), oracle(spec, trace), spec, trace, "functions")


def test_input_named_like_a_called_math_function_is_refused() -> None:
    spec = MonitorSpec(
        "t", (VarDecl("sqrt", "double"),), (RequirementSpec("r", parse_formula("sqrt(sqrt) > 1")),)
    )
    with pytest.raises(UserError, match="C math function"):
        generate(spec)
    # not called: the name is free
    generate(
        MonitorSpec(
            "t", (VarDecl("sqrt", "double"),), (RequirementSpec("r", parse_formula("sqrt > 1")),)
        )
    )
