"""The Copilot backend against the reference interpreter and the native backend.

Real GHC + NASA Copilot 3.13, real gcc and cffi.  GHC is slow to start, so the
random formulas are batched into ONE spec (one runghc run) and checked on many
traces.  Without Copilot these tests skip, unless
SAFETY_SUPERVISOR_REQUIRE_COPILOT=1 (CI), where they fail instead.

Not cross-checked: real ``mod`` (Copilot 3.13 has no fmod; the backend rejects
it with a UserError, tested below).
"""

from __future__ import annotations

import json
import math
import os
import random
import time
from pathlib import Path

import pytest

from monitors.backends.copilot import (
    INSTALL_HINT,
    build_copilot_monitor,
    compile_copilot,
    copilot_available,
    generate_haskell,
    require_copilot,
    run_copilot,
    run_haskell,
)
from monitors.backends.load import compile_spec
from monitors.errors import UserError
from monitors.ir.formula import (
    ARITH_OPS,
    BOOL_OPS,
    REL_OPS,
    BinOp,
    Const,
    Formula,
    Neg,
    Not,
    Past,
    Since,
    Var,
    parse_formula,
    subterms,
)
from monitors.ir.spec import Define, MonitorSpec, RequirementSpec, VarDecl

REQUIRE = os.environ.get("SAFETY_SUPERVISOR_REQUIRE_COPILOT") == "1"
SROBOT_EXPORT = Path(__file__).resolve().parents[2] / "data" / "sRobot-fret-export.json"
from harness import BOOLS, I64_MAX, I64_MIN, INPUTS, INTS, REALS, make_trace, oracle, run  # noqa: E402

DEFINES = (
    Define("big", "bool", parse_formula("i0 > 3")),
    Define("rose", "bool", parse_formula("b0 & (Y (! b0))")),  # temporal define
)


@pytest.fixture(scope="module")
def copilot() -> None:
    try:
        require_copilot()
    except UserError as e:
        if REQUIRE:
            pytest.fail(f"SAFETY_SUPERVISOR_REQUIRE_COPILOT=1 but Copilot is unusable: {e}")
        pytest.skip(f"NASA Copilot is not installed ({e})")


# ------------------------------------------------------------------ formulas
# Constants never repeat a value of another type (no 0, 1, 0.0, 1.0): the
# interpreter shares equal subterms and Const(1) == Const(1.0) == Const(True)
# as dataclasses, so such a mix would make the judge itself wrong.
INT_CONSTS = [-1, 2, 3, 7, -5, I64_MIN, I64_MAX, 2**53 + 1]
REAL_CONSTS = [0.5, -2.5, 3.25, 1e300, math.inf, -math.inf, 2.0**63, 9.2e18]


def num_f(rnd: random.Random, depth: int, real: bool) -> Formula:
    if depth <= 0 or rnd.random() < 0.25:
        k = rnd.randrange(6)
        if k == 0:
            return Var(rnd.choice(BOOLS))  # a bool as a number: 0/1
        if k == 1:
            return Const(rnd.choice(REAL_CONSTS if real else INT_CONSTS))
        if real and k < 4:
            return Var(rnd.choice(REALS))
        return Var(rnd.choice(INTS))
    k = rnd.randrange(8)
    if k == 0:
        return Neg(num_f(rnd, depth - 1, real))
    if k == 1:
        if real:  # a real base, so that the power is real
            base = rnd.choice([Var(rnd.choice(REALS)), Const(rnd.choice(REAL_CONSTS))])
            return BinOp("^", base, num_f(rnd, depth - 1, True))
        # a small exponent: Copilot inlines every multiplication (x^63 once, below)
        return BinOp("^", num_f(rnd, 1, False), Const(rnd.choice([0, 2, 3])))
    ops = ["+", "-", "*", "/"] if real else ["+", "-", "*", "/", "mod"]
    return BinOp(rnd.choice(ops), num_f(rnd, depth - 1, real), num_f(rnd, depth - 1, real))


def window(rnd: random.Random) -> tuple[int | None, int | None]:
    k = rnd.randrange(10)
    if k < 2:
        return None, None
    lo = rnd.randrange(6)
    if k < 4:
        return lo, None
    if k == 4:
        return lo + 2, lo  # empty window
    return lo, lo + rnd.randrange(6)


def bool_f(rnd: random.Random, depth: int) -> Formula:
    if depth <= 0 or rnd.random() < 0.2:
        k = rnd.randrange(12)
        if k == 0:
            return Const(rnd.random() < 0.5)
        if k == 1:
            return Var(rnd.choice(["big", "rose"]))
        if k < 5:
            real = rnd.random() < 0.5
            op = rnd.choice(REL_OPS)
            return BinOp(op, num_f(rnd, 2, real), num_f(rnd, 2, rnd.random() < 0.5))
        if k == 5:
            return Var(rnd.choice(INTS))  # a number as a condition: != 0
        return Var(rnd.choice(BOOLS))
    k = rnd.randrange(10)
    if k == 0:
        return Not(bool_f(rnd, depth - 1))
    if k < 3:
        return BinOp(rnd.choice(BOOL_OPS), bool_f(rnd, depth - 1), bool_f(rnd, depth - 1))
    if k < 7:
        op = rnd.choice("YZHO")
        lo, hi = window(rnd) if op in "HO" else (None, None)
        return Past(op, bool_f(rnd, depth - 1), lo, hi)
    lo, hi = window(rnd)
    return Since(rnd.choice("ST"), bool_f(rnd, depth - 1), bool_f(rnd, depth - 1), lo, hi)


# Every operator and bound shape at least once, whatever the random draw.
TARGETED = [
    "Y b0",
    "Z b0",
    "H b0",
    "O b0",
    "b0 S b1",
    "b0 T b1",
    "H[0,3] b0",
    "O[2,3] b0",
    "O[0,0] b0",
    "H[2,inf] b0",
    "O[3,inf] b0",
    "b0 S[0,2] b1",
    "b0 S[1,3] b1",
    "b0 S[2,inf] b1",
    "b0 T[0,2] b1",
    "b0 T[2,4] b1",
    "b0 T[1,inf] b1",
    "O[70,90] b0",  # long delay lines
    "b1 S[100,140] b0",
    "(b0 xor b1) <-> (b2 -> ! b0)",
    "(b0 = b1) | (b1 != b2)",
    "(i0 / i1) >= (i0 mod i1)",  # zero divisor, INT64_MIN / -1
    "((i0 + i1) * i0) - i1 > (- i0)",  # wrap-around
    "(i0 ^ 63) = (i1 ^ 2)",
    "(d0 / d1) <= (d0 ^ d1)",  # IEEE division, pow edge cases
    "(- d0) + (d1 * d0) < d1 - 3.25",
    "(i0 = d0) | (d1 < i1) | (i0 >= d1) | (d0 != i1)",  # exact int64 vs double
    "(b0 + b1) * i0 > d0",  # bools as numbers, int promoted to real
    "O i0",  # a number as a condition
    "H ((O[5,5] ((b1 & (Y (! b1))) | (b1 & FTP))) -> (O[0,5] b2))",  # FRET 'within'
]


def make_spec(formulas: list[Formula], prefix: str = "") -> MonitorSpec:
    reqs = tuple(RequirementSpec(f"R{i}", f) for i, f in enumerate(formulas))
    return MonitorSpec("test", INPUTS, reqs, DEFINES, prefix=prefix)


def batch_formulas(seed: int, n: int) -> list[Formula]:
    rnd = random.Random(seed)
    return [parse_formula(t) for t in TARGETED] + [bool_f(rnd, 4) for _ in range(n)]


def covered(formulas: list[Formula]) -> set[str]:
    out: set[str] = set()
    for f in formulas:
        for g in subterms(f):
            match g:
                case Not():
                    out.add("!")
                case Neg():
                    out.add("neg")
                case BinOp(op):
                    out.add(op)
                case Past(op, _, lo, hi) | Since(op, _, _, lo, hi):
                    shape = "" if hi is None and not lo else "[l,inf]" if hi is None else "[l,h]"
                    out.add(op + shape)
    return out


def assert_same(got: list, want: list, spec: MonitorSpec, trace: list, what: str) -> None:
    for i, (g, w) in enumerate(zip(got, want, strict=True)):
        if g != w:
            tick = next(t for t in range(len(g)) if g[t] != w[t])
            req = spec.requirements[i]
            raise AssertionError(
                f"{what}: {req.id} = {spec.expanded(req)}\n  first difference at tick "
                f"{tick}: Copilot violated={g[tick]}, expected {w[tick]}\n"
                f"  trace[{max(0, tick - 3)}:{tick + 1}] = {trace[max(0, tick - 3) : tick + 1]}"
            )


# ------------------------------------------------------------------ the batch


@pytest.fixture(scope="module")
def batch(copilot: None, tmp_path_factory: pytest.TempPathFactory) -> tuple:
    spec = make_spec(batch_formulas(seed=2024, n=70), prefix="batch")
    out = tmp_path_factory.mktemp("batch")
    start = time.perf_counter()
    mon = build_copilot_monitor(spec, out)
    print(f"\nCopilot batch of {len(spec.requirements)}: {time.perf_counter() - start:.1f} s")
    return spec, mon, compile_spec(spec, out / "native")


def test_batch_covers_every_operator() -> None:
    got = covered(batch_formulas(seed=2024, n=70))
    want = {"!", "neg", *BOOL_OPS, *REL_OPS, *ARITH_OPS}
    want |= {op + shape for op in "HOST" for shape in ("", "[l,h]", "[l,inf]")} | {"Y", "Z"}
    assert want <= got, want - got


@pytest.mark.ghc
@pytest.mark.parametrize("seed", range(6))
def test_copilot_matches_interpreter_and_native(batch: tuple, seed: int) -> None:
    spec, mon, native = batch
    trace = make_trace(seed, 320)
    mon.reset()
    native.reset()
    got = run(mon, spec, trace)
    assert_same(got, oracle(spec, trace), spec, trace, "vs interpreter")
    assert_same(got, run(native, spec, trace), spec, trace, "vs native")


@pytest.mark.ghc
def test_reset_loads_a_fresh_copilot_monitor(batch: tuple) -> None:
    spec, mon, _ = batch
    trace = make_trace(99, 120)
    assert not mon.has_reset  # Copilot generates no reset function
    mon.reset()
    run(mon, spec, trace[:50])
    mon.reset()
    assert_same(run(mon, spec, trace[50:]), oracle(spec, trace[50:]), spec, trace, "reset")


def test_generated_haskell_is_an_ogma_style_spec() -> None:
    spec = make_spec([parse_formula("b0 S b1"), parse_formula("H (i0 < d0)")], prefix="mon")
    hs = generate_haskell(spec)
    for v in INPUTS:
        typ = {"bool": "Bool", "int64": "Int64", "double": "Double"}[v.type]
        assert f'in_{v.name} :: Stream {typ}\nin_{v.name} = extern "{v.name}" Nothing' in hs
    assert 'trigger "handlerR0" (not t' in hs and 'trigger "handlerR1" (not t' in hs
    assert 'cSettingsStepFunctionName = "mon_step"' in hs
    assert "compileWith" in hs and "reify spec" in hs
    assert "def_rose :: Stream Bool" in hs  # internal variables are bindings
    assert "Copilot.Library" not in hs  # own since: the library's is non-standard
    assert "cSettingsStepFunctionName" not in generate_haskell(make_spec([parse_formula("b0")]))


def test_real_mod_is_rejected_with_a_reason() -> None:
    spec = make_spec([parse_formula("(d0 mod 2.5) > 1.0")])
    with pytest.raises(UserError, match="real 'mod'.*no fmod"):
        generate_haskell(spec)


# ------------------------------------------------------------------ sRobot, processes


def srobot_spec(prefix: str = "sRobot") -> MonitorSpec:
    data = json.loads(SROBOT_EXPORT.read_text())["sRobotSpec"]
    types = {"int": "int64", "bool": "bool", "real": "double"}
    return MonitorSpec(
        "sRobot",
        tuple(VarDecl(v["name"], types[v["type"]]) for v in data["Other_variables"]),
        tuple(RequirementSpec(r["name"], parse_formula(r["ptLTL"])) for r in data["Requirements"]),
        tuple(
            Define(v["name"], types[v["type"]], parse_formula(v["assignmentCopilot"]))
            for v in data["Internal_variables"]
        ),
        prefix=prefix,
    )


def srobot_trace(seed: int, n: int) -> list[dict[str, bool | int]]:
    rnd = random.Random(seed)
    return [
        {
            "OpState": rnd.choice([0, 1, 2, 3, 3, 4]),
            "classifier": rnd.choice([0, 1, 2, 2, 5]),
            "distance_to_target": rnd.randint(-2, 12),
            **{b: rnd.random() < 0.5 for b in ("alert", "halt", "slowdown", "turnoffUVC")},
        }
        for _ in range(n)
    ]


@pytest.fixture(scope="module")
def srobot(copilot: None, tmp_path_factory: pytest.TempPathFactory) -> tuple:
    spec = srobot_spec()
    return spec, build_copilot_monitor(spec, tmp_path_factory.mktemp("srobot"))


@pytest.mark.ghc
@pytest.mark.skipif(not SROBOT_EXPORT.exists(), reason="sRobot FRET export not present")
def test_srobot_requirements_match_interpreter(srobot: tuple) -> None:
    spec, mon = srobot
    assert len(spec.requirements) == 13
    for seed in range(4):
        mon.reset()
        trace = srobot_trace(seed, 150 + 50 * seed)
        want = oracle(spec, trace)
        assert any(any(w) for w in want) and not all(all(w) for w in want)
        assert_same(run(mon, spec, trace), want, spec, trace, f"sRobot seed {seed}")


@pytest.mark.ghc
@pytest.mark.skipif(not SROBOT_EXPORT.exists(), reason="sRobot FRET export not present")
def test_two_copilot_monitors_in_one_process(srobot: tuple, tmp_path: Path) -> None:
    # the second one keeps Copilot's default step name 'step' (glibc has a 'step')
    # and both define Copilot's non-static s0_get, s0_gen, handler*_guard ...
    spec_a, mon_a = srobot
    spec_b = make_spec([parse_formula("b0 S[1,3] b1"), parse_formula("H (i0 <= i1)")])
    mon_b = build_copilot_monitor(spec_b, tmp_path)
    assert spec_b.step_name == "step" and mon_a.path.name != mon_b.path.name
    mon_a.reset()
    ta, tb = srobot_trace(11, 200), make_trace(12, 200)
    got_a, got_b = [], []
    for ra, rb in zip(ta, tb, strict=True):  # interleaved
        got_a.append(mon_a.tick([ra[v.name] for v in spec_a.inputs]))
        got_b.append(mon_b.tick([rb[v.name] for v in spec_b.inputs]))
    for spec, got, trace in ((spec_a, got_a, ta), (spec_b, got_b, tb)):
        flags = [[bool(t[i]) for t in got] for i in range(len(spec.requirements))]
        assert_same(flags, oracle(spec, trace), spec, trace, "interleaved")


@pytest.mark.ghc
def test_runghc_and_compiled_ghc_give_the_same_c(copilot: None, tmp_path: Path) -> None:
    spec = make_spec([parse_formula("b0 T[1,2] (i0 > d0)")], prefix="same")
    a = run_copilot(spec, tmp_path / "a", runner="runghc")
    b = run_copilot(spec, tmp_path / "b", runner="ghc")
    print(f"\nrunghc {a.seconds:.2f} s, ghc -O0 + run {b.seconds:.2f} s")
    assert [p.name for p in a.c_files] == ["same.c", "same.h", "same_types.h"]
    for x, y in zip(a.c_files, b.c_files, strict=True):
        assert x.read_text() == y.read_text()
    assert "void same_step(void);" in a.c_files[1].read_text()


# ------------------------------------------------------------------ errors


@pytest.mark.ghc
def test_haskell_errors_become_one_readable_line(copilot: None, tmp_path: Path) -> None:
    source = "module Main (main) where\nmain :: IO ()\nmain = putStrLn (1 + True)\n"
    with pytest.raises(UserError) as err:
        run_haskell(source, tmp_path)
    text = str(err.value)
    assert "\n" not in text and "line 3:" in text and "generated Copilot spec" in text


@pytest.mark.ghc
def test_input_named_like_a_libc_function_gets_a_hint(copilot: None, tmp_path: Path) -> None:
    spec = MonitorSpec(
        "x", (VarDecl("log", "double"),), (RequirementSpec("A", parse_formula("log > 1.5")),)
    )
    with pytest.raises(UserError, match="redeclared") as err:
        build_copilot_monitor(spec, tmp_path)
    assert "C library function" in (err.value.hint or "")
    clash = MonitorSpec("x", (VarDecl("s0", "bool"),), (RequirementSpec("A", Var("s0")),))
    with pytest.raises(UserError, match="clashes with a name Copilot uses"):
        generate_haskell(clash)


def test_missing_ghc_says_how_to_install(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))  # no ghc on PATH
    assert not copilot_available()
    with pytest.raises(UserError) as err:
        compile_copilot(make_spec([parse_formula("b0")]), tmp_path / "out")
    assert "'ghc' is not on PATH" in str(err.value)
    assert "apt-get install ghc libghc-copilot-dev" in str(err.value)
    assert "apt-get install ghc libghc-copilot-dev" in INSTALL_HINT


@pytest.mark.ghc
def test_missing_copilot_library_says_how_to_install(
    copilot: None, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a real GHC whose package database has no Copilot in it
    (tmp_path / "db").mkdir()
    monkeypatch.setenv("GHC_PACKAGE_PATH", str(tmp_path / "db"))
    assert not copilot_available()
    with pytest.raises(UserError, match="copilot-c99.*apt-get install ghc libghc-copilot-dev"):
        compile_copilot(make_spec([parse_formula("b0")]), tmp_path / "out")


@pytest.mark.ghc
def test_cli_compile_with_copilot_backend(copilot: None, tmp_path: Path) -> None:
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[3]
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "supervisor",
            "compile",
            str(root / "config" / "srobot.yaml"),
            "-o",
            str(tmp_path / "out"),
            "--backend",
            "copilot",
        ],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=root,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["backend"] == "copilot" and manifest["reset_function"] is None
    assert (tmp_path / "out" / "monitor.c").exists() and (tmp_path / "out" / "monitor.hs").exists()
    assert (tmp_path / "out" / manifest["library"]).exists()
