"""Command line: ``safety-supervisor COMMAND`` (also ``python -m supervisor``).

Exit codes (docs/reference/commands.md): 0 success; 1 the input was understood and something
is wrong with it; 2 usage error.  User errors print as ``FILE:LINE: message``;
an unexpected internal error prints one line naming it (plus where to report),
never a raw traceback unless SAFETY_SUPERVISOR_DEBUG=1.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from monitors.errors import UserError
from supervisor.tools.bench.command import add_parser as add_bench_parser
from supervisor.tools.bench.command import cmd_bench
from supervisor.tools.demo.command import add_parser as add_demo_parser
from supervisor.tools.demo.command import cmd_demo
from supervisor.tools.fleet.command import add_parser as add_fleet_parser
from supervisor.tools.fleet.command import cmd_fleet
from supervisor.tools.init import add_parser as add_init_parser
from supervisor.tools.init import cmd_init
from supervisor.tools.inject.command import add_parser as add_inject_parser
from supervisor.tools.inject.command import cmd_inject
from supervisor.tools.install import add_parser as add_install_parser
from supervisor.tools.install import cmd_install_service
from supervisor.tools.logs import add_parser as add_logs_parser
from supervisor.tools.logs import cmd_logs
from supervisor.tools.reload import add_parser as add_reload_parser
from supervisor.tools.reload import cmd_reload
from supervisor.tools.replay.command import add_parser as add_replay_parser
from supervisor.tools.replay.command import cmd_replay
from supervisor.tools.report.command import add_parser as add_report_parser
from supervisor.tools.report.command import cmd_report
from supervisor.tools.reset import add_parser as add_reset_parser
from supervisor.tools.reset import cmd_reset
from supervisor.tools.status import add_parser as add_status_parser
from supervisor.tools.status import cmd_status
from supervisor.tools.ui.command import add_parser as add_ui_parser
from supervisor.tools.ui.command import cmd_ui

if TYPE_CHECKING:
    from monitors.ir.spec import MonitorSpec
    from supervisor.pipeline import Project

EXIT_OK, EXIT_FAIL = 0, 1  # and 2, a usage error, is argparse's own


def _out(text: str = "") -> None:
    print(text, flush=True)


def _err(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


# ------------------------------------------------------------------ formalize

STDIN_BYTES = 1 << 20  # requirements on stdin, at most: /dev/zero has no end


def _stdin_text() -> str:
    binary = getattr(sys.stdin, "buffer", None)  # None: a text stream put in its place
    data = (binary or sys.stdin).read(STDIN_BYTES + 1)
    if isinstance(data, str):
        data = data.encode()
    if len(data) > STDIN_BYTES:
        raise UserError(f"more than {STDIN_BYTES:,} bytes of requirements", file="<stdin>")
    try:
        return data.decode()
    except UnicodeDecodeError as e:
        raise UserError(f"not UTF-8 text at byte {e.start}", file="<stdin>") from None


def cmd_formalize(args: argparse.Namespace) -> int:
    from monitors.frontend.formalize import formalize
    from monitors.frontend.parse import parse_requirement
    from monitors.ir.formula import to_fret

    if args.text:
        items = [(t, "<arg>", 1) for t in args.text]
    else:
        lines = _stdin_text().splitlines()
        items = [(line, "<stdin>", i) for i, line in enumerate(lines, 1)]
        items = [it for it in items if it[0].strip() and not it[0].lstrip().startswith("#")]
        if not items:
            raise UserError("no requirement to formalize", file="<stdin>")
    status = EXIT_OK
    for text, file, line in items:
        try:
            req = parse_requirement(text, file=file, line=line)
            form = formalize(req, period_ms=args.period_ms, file=file, line=line)
            formula, error = to_fret(form.formula), None
        except UserError as e:
            formula, error = None, str(e)
            status = EXIT_FAIL
        if args.json:
            _out(json.dumps({"text": text, "formula": formula, "error": error}))
        elif error:
            _err(error)
        else:
            _out(formula or "")
    return status


# ------------------------------------------------------------------ explain


def cmd_explain(args: argparse.Namespace) -> int:
    from monitors.frontend.formalize import describe
    from monitors.ir.formula import fret_name, to_fret, variables
    from monitors.ir.spec import c_name
    from supervisor.config import load_config
    from supervisor.pipeline import build_project

    project = build_project(load_config(args.config), ros=False)
    wanted = set(args.requirements or [])
    unknown = wanted - {r.id for r in project.requirements}
    if unknown:
        project.config.requirement(sorted(unknown)[0])  # raises with the list of ids
    from supervisor.analysis_report import explain_lines
    from supervisor.validation import analyse_project

    analysis = analyse_project(project, args.k)
    status = EXIT_OK
    for r in project.requirements:
        if wanted and r.id not in wanted:
            continue
        _out(f"{r.id}")
        _out(f"  text:      {r.entry.text}")
        if r.entry.rationale:
            _out(f"  rationale: {r.entry.rationale}")
        if r.error or r.parsed is None or r.formalization is None:
            _out(f"  error:     {r.error}")
            status = EXIT_FAIL
            _out()
            continue
        _out(f"  formula:   {to_fret(r.formula)}")
        _out(f"  reading:   {describe(r.parsed, project.config.step.period_ms)}")
        names = variables(r.formula)
        expanded = []
        for n in names:
            v = project.config.variables.get(n)
            # A name C cannot hold (a dotted name, a C keyword) is renamed in the
            # monitor, and one formula text cannot hold (`T`, `left wheel`) is
            # written as FRET writes a quoted name; say to which, as manifest.json does.
            facts = [f"formula name {fret_name(n)}"] if fret_name(n) != n else []
            facts += [f"C name {c_name(n)}"] if c_name(n) != n else []
            if v is not None and v.define_text:
                facts.insert(0, f"= {v.define_text}")
            elif v is not None:
                facts[:0] = [v.type, str(v.topic)]
            expanded.append(f"{n} ({', '.join(facts)})" if facts else n)
        _out(f"  reads:     {', '.join(expanded)}")
        for name in r.functions:  # expanded into the formula above
            fn = project.config.functions[name]
            _out(f"  function:  {fn.signature()} = {to_fret(fn.body)}")
        _out(f"  handler:   handler{r.id}")
        kind = "assumption (constrains inputs)" if r.entry.assumption else "guarantee"
        _out(f"  role:      {kind}")
        if r.formalization.note:
            _out(f"  note:      {r.formalization.note}")
        for line in explain_lines(analysis, r.id) if analysis else []:
            _out(line)
        if r.entry.on_violation:
            _out(f"  on violation: {', '.join(r.entry.on_violation)}")
        _out()
    return status


# ------------------------------------------------------------------ check / compile


def _print_project(project: object) -> int:
    from monitors.ir.formula import to_fret
    from supervisor.pipeline import Project

    assert isinstance(project, Project)
    width = max((len(r.id) for r in project.requirements), default=2)
    for r in project.requirements:
        if r.ok:
            mono = "" if r.formalization is None or r.formalization.monotone else "  [non-monotone]"
            _out(f"ok    {r.id:<{width}}  {to_fret(r.formula)}{mono}")
            for w in r.warnings:
                _out(f"      {'':<{width}}  warning: {w}")
        else:
            _out(f"FAIL  {r.id:<{width}}  {r.error}")
    for e in project.errors:
        _out(f"error {e}")
    for w in project.warnings:
        _out(f"warning: {w}")
    return sum(1 for r in project.requirements if not r.ok) + len(project.errors)


def _print_variables(project: object) -> None:
    """What each variable reads and the C type it becomes (docs/reference/commands.md)."""
    from monitors.ir.formula import to_fret
    from supervisor.inputs.readers import C_TYPES, check_input
    from supervisor.pipeline import Project

    assert isinstance(project, Project)
    rows = []
    for v in project.config.variables.values():
        if v.define is not None:
            rows.append((v.name, "define", "", "", to_fret(v.define), "", C_TYPES[v.type]))
            continue
        if v.topic is None:
            continue  # no topic: an error said so already
        try:
            d = check_input(v)
        except UserError:
            continue  # said in the errors above
        rows.append((v.name, d.kind, d.topic, d.message, d.path, d.reduction, d.c_type))
    if not rows:
        return
    head = ("variable", "kind", "topic", "message", "reads", "reduce", "C type")
    widths = [max(len(str(r[i])) for r in [head, *rows]) for i in range(len(head))]
    _out("variables:")
    for r in [head, *rows]:
        _out("  " + "  ".join(f"{str(x):<{w}}" for x, w in zip(r, widths, strict=True)).rstrip())


def _print_margins(spec: MonitorSpec) -> None:
    """With step.margins: each requirement's margin state and the windows whose
    margins fall back to booleans (docs/reference/margins.md, "Fallback")."""
    from monitors.backends.c99 import margin_state
    from monitors.ir.spec import MARGIN_DELAY_TICKS, MARGIN_WINDOW_TICKS

    too_long = f"window over {MARGIN_WINDOW_TICKS} or lower bound over {MARGIN_DELAY_TICKS} ticks"
    for rid, m in margin_state(spec).items():
        line = f"  margin {rid}: {m.bytes} bytes of state"
        if m.fallbacks:
            line += f"; boolean ({too_long}): " + ", ".join(m.fallbacks)
        _out(line)


def _print_predictions(project: Project) -> None:
    """With predict:, what each prediction fits and the monitor it costs
    (docs/reference/prediction.md, "What is fitted")."""
    if not project.predicts:
        return
    from monitors.backends.c99 import margin_state
    from monitors.ir.formula import to_fret

    spec = project.prediction_spec()
    state = margin_state(spec)
    for r, rs in zip([r for r in project.requirements if r.ok], spec.requirements, strict=True):
        if r.entry.policy_config.predict is None:
            continue
        m = state[rs.id]
        line = (
            f"  predict {rs.id}: fits the margin of {to_fret(rs.formula)} in a second monitor, "
            f"stepped beside the boolean one ({m.bytes} bytes of margin state)"
        )
        if m.fallbacks:
            line += "; boolean where a window is too long: " + ", ".join(m.fallbacks)
        _out(line)


def cmd_check(args: argparse.Namespace) -> int:
    from monitors.backends.load import load_monitor
    from supervisor.analysis_report import format_analysis
    from supervisor.pipeline import monitor_library
    from supervisor.progress import Progress
    from supervisor.validation import validate

    t0 = time.perf_counter()
    progress = Progress()  # one line per stage on stderr, only on a terminal
    checked = validate(args.config, args.k, progress)  # the same validation as run and reload
    project = checked.project
    failures = _print_project(project)
    _print_variables(project)
    n = len(project.requirements)
    if failures:
        _out(
            f"{args.config}: {n} requirements, {n - sum(1 for r in project.requirements if not r.ok)} ok; "
            f"{failures} error(s); monitor not compiled"
        )
        return EXIT_FAIL
    if checked.analysis is not None:
        _out(format_analysis(checked.analysis))
    elif checked.report is not None:  # from the start-up cache (supervisor/cache.py)
        _out(checked.report)
    spec = project.spec()
    with (
        progress.stage("compile"),
        tempfile.TemporaryDirectory(prefix="safety-supervisor-check-") as tmp,
    ):
        load_monitor(monitor_library(spec, Path(tmp), checked.cache, checked.key), spec)
    _print_margins(spec)
    _print_predictions(project)
    dt = time.perf_counter() - t0
    if checked.errors:
        _out(
            f"{args.config}: {n} requirements formalized, analysis found "
            f"{len(checked.errors)} error(s); monitor compiled and loaded ({dt:.2f} s)"
        )
        return EXIT_FAIL
    _out(f"{args.config}: {n} requirements ok, monitor compiled and loaded ({dt:.2f} s)")
    return EXIT_OK


def cmd_compile(args: argparse.Namespace) -> int:
    from supervisor.config import load_config
    from supervisor.pipeline import build_project, compile_project

    project = build_project(load_config(args.config))
    if not project.ok:
        _print_project(project)
        err = project.first_error()
        _err(f"{args.config}: not compiled: {err}")
        return EXIT_FAIL
    out = Path(args.output)
    manifest = compile_project(project, out, backend=args.backend)
    _out(
        f"wrote {out}/monitor.c, monitor.h, {manifest['library']} and manifest.json "
        f"({len(manifest['requirements'])} requirements, backend {args.backend})"
    )
    return EXIT_OK


def cmd_run(args: argparse.Namespace) -> int:
    from supervisor.daemon.process import run_daemon

    return run_daemon(args.config, log_path=args.log, build_dir=args.build_dir, record=args.record)


# ------------------------------------------------------------------ main

COMMANDS: dict[str, Callable[[argparse.Namespace], int]] = {
    "init": cmd_init,
    "formalize": cmd_formalize,
    "explain": cmd_explain,
    "check": cmd_check,
    "compile": cmd_compile,
    "logs": cmd_logs,
    "run": cmd_run,
    "reset": cmd_reset,
    "status": cmd_status,
    "reload": cmd_reload,
    "ui": cmd_ui,
    "install-service": cmd_install_service,
    "demo": cmd_demo,
    "inject": cmd_inject,
    "replay": cmd_replay,
    "fleet": cmd_fleet,
    "report": cmd_report,
    "bench": cmd_bench,
}


def k_arg(text: str) -> int:
    """argparse type of ``--k``: a trace length of at least one tick (else usage error)."""
    try:
        k = int(text)
    except ValueError:
        k = 0
    if k < 1:
        raise argparse.ArgumentTypeError(f"--k needs a whole number of ticks >= 1, not '{text}'")
    return k


def _version() -> str:
    """The installed distribution's version (its metadata, as pip shows it)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("safety-supervisor")
    except PackageNotFoundError:  # run from a checkout that was never installed
        return "unknown (not installed)"


class _Version(argparse.Action):
    """``--version``, its metadata read only when asked: every other start skips
    importlib.metadata (docs/BENCHMARKS.md, "Start-up")."""

    def __init__(self, option_strings: list[str], dest: str, **kwargs: object) -> None:
        super().__init__(
            option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, nargs=0,
            help=str(kwargs.get("help")),
        )  # fmt: skip

    def __call__(self, parser: argparse.ArgumentParser, *_args: object) -> None:
        print(f"{parser.prog} {_version()}", flush=True)
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="safety-supervisor",
        description="Runtime-verification safety supervisor for ROS 2 robots.",
    )
    p.add_argument("--version", action=_Version, help="the installed package's version, and exit")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add_init_parser(sub)

    f = sub.add_parser("formalize", help="FRETISH sentences to past-time formulas (FRET syntax)")
    f.add_argument("text", nargs="*", help="sentences; one per line on stdin when none are given")
    f.add_argument(
        "--json", action="store_true", help='one {"text","formula","error"} object per line'
    )
    f.add_argument(
        "--period-ms", type=float, default=None, help="tick length for durations in time units"
    )

    e = sub.add_parser(
        "explain", help="text, formula, reading, variables and handler of each requirement"
    )
    e.add_argument("config")
    e.add_argument("requirements", nargs="*", metavar="REQ")
    e.add_argument("--k", type=k_arg, default=None, help="analysed trace length in ticks")

    c = sub.add_parser("check", help="validate config and requirements, compile the monitor")
    c.add_argument("config")
    c.add_argument("--k", type=k_arg, default=None, help="analysed trace length in ticks")

    k = sub.add_parser("compile", help="write monitor.c/.h, the shared library and manifest.json")
    k.add_argument("config")
    k.add_argument("-o", "--output", required=True, metavar="DIR")
    k.add_argument("--backend", choices=("native", "copilot"), default="native")
    r = sub.add_parser(
        "run", help="the daemon: monitor the configured topics (systemd Type=notify)"
    )
    r.add_argument("config")
    r.add_argument("--log", default=None, metavar="PATH", help="violation log (default: config)")
    r.add_argument(
        "--build-dir",
        default=None,
        metavar="DIR",
        help="where to build the monitor (default: temp)",
    )
    r.add_argument(
        "--record",
        default=None,
        metavar="DIR",
        help="record inputs and records into rosbag2 MCAP bags in DIR (also record.path)",
    )
    add_logs_parser(sub)
    add_reset_parser(sub)
    add_status_parser(sub)
    add_reload_parser(sub)
    add_ui_parser(sub)
    add_install_parser(sub)
    add_demo_parser(sub)
    add_inject_parser(sub)
    add_replay_parser(sub)
    add_fleet_parser(sub)
    add_report_parser(sub)
    add_bench_parser(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    # a standard stream closed by the caller (2>&-) is None in Python: what would be
    # written there is dropped, and what is read there is empty
    for name, mode in (("stdin", "r"), ("stdout", "w"), ("stderr", "w")):
        if getattr(sys, name) is None:
            setattr(sys, name, open(os.devnull, mode))  # noqa: SIM115 - for the process
    out = _Stdout(sys.stdout)
    err = _Stderr(sys.stderr)
    sys.stdout = out  # type: ignore[assignment] - a TextIO in all but name
    sys.stderr = err  # type: ignore[assignment]
    try:
        return _main(argv, out)
    finally:
        if sys.stdout is out:
            sys.stdout = out.stream
        if sys.stderr is err:
            sys.stderr = err.stream
        if err.failed:  # what it still holds would fail the interpreter's flush at exit
            os.dup2(os.open(os.devnull, os.O_WRONLY), err.stream.fileno())


class _Stdout:
    """sys.stdout, noting whether a write to it failed: a full disk under a redirect
    is the user's to hear of, not an internal error."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.failed = False

    def write(self, text: str) -> int:
        try:
            return self.stream.write(text)
        except OSError:
            self.failed = True
            raise

    def flush(self) -> None:
        try:
            self.stream.flush()
        except OSError:
            self.failed = True
            raise

    def __getattr__(self, name: str) -> Any:
        return getattr(self.stream, name)


class _Stderr(_Stdout):
    """sys.stderr, where a write that fails (a full disk under a redirect) is dropped:
    there is nowhere left to say so, and a warning that cannot be shown must not
    change what the command did or its exit code."""

    def write(self, text: str) -> int:
        try:
            return self.stream.write(text)
        except OSError:
            self.failed = True
            return len(text)

    def flush(self) -> None:
        try:
            self.stream.flush()
        except OSError:
            self.failed = True


def _main(argv: list[str] | None, out: _Stdout) -> int:
    try:
        args = build_parser().parse_args(argv)  # --help writes to stdout too
        return COMMANDS[args.command](args)
    except UserError as e:
        _err(str(e))
        return EXIT_FAIL
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # `safety-supervisor explain ... | head`: the reader left; not an error.
        _drop_stdout()
        return 0
    except OSError as e:
        if e.filename is not None and not out.failed:
            # a path the system refused (too long, not permitted, read-only): the
            # user's to fix, wherever it was met
            from monitors.untrusted import printable

            _err(f"{printable(str(e.filename))}: {e.strerror or e}")
            return EXIT_FAIL
        if not out.failed:
            return _internal(e)
        # a full disk under a redirect (ENOSPC, EIO): the output is lost, and said so
        _err(f"<stdout>: cannot write the output: {e.strerror or e}")
        _drop_stdout()
        return EXIT_FAIL
    except Exception as e:  # noqa: BLE001 - last line of defence: no raw tracebacks for users
        return _internal(e)


def _internal(e: Exception) -> int:
    if os.environ.get("SAFETY_SUPERVISOR_DEBUG"):
        raise e
    _err(
        f"safety-supervisor: internal error: {type(e).__name__}: {e} "
        "(set SAFETY_SUPERVISOR_DEBUG=1 for the traceback and report it)"
    )
    return 3


def _drop_stdout() -> None:
    """stdout to /dev/null: the interpreter's flush at exit then has nowhere to fail."""
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
