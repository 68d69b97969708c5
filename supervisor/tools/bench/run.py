"""``safety-supervisor bench``: the thesis's overhead and latency experiments.

Prints numbers and asserts nothing (speed goals are benchmarks, not tests).

1. Throughput and overhead (thesis sec. 5.1.1, eq. 1:
   Overhead = (P_standalone - P_monitor) / P_monitor x 100 %, P = messages
   received per second).  Per offered rate, one publisher process spreads the
   rate evenly over the config's input topics (a nominal state that satisfies
   every requirement, the step trigger last in each round); in the same run
   the daemon and a plain rclpy wait-set subscriber (optionally also rclpy's
   default executor) receive the same stream.  The daemon's counts come from
   its ``stop`` record, its drain is watched on ``/diagnostics``.
2. Latency (issue 4): the violating message's trigger published -> the halt
   received by another process, over many trials, measured in that one
   process with ``time.monotonic_ns``; first against a bare rclpy echo (the
   DDS round trip alone), then against the daemon, whose violation record is
   fsynced before the halt goes out.  Each trial: the nominal state, the
   violating values, then the trigger alone; before each part the driver
   waits for a handshake on the responder's reset service (served by its
   loop after the messages published before it) and, for the daemon, for the
   reset and mitigation records of the previous trial, so every trial starts
   from an idle responder in a holding state.  The daemon's log adds where
   its time goes (trigger -> violation record, detection -> halt published).

Every process runs on this machine with localhost-only discovery and a random
ROS_DOMAIN_ID outside the test suite's range; all of them are killed (process
groups, and PR_SET_PDEATHSIG should this process die) on exit, Ctrl-C and errors.
"""

from __future__ import annotations

import argparse
import calendar
import contextlib
import json
import os
import random
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from supervisor import data

ROOT = Path(__file__).resolve().parents[3]
DEFAULT_CONFIG = data.example("srobot.yaml")
DEFAULT_RATES = "5000,10000,12500,15000,17500,20000"
DEPTH = 1000
# tests/rosutil.py draws ROS_DOMAIN_ID from 1..200; 215..232 is disjoint from it
# and, unlike 102..214, clear of Linux's ephemeral port range.
DOMAIN_IDS = (215, 232)

# The thesis's sRobot: a nominal state satisfying every requirement, and the
# violating state of the latency experiment (state_req103: a trained worker in
# the red zone, OpState not 3) with the step trigger turnoffUVC false.
SROBOT_NOMINAL = {"classifier": 0, "distance_to_target": 50, "OpState": 0}
SROBOT_VIOLATING = {
    "classifier": 1,
    "distance_to_target": 2,
    "OpState": 2,
    "alert": True,
    "slowdown": True,
    "halt": False,
    "turnoffUVC": False,
}
SROBOT_NOMINAL_CHECK = {"classifier": 0, "halt": False}
LATENCY_REQUIREMENT = "state_req103"
HALT_MITIGATION = "stop_robot"
THESIS_MEAN_MS = 33.0  # thesis: OGMA/Copilot node, violation -> halt, average
TESSLA_MEAN_MS = 15.0  # thesis: TeSSLa-ROS-Bridge, average


class BenchError(Exception):
    """One line for the user."""


# ------------------------------------------------------------------ CLI


def _rates(text: str) -> list[float]:
    try:
        rates = [float(r) for r in text.split(",") if r.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma-separated list of rates: {text}") from None
    if not rates or any(r <= 0 for r in rates):
        raise argparse.ArgumentTypeError("rates must be positive messages per second")
    return rates


def _positive(kind: type) -> Callable[[str], Any]:
    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text}") from None
        if value <= 0:
            raise argparse.ArgumentTypeError(f"must be positive: {text}")
        return value

    return parse


def _add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="default: config/srobot.yaml")
    p.add_argument(
        "--rates",
        type=_rates,
        default=_rates(DEFAULT_RATES),
        metavar="R,R,...",
        help=f"total offered msg/s over all topics (default {DEFAULT_RATES})",
    )
    p.add_argument("--seconds", type=_positive(float), default=5.0, help="per rate (default 5)")
    p.add_argument(
        "--latency-trials", type=_positive(int), default=1000, metavar="N", help="default 1000"
    )
    p.add_argument("--skip-throughput", action="store_true")
    p.add_argument("--skip-latency", action="store_true")
    p.add_argument(
        "--naive",
        action="store_true",
        help="also measure rclpy's default SingleThreadedExecutor (busy: takes a CPU)",
    )
    p.add_argument("--domain-id", type=int, default=None, help="default: random in 215..232")
    p.add_argument("--json", action="store_true", help="one JSON document instead of tables")


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "bench", help="the thesis's overhead and latency experiment, with and without the daemon"
    )
    _add_arguments(p)


def cmd_bench(args: argparse.Namespace) -> int:
    restore = None
    if threading.current_thread() is threading.main_thread():
        # SIGTERM unwinds like Ctrl-C, so the finally blocks kill the children.
        restore = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        results = run(args, progress=None if args.json else _progress)
    except BenchError as e:
        print(f"safety-supervisor bench: {e}", file=sys.stderr, flush=True)
        return 1
    except KeyboardInterrupt:
        print("safety-supervisor bench: interrupted", file=sys.stderr, flush=True)
        return 130
    finally:
        if restore is not None:
            signal.signal(signal.SIGTERM, restore)
    if args.json:
        print(json.dumps(results, indent=2), flush=True)
    else:
        print(format_results(results), flush=True)
    return 0


def _raise_interrupt(_signum: int, _frame: Any) -> None:
    raise KeyboardInterrupt


def _progress(text: str) -> None:
    print(f"  ... {text}", file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    """``python -m supervisor.tools.bench.run``: the same as ``safety-supervisor bench`` (one error
    handling for every command: the CLI's)."""
    from supervisor.cli import main as cli_main

    return cli_main(["bench", *(sys.argv[1:] if argv is None else argv)])


# ------------------------------------------------------------------ plan


class Plan:
    """What the config says the bench publishes, and the configs the daemon runs."""

    def __init__(self, config: Path) -> None:
        from monitors.errors import UserError
        from supervisor.config.load import load_config

        try:
            self.cfg = load_config(config)
        except UserError as e:
            raise BenchError(str(e)) from None
        self.path = config
        cfg = self.cfg
        inputs = list(cfg.inputs)
        if not inputs:
            raise BenchError(f"{config}: no input variables with topics")
        trigger = cfg.step.trigger if cfg.step.policy == "on_trigger" else None
        # The trigger is published last in each round: it ends a tick.
        inputs.sort(key=lambda v: v.name == trigger)
        self.trigger = trigger or inputs[-1].name
        self.topics = [
            {"name": v.name, "topic": v.topic, "msg": v.msg, "field": v.field} for v in inputs
        ]
        self.nominal = {v.name: _nominal(v) for v in inputs}
        self.daemon_node = cfg.ros.node_name

    def latency_problem(self) -> str | None:
        """Why this config cannot run the latency experiment, or None."""
        names = {t["name"] for t in self.topics}
        missing = sorted(set(SROBOT_VIOLATING) - names)
        if missing:
            return f"the latency experiment needs the sRobot inputs (missing: {', '.join(missing)})"
        if self.trigger != "turnoffUVC":
            return "the latency experiment needs step.policy on_trigger with trigger turnoffUVC"
        if not any(r.id == LATENCY_REQUIREMENT for r in self.cfg.requirements):
            return f"the latency experiment needs requirement {LATENCY_REQUIREMENT}"
        m = self.cfg.mitigations.get(HALT_MITIGATION)
        if m is None or m.kind != "publish":
            return f"the latency experiment needs a publish mitigation '{HALT_MITIGATION}'"
        return None

    @property
    def halt(self) -> tuple[str, str]:
        p = self.cfg.mitigations[HALT_MITIGATION].params
        return str(p["topic"]), str(p["msg"])

    def write_config(self, out: Path, log: Path, *, latency: bool) -> Path:
        """A copy of the config for the daemon: inputs reliable with depth 1000 (the
        baselines' QoS), no on_stale (a stale halt would add messages nobody sent),
        the log in our temp dir; for latency, state_req103 acts at every violation."""
        import yaml

        doc = yaml.safe_load(self.path.read_text())
        base = self.path.resolve().parent
        for key in ("requirements_from", "variables_from"):
            if isinstance(doc.get(key), str) and not os.path.isabs(doc[key]):
                doc[key] = str(base / doc[key])
        for spec in (doc.get("variables") or {}).values():
            if isinstance(spec, dict) and "topic" in spec:
                spec["qos"], spec["depth"] = "reliable", DEPTH
        doc.pop("on_stale", None)
        doc.setdefault("logging", {})["violations"] = str(log)
        if latency:
            reqs = doc.setdefault("requirements", [])
            entry = next((r for r in reqs if r.get("id") == LATENCY_REQUIREMENT), None)
            if entry is None:  # imported (requirements_from): refine it by id
                entry = {"id": LATENCY_REQUIREMENT}
                reqs.append(entry)
            entry["on_violation"] = [HALT_MITIGATION]
            entry["policy"] = {"debounce_steps": 1, "reset": "after_mitigation"}
        out.write_text(yaml.safe_dump(doc, sort_keys=False))
        return out


def _nominal(v: Any) -> Any:
    if v.name in SROBOT_NOMINAL:
        return SROBOT_NOMINAL[v.name]
    if v.type == "bool":
        return False
    zero: Any = 0.0 if v.type == "double" else 0
    if v.range is not None and not (v.range[0] <= zero <= v.range[1]):
        return v.range[0]
    return zero


# ------------------------------------------------------------------ processes


def _cpu_seconds(pid: int) -> float:
    """utime + stime of every thread of ``pid`` (DDS threads included)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return float("nan")
    fields = stat[stat.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class Child:
    """A helper process (``python -m supervisor.tools.bench.procs ...``) in its own
    process group, its JSON-lines stdout collected by a thread."""

    def __init__(self, label: str, argv: list[str], env: dict[str, str], stderr: Path) -> None:
        self.label = label
        self.stderr_path = stderr
        self.events: list[tuple[float, dict[str, Any]]] = []
        self._cond = threading.Condition()
        with stderr.open("w") as err:
            self.proc = subprocess.Popen(
                argv,
                cwd=ROOT,
                env=env,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=err,
                text=True,
                start_new_session=True,  # its own process group: killed as a whole
            )
        self._reader = threading.Thread(target=self._read, name=f"bench-{label}", daemon=True)
        self._reader.start()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            try:
                event = json.loads(line)
            except ValueError:
                continue
            if isinstance(event, dict):
                with self._cond:
                    self.events.append((time.monotonic(), event))
                    self._cond.notify_all()
        with self._cond:
            self._cond.notify_all()

    def last_stderr(self) -> str:
        try:
            lines = [ln for ln in self.stderr_path.read_text().splitlines() if ln.strip()]
        except OSError:
            return ""
        return lines[-1] if lines else ""

    def check(self) -> None:
        """Raise BenchError if the child reported an error or died."""
        for _t, ev in self.events:
            if ev.get("event") == "error":
                raise BenchError(f"{self.label}: {ev.get('error')}")
        if self.proc.poll() is not None:
            why = self.last_stderr()
            raise BenchError(
                f"{self.label} exited ({self.proc.returncode})" + (f": {why}" if why else "")
            )

    def latest(self, kind: str) -> tuple[float, dict[str, Any]] | None:
        with self._cond:
            for t, ev in reversed(self.events):
                if ev.get("event") == kind:
                    return t, ev
        return None

    def wait_event(
        self, kind: str, timeout: float, others: tuple[Child, ...] = ()
    ) -> dict[str, Any]:
        """The first event ``kind``; BenchError if this child (or one of
        ``others``) fails first or ``timeout`` passes."""
        deadline = time.monotonic() + timeout
        while True:
            with self._cond:
                for _t, ev in self.events:
                    if ev.get("event") == kind:
                        return ev
                self._cond.wait(0.1)
            for c in (self, *others):
                c.check()
            if time.monotonic() > deadline:
                raise BenchError(f"{self.label}: no '{kind}' within {timeout:g} s")

    def send(self, line: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def terminate(self, timeout: float = 5.0) -> int | None:
        """SIGTERM (the helper prints its final line), then the group is killed."""
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                self.proc.send_signal(signal.SIGTERM)
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.proc.wait(timeout)
        self.kill()
        self._reader.join(1.0)
        return self.proc.returncode

    def kill(self) -> None:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(5)
        for f in (self.proc.stdin,):
            with contextlib.suppress(Exception):
                f.close()  # type: ignore[union-attr]


class DaemonChild(Child):
    """``python -m supervisor run CONFIG --log FILE --build-dir DIR`` with a bound
    NOTIFY_SOCKET, exec'd through ``bench_procs exec`` (PR_SET_PDEATHSIG; same pid)."""

    def __init__(self, config: Path, workdir: Path, env: dict[str, str]) -> None:
        workdir.mkdir(parents=True, exist_ok=True)
        self.log = workdir / "violations.jsonl"
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        sock_path = workdir / "notify.sock"
        self.sock.bind(str(sock_path))
        argv = [
            *_procs_argv("exec"),
            "--",
            sys.executable,
            "-m",
            "supervisor",
            "run",
            str(config),
            "--log",
            str(self.log),
            "--build-dir",
            str(workdir / "build"),
        ]
        super().__init__(
            "daemon", argv, {**env, "NOTIFY_SOCKET": str(sock_path)}, workdir / "daemon.stderr"
        )

    def wait_ready(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise BenchError(f"daemon: not ready within {timeout:g} s: {self.last_stderr()}")
            self.check()
            self.sock.settimeout(min(left, 0.2))
            try:
                data = self.sock.recv(4096).decode()
            except TimeoutError:
                continue
            if "READY=1" in data.splitlines():
                return

    def stop(self, timeout: float = 10.0) -> None:
        """SIGTERM and wait: the daemon writes its ``stop`` record."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                raise BenchError(f"daemon did not stop within {timeout:g} s") from None
        if self.proc.returncode != 0:
            raise BenchError(f"daemon exited ({self.proc.returncode}): {self.last_stderr()}")

    def records(self) -> list[dict[str, Any]]:
        if not self.log.exists():
            return []
        out = []
        for line in self.log.read_text().splitlines():
            with contextlib.suppress(ValueError):
                out.append(json.loads(line))
        return out

    def stop_record(self) -> dict[str, Any]:
        for r in reversed(self.records()):
            if r.get("event") == "supervisor" and r.get("what") == "stop":
                return r
        raise BenchError(f"daemon wrote no stop record in {self.log}")

    def kill(self) -> None:
        super().kill()
        with contextlib.suppress(OSError):
            self.sock.close()


def _procs_argv(role: str) -> list[str]:
    return [sys.executable, "-m", "supervisor.tools.bench.procs", role]


class Session:
    """The temp dir, the ROS environment and every process started (for cleanup)."""

    def __init__(self, domain_id: int | None) -> None:
        self.tmp = Path(tempfile.mkdtemp(prefix="safety-supervisor-bench-"))
        self.domain_id = domain_id if domain_id is not None else random.randint(*DOMAIN_IDS)
        (self.tmp / "ros-log").mkdir()
        env = {
            k: v
            for k, v in os.environ.items()
            if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID", "ROS_LOCALHOST_ONLY")
        }
        env.update(
            ROS_DOMAIN_ID=str(self.domain_id),
            ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
            ROS_LOG_DIR=str(self.tmp / "ros-log"),
            PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")])),
        )
        self.env = env
        self.children: list[Child] = []

    def child(self, label: str, role: str, *args: str, workdir: Path) -> Child:
        workdir.mkdir(parents=True, exist_ok=True)
        c = Child(label, [*_procs_argv(role), *args], self.env, workdir / f"{role}.stderr")
        self.children.append(c)
        return c

    def daemon(self, config: Path, workdir: Path) -> DaemonChild:
        d = DaemonChild(config, workdir, self.env)
        self.children.append(d)
        return d

    def close(self) -> None:
        for c in self.children:
            c.kill()
        self.children = []
        shutil.rmtree(self.tmp, ignore_errors=True)


@contextlib.contextmanager
def session(domain_id: int | None) -> Iterator[Session]:
    s = Session(domain_id)
    try:
        yield s
    finally:
        s.close()


# ------------------------------------------------------------------ the run


def run(args: argparse.Namespace, progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    say = progress or (lambda _text: None)
    config = Path(args.config)
    plan = Plan(config)
    if not args.skip_latency:
        problem = plan.latency_problem()
        if problem:
            raise BenchError(f"{config}: {problem} (use --skip-latency)")
    results: dict[str, Any] = {
        "config": str(config),
        "topics": [t["topic"] for t in plan.topics],
        "trigger": plan.trigger,
        "cpus": os.cpu_count(),
        "loadavg_before": _loadavg(),
        "python": sys.version.split()[0],
        "rmw": os.environ.get("RMW_IMPLEMENTATION") or "default (rmw_fastrtps_cpp)",
    }
    with session(args.domain_id) as s:
        results["domain_id"] = s.domain_id
        if not args.skip_throughput:
            results["throughput"] = []
            for rate in args.rates:
                say(f"throughput at {rate:g} msg/s for {args.seconds:g} s")
                results["throughput"].append(throughput(s, plan, rate, args.seconds, args.naive))
        if not args.skip_latency:
            results["latency"] = latency(s, plan, args.latency_trials, say)
    results["loadavg_after"] = _loadavg()
    return results


def _loadavg() -> str:
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "?"


def throughput(s: Session, plan: Plan, rate: float, seconds: float, naive: bool) -> dict[str, Any]:
    work = Path(tempfile.mkdtemp(prefix=f"throughput-{rate:g}-", dir=s.tmp))
    config = plan.write_config(work / "config.yaml", work / "violations.jsonl", latency=False)
    spec = json.dumps(plan.topics)
    daemon = s.daemon(config, work)
    baselines = {
        "rclpy wait-set": s.child("rclpy wait-set", "waitset", "--spec", spec, workdir=work)
    }
    if naive:
        baselines["rclpy executor"] = s.child(
            "rclpy executor", "executor", "--spec", spec, workdir=work
        )
    pub = s.child(
        "publisher",
        "publisher",
        "--spec",
        spec,
        "--values",
        json.dumps(plan.nominal),
        "--rate",
        str(rate),
        "--seconds",
        str(seconds),
        "--receivers",
        str(1 + len(baselines)),
        "--diagnostics",
        "--daemon-node",
        plan.daemon_node,
        workdir=work,
    )
    everyone = (daemon, pub, *baselines.values())
    try:
        daemon.wait_ready(60)
        pub.wait_event("matched", 60, everyone)
        for b in baselines.values():
            b.wait_event("matched", 60, everyone)  # they see the publisher too
        pids = {"daemon": daemon.pid, **{k: b.pid for k, b in baselines.items()}}
        cpu0 = {k: _cpu_seconds(p) for k, p in pids.items()}
        pub.send("go")
        done = pub.wait_event("done", seconds * 4 + 30, everyone)
        sent: dict[str, int] = done["sent"]
        drained = _wait_drained(pub, baselines, sent, done["wall"], everyone)
        cpu1 = {k: _cpu_seconds(p) for k, p in pids.items()}
        daemon.stop()
        stop = daemon.stop_record()
        received = {"daemon": {n: c["messages"] + c["rejected"] for n, c in stop["inputs"].items()}}
        for name, b in baselines.items():
            b.terminate()
            final = b.latest("final") or b.latest("counts")
            if final is None:
                raise BenchError(f"{name}: reported no counts")
            received[name] = final[1]["counts"]
    finally:
        for c in everyone:
            c.kill()
    total_sent = sum(sent.values())
    out: dict[str, Any] = {
        "offered": rate,
        "seconds": done["seconds"],
        "sent": total_sent,
        "sent_per_topic": sent,
        "achieved": done["achieved"],
        "drained": drained,
        "daemon_violations": stop.get("violations"),
        "receivers": {},
    }
    for name, per_topic in received.items():
        n = sum(int(per_topic.get(t, 0)) for t in sent)
        cpu = cpu1[name] - cpu0[name]
        out["receivers"][name] = {
            "received": n,
            "received_per_topic": per_topic,
            "loss_pct": 100.0 * (total_sent - n) / total_sent,
            "msg_per_s": n / done["seconds"],
            "cpu_s": cpu,
            "cpu_us_per_msg": 1e6 * cpu / n if n else None,
        }
    fastest = max(baselines, key=lambda k: out["receivers"][k]["received"])
    p_standalone = out["receivers"][fastest]["msg_per_s"]
    p_monitor = out["receivers"]["daemon"]["msg_per_s"]
    out["fastest_baseline"] = fastest
    # Eq. 1 of the thesis; the publishing window is the same for both receivers.
    out["overhead_pct"] = 100.0 * (p_standalone - p_monitor) / p_monitor if p_monitor else None
    return out


def _wait_drained(
    pub: Child,
    baselines: dict[str, Child],
    sent: dict[str, int],
    done_wall: float,
    everyone: tuple[Child, ...],
    timeout: float = 30.0,
) -> bool:
    """Until every receiver's counts stop increasing (or equal what was sent).
    The daemon's come from its /diagnostics reports (1 Hz) published after the
    publisher finished, relayed by the publisher process."""
    deadline = time.monotonic() + timeout
    quiet = 0.5  # a baseline reports every 0.1 s: five equal reports
    last: dict[str, tuple[dict[str, int], float]] = {}
    while time.monotonic() < deadline:
        for c in everyone:
            c.check()
        ok = True
        diags = [
            ev for _t, ev in pub.events if ev.get("event") == "diag" and ev["stamp"] > done_wall
        ]
        if not (
            diags
            and (
                diags[-1]["counts"] == sent
                or (len(diags) >= 2 and diags[-1]["counts"] == diags[-2]["counts"])
            )
        ):
            ok = False
        now = time.monotonic()
        for name, b in baselines.items():
            got = b.latest("counts")
            if got is None:
                ok = False
                continue
            counts = got[1]["counts"]
            prev = last.get(name)
            if prev is None or prev[0] != counts:
                last[name] = (counts, now)
            if counts != sent and now - last[name][1] < quiet:
                ok = False
        if ok:
            return True
        time.sleep(0.05)  # polling interval
    return False


def latency(s: Session, plan: Plan, trials: int, say: Callable[[str], None]) -> dict[str, Any]:
    work = s.tmp / "latency"
    work.mkdir()
    spec = json.dumps(plan.topics)
    halt_topic, halt_msg = plan.halt
    warmup = 10
    common = ["--spec", spec, "--trigger", plan.trigger, "--halt-topic", halt_topic]
    common += ["--halt-msg", halt_msg]
    driver_args = [
        *common,
        "--nominal",
        json.dumps(plan.nominal),  # halt false: each trial starts from a holding state
        "--violating",
        json.dumps(SROBOT_VIOLATING),
        "--trials",
        str(trials),
        "--warmup",
        str(warmup),
    ]
    budget = 120 + trials * 0.2
    out: dict[str, Any] = {"trials": trials, "warmup": warmup}

    say(f"latency: bare rclpy echo, {trials} trials")
    echo = s.child(
        "echo",
        "echo",
        *common,
        "--when",
        f"classifier={SROBOT_VIOLATING['classifier']}",
        workdir=work / "echo",
    )
    driver = s.child("driver", "driver", *driver_args, workdir=work / "echo")
    try:
        echo.wait_event("started", 60, (echo, driver))
        result = driver.wait_event("result", budget, (echo, driver))
    finally:
        driver.kill()
        echo.kill()
    out["echo"] = _latency_stats(result)

    say(f"latency: daemon, {trials} trials")
    dwork = work / "daemon"
    dwork.mkdir()
    config = plan.write_config(dwork / "config.yaml", dwork / "violations.jsonl", latency=True)
    daemon = s.daemon(config, dwork)
    try:
        daemon.wait_ready(60)
        log_args = ["--log", str(daemon.log), "--requirement", LATENCY_REQUIREMENT]
        driver = s.child("driver", "driver", *driver_args, *log_args, workdir=dwork)
        try:
            result = driver.wait_event("result", budget, (daemon, driver))
        finally:
            driver.kill()
        daemon.stop()
        records = daemon.records()
    finally:
        daemon.kill()
    out["daemon"] = _latency_stats(result)
    out["daemon"].update(_daemon_internals(records, warmup, result))
    out["fsync"] = _fsync_times(s.tmp, out["daemon"].get("violation_record_bytes") or 2048)
    out["thesis_mean_ms"] = THESIS_MEAN_MS
    out["tessla_mean_ms"] = TESSLA_MEAN_MS
    return out


def _percentiles(values_ms: list[float]) -> dict[str, float | None]:
    if not values_ms:
        return {k: None for k in ("p50", "p90", "p99", "max", "mean")}
    v = sorted(values_ms)

    def pct(p: int) -> float:
        # nearest rank: the smallest value with at least p % of the samples at or below it
        return v[max(0, min(len(v) - 1, -(-len(v) * p // 100) - 1))]

    return {
        "p50": pct(50),
        "p90": pct(90),
        "p99": pct(99),
        "max": v[-1],
        "mean": statistics.fmean(v),
    }


def _latency_stats(result: dict[str, Any]) -> dict[str, Any]:
    ms = [ns / 1e6 for ns in result["latencies_ns"]]
    return {
        "n": len(ms),
        "missed": result["missed"],
        "stray_halts": result["strays"],
        "sync_timeouts": result.get("sync_timeouts", 0),
        **_percentiles(ms),
    }


def _daemon_internals(
    records: list[dict[str, Any]], warmup: int, result: dict[str, Any]
) -> dict[str, Any]:
    """From the daemon's log: detection -> halt published (the mitigation
    record's latency_ms, fsync of the violation record included), and trigger
    published -> violation record rendered (wall clocks of one machine)."""
    violations = [r for r in records if r.get("event") == "violation"]
    mitigations = [
        r
        for r in records
        if r.get("event") == "mitigation"
        and r.get("requirement") == LATENCY_REQUIREMENT
        and r.get("stage") == "violation"
    ]
    internal = [float(r["latency_ms"]) for r in mitigations[warmup:]]
    sizes = [len(json.dumps(r, separators=(",", ":"))) + 1 for r in violations]
    mine = [r for r in violations if r.get("requirement") == LATENCY_REQUIREMENT]
    # A trial starts from a holding state when the tick before its violation
    # was the nominal state the driver published (classifier 0, halt false).
    not_holding = 0
    for r in mine[warmup:]:
        recent = r.get("recent") or []
        before = recent[-2] if len(recent) >= 2 else {}
        if any(before.get(k) != v for k, v in SROBOT_NOMINAL_CHECK.items()):
            not_holding += 1
    # Each trial's record: the first after its trigger went out (strays aside).
    to_record: list[float] = []
    stamps = [_epoch_ns(r["ts"]) for r in mine]
    j = 0
    for wall in result.get("published_wall_ns") or []:
        while j < len(stamps) and stamps[j] < wall:
            j += 1
        if j < len(stamps):
            to_record.append((stamps[j] - wall) / 1e6)
            j += 1
    return {
        "violation_records": len(violations),
        "trigger_to_record_ms": _percentiles(to_record),
        "other_violations": len(violations) - len(mine),
        "not_from_holding_state": not_holding,
        "detect_to_publish_ms": _percentiles(internal),
        "violation_record_bytes": int(statistics.median(sizes)) if sizes else None,
    }


def _epoch_ns(ts: str) -> int:
    """The log's ``ts`` (ISO 8601 UTC, microseconds) as ns since the epoch."""
    dt = datetime.strptime(ts, "%Y-%m-%dT%H:%M:%S.%fZ").replace(tzinfo=UTC)
    return (calendar.timegm(dt.timetuple()) * 1_000_000 + dt.microsecond) * 1000


def _fsync_times(where: Path, size: int, n: int = 200) -> dict[str, Any]:
    """write + fsync of a violation-record-sized append, on the log's file system."""
    path = where / "fsync-probe.jsonl"
    line = b"x" * (size - 1) + b"\n"
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o640)
    times = []
    try:
        for _ in range(n):
            t = time.perf_counter_ns()
            os.write(fd, line)
            os.fsync(fd)
            times.append((time.perf_counter_ns() - t) / 1e6)
    finally:
        os.close(fd)
        path.unlink()
    return {"bytes": size, "n": n, **_percentiles(times)}


# ------------------------------------------------------------------ output


def _f(x: float | None, fmt: str = ".2f") -> str:
    return "-" if x is None else format(x, fmt)


def format_results(r: dict[str, Any]) -> str:
    lines = [
        f"safety-supervisor bench: {r['config']} ({len(r['topics'])} topics, trigger {r['trigger']})",
        f"machine: {r['cpus']} CPUs, load average {r['loadavg_before']} before, "
        f"{r['loadavg_after']} after; Python {r['python']}; RMW {r['rmw']}; "
        f"ROS_DOMAIN_ID={r.get('domain_id')}, localhost discovery",
    ]
    if "throughput" in r:
        lines += ["", *_format_throughput(r["throughput"])]
    if "latency" in r:
        lines += ["", *_format_latency(r["latency"])]
    return "\n".join(lines)


def _format_throughput(rows: list[dict[str, Any]]) -> list[str]:
    lines = [
        "Throughput and overhead (thesis sec. 5.1.1, eq. 1: "
        "(P_standalone - P_monitor) / P_monitor x 100 %)",
        f"one publisher process, reliable + volatile, depth {DEPTH}, same stream to every receiver",
    ]
    for row in rows:
        per = next(iter(row["sent_per_topic"].values()))
        lines += [
            "",
            f"offered {row['offered']:g} msg/s: sent {row['sent']} ({per}/topic) in "
            f"{row['seconds']:.2f} s = {row['achieved']:.0f} msg/s achieved"
            + ("" if row["drained"] else "  [receivers still busy after 30 s]"),
            f"  {'receiver':<16} {'received':>9} {'loss %':>7} {'msg/s':>8} {'CPU s':>6} "
            f"{'CPU us/msg':>10}",
        ]
        for name, rc in row["receivers"].items():
            lines.append(
                f"  {name:<16} {rc['received']:>9} {rc['loss_pct']:>7.2f} "
                f"{rc['msg_per_s']:>8.0f} {rc['cpu_s']:>6.2f} {_f(rc['cpu_us_per_msg'], '.1f'):>10}"
            )
        lines.append(
            f"  overhead (eq. 1) vs {row['fastest_baseline']}: {_f(row['overhead_pct'])} %"
            + (
                f"; daemon reported {row['daemon_violations']} violations (expected 0)"
                if row["daemon_violations"]
                else ""
            )
        )
    base = {k for row in rows for k in row["receivers"] if k != "daemon"}
    lines += ["", "summary"]
    head = f"  {'offered':>8} {'achieved':>8} {'daemon loss %':>13}"
    for b in sorted(base):
        head += f" {b + ' loss %':>21}"
    head += f" {'overhead %':>10} {'daemon us/msg':>13} {'wait-set us/msg':>15}"
    lines.append(head)
    for row in rows:
        rc = row["receivers"]
        line = f"  {row['offered']:>8g} {row['achieved']:>8.0f} {rc['daemon']['loss_pct']:>13.2f}"
        for b in sorted(base):
            line += f" {_f(rc[b]['loss_pct'] if b in rc else None):>21}"
        ws = rc.get("rclpy wait-set", {}).get("cpu_us_per_msg")
        line += (
            f" {_f(row['overhead_pct']):>10} {_f(rc['daemon']['cpu_us_per_msg'], '.1f'):>13}"
            f" {_f(ws, '.1f'):>15}"
        )
        lines.append(line)
    return lines


def _format_latency(lat: dict[str, Any]) -> list[str]:
    lines = [
        "Latency: violating trigger published -> halt received, in one process "
        f"(time.monotonic_ns); {lat['trials']} trials after {lat['warmup']} warm-up",
        f"  {'responder':<22} {'n':>5} {'p50 ms':>7} {'p90 ms':>7} {'p99 ms':>7} {'max ms':>7} "
        f"{'mean ms':>7} {'missed':>6}",
    ]
    for label, key in (("bare rclpy echo", "echo"), ("safety-supervisor", "daemon")):
        st = lat[key]
        lines.append(
            f"  {label:<22} {st['n']:>5} {_f(st['p50'], '.3f'):>7} {_f(st['p90'], '.3f'):>7} "
            f"{_f(st['p99'], '.3f'):>7} {_f(st['max'], '.3f'):>7} {_f(st['mean'], '.3f'):>7} "
            f"{st['missed']:>6}"
        )
    d = lat["daemon"]
    inner = d["detect_to_publish_ms"]
    rec = d["trigger_to_record_ms"]
    lines += [
        f"  daemon, trigger published -> violation record stamped (before its fsync): p50 "
        f"{_f(rec['p50'], '.3f')} ms, p99 {_f(rec['p99'], '.3f')} ms, max {_f(rec['max'], '.3f')} ms",
        f"  daemon, detection -> halt published (its mitigation records): p50 "
        f"{_f(inner['p50'], '.3f')} ms, p99 {_f(inner['p99'], '.3f')} ms, "
        f"max {_f(inner['max'], '.3f')} ms",
    ]
    fs = lat["fsync"]
    lines.append(
        f"  fsync of a {fs['bytes']}-byte append on the log's file system ({fs['n']} samples): "
        f"p50 {_f(fs['p50'], '.3f')} ms, p99 {_f(fs['p99'], '.3f')} ms, "
        f"max {_f(fs['max'], '.3f')} ms"
    )
    if (
        d["other_violations"]
        or d["stray_halts"]
        or lat["echo"]["stray_halts"]
        or d["not_from_holding_state"]
        or d["sync_timeouts"]
        or lat["echo"]["sync_timeouts"]
    ):
        lines.append(
            f"  note: {d['other_violations']} violations of other requirements, "
            f"{d['not_from_holding_state']} trials not stepped from the nominal state, stray "
            f"halts {lat['echo']['stray_halts']} (echo) / {d['stray_halts']} (daemon) while "
            f"settling, handshake timeouts {lat['echo']['sync_timeouts']} / {d['sync_timeouts']}"
        )
    mean = d["mean"]
    cmp = "" if mean is None else f" ({THESIS_MEAN_MS / mean:.0f}x faster than the thesis's mean)"
    lines.append(
        f"  thesis: {THESIS_MEAN_MS:g} ms mean (OGMA/Copilot node), TeSSLa-ROS-Bridge "
        f"{TESSLA_MEAN_MS:g} ms mean; here: {_f(mean, '.3f')} ms mean{cmp}"
    )
    return lines


if __name__ == "__main__":
    raise SystemExit(main())
