"""``safety-supervisor run``: the process around :class:`~supervisor.daemon.node.SupervisorNode`.

Start-up order matters to systemd: the config is checked and the monitor
compiled and loaded, subscriptions are created, and only then ``READY=1``.
SIGTERM/SIGINT: ``STOPPING=1`` and a clean exit within 2 s.  SIGHUP: the
config is reloaded (``RELOADING=1``, then ``READY=1`` once the new config is
in force or refused; ``safety-supervisor reload`` asks the same on the control
socket and waits for the outcome); a config that fails the same checks as
``safety-supervisor check`` is rejected, the reason is logged and the running
monitor continues untouched.  SIGUSR1: the violation log is reopened
(logrotate), nothing else.  No signal is lost: one that arrives before the
node exists, or during a reload, is served when it can be
(docs/reference/ros-interfaces.md#signals).
"""

from __future__ import annotations

import contextlib
import faulthandler
import os
import shutil
import signal
import sys
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

import rclpy
from rclpy.context import Context

from mitigations.violationlog.writer import ViolationLog
from monitors.backends.load import load_monitor
from monitors.errors import UserError
from supervisor.analysis_child import Aside
from supervisor.config import Config, read_config
from supervisor.config.record import RecordConfig
from supervisor.daemon import heap
from supervisor.daemon.control import open_control
from supervisor.daemon.node import SupervisorNode
from supervisor.daemon.notify import Notifier, watchdog_interval
from supervisor.daemon.session import Session, build_session
from supervisor.daemon.transport import udp_only
from supervisor.pipeline import monitor_library

if TYPE_CHECKING:  # rosbags loads only when recording is on
    from supervisor.daemon.recorder import Recorder


def init_ros(domain_id: int | None = None) -> Context:
    """A fresh rclpy context without rclpy's signal handlers (the daemon has its own)."""
    from rclpy.signals import SignalHandlerOptions

    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
    return ctx


def _shutdown_ros(ctx: Context) -> None:
    with contextlib.suppress(Exception):
        rclpy.shutdown(context=ctx)


def prepare_session(
    config: str | Path, build_root: Path, skipped: Callable[[str], None] | None = None
) -> Session:
    """Validate ``config`` as ``check`` does (the same analyses, in a child process)
    and compile it into a loaded Session; raises UserError.  ``skipped`` hears why the analyses did not
    run in full, for the log (docs/reference/log.md)."""
    # Read once: the monitor, the analyses and the session's hash are of the same
    # bytes however the file changes meanwhile (supervisor/analysis_child.py).
    # The analyses run in a child (z3's memory stays there) while the monitor compiles.
    aside = Aside(read_config(config))
    err = aside.project.first_error()
    if err is not None:
        raise err
    project = aside.project
    build_root.mkdir(parents=True, exist_ok=True)
    build = Path(tempfile.mkdtemp(prefix="monitor-", dir=build_root))
    try:
        # From the start-up cache when check or an earlier start built it (supervisor/cache.py).
        spec = project.spec()
        monitor = load_monitor(monitor_library(spec, build, aside.cache, aside.key), spec)
        checked = aside.result()
        err = checked.first_error()
        if err is not None:
            raise err
    except BaseException:
        aside.cancel()
        shutil.rmtree(build, ignore_errors=True)
        raise
    if checked.skipped and skipped is not None:
        skipped(checked.skipped)
    cache = aside.cache

    def cleanup() -> None:
        shutil.rmtree(build, ignore_errors=True)
        if cache is not None:
            # Held until now: no pruner removes the entry of the config in force
            # (supervisor/cache.py).
            cache.close()

    return build_session(project, monitor, cleanup=cleanup)


def open_recorder(cfg: Config, path: str | None, log: ViolationLog) -> Recorder | None:
    """The recorder of ``run --record PATH`` or ``record.path``, else None. It
    reports into the log: what it leaves out, and why it stopped (recording stops,
    monitoring never does)."""
    settings = cfg.record or RecordConfig()
    if path is None and settings.path is None:
        return None
    from supervisor.daemon.recorder import Recorder  # rosbags: only when recording

    topics = list(dict.fromkeys((v.topic or "", v.msg or "") for v in cfg.inputs))

    # Each record is echoed on stderr (or sent to the journal) by the log itself:
    # a print as well would say every warning twice (docs/reference/log.md).
    def stopped(reason: str) -> None:
        log.supervisor("record_stopped", reason=reason)

    def warning(text: str) -> None:
        log.supervisor("record_warning", detail=text)

    try:
        recorder = Recorder.from_config(
            settings, topics, path=path, on_stopped=stopped, on_warning=warning
        )
    except OSError as e:
        raise UserError(
            f"cannot record into {path or settings.path}: {e.strerror}",
            file=cfg.path,
            line=settings.line,
        ) from None
    log.supervisor(
        "record",
        path=str(recorder.directory),
        topics=[t for t, _ in topics],
        writer_pid=recorder.writer_pid,  # the process that writes the bags (bench reads it)
    )
    return recorder


class _Signals:
    """SIGTERM/SIGINT stop the daemon, SIGHUP reloads the config, SIGUSR1 reopens the
    log; one that comes before the node exists is served once it does."""

    def __init__(self, reload_session: Callable[[], Session]) -> None:
        self.reload_session = reload_session
        self.stop_requested = threading.Event()
        self.node: SupervisorNode | None = None
        self.early: set[int] = set()  # SIGHUP/SIGUSR1 before the node exists

    def install(self) -> None:
        for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP, signal.SIGUSR1):
            signal.signal(sig, self.on_signal)

    def on_signal(self, signum: int, _frame: Any) -> None:
        node = self.node
        if signum in (signal.SIGHUP, signal.SIGUSR1):
            if node is None:
                self.early.add(signum)
            elif signum == signal.SIGHUP:
                node.request_reload(self.reload_session)
            else:
                node.request_reopen()
            return
        self.stop_requested.set()
        if node is not None:
            node.stop()

    def attach(self, node: SupervisorNode) -> None:
        """From now on signals go to ``node``; those that came before, too."""
        self.node = node
        if self.stop_requested.is_set():
            node.stop()
        if signal.SIGUSR1 in self.early:
            node.request_reopen()
        if signal.SIGHUP in self.early:
            node.request_reload(self.reload_session)


def _ros_log_dir(stack: contextlib.ExitStack) -> None:
    """rclpy writes its own log files; under ProtectSystem=strict only a few places
    are writable.  A directory made here is removed at exit."""
    if not os.environ.get("ROS_LOG_DIR"):
        stack.callback(os.environ.pop, "ROS_LOG_DIR", None)
        os.environ["ROS_LOG_DIR"] = os.environ.get("LOGS_DIRECTORY") or stack.enter_context(
            tempfile.TemporaryDirectory(prefix="safety-supervisor-ros-log-")
        )


def _open_log(
    stack: contextlib.ExitStack, session: Session, config: str, log_path: str | None
) -> ViolationLog:
    """The violation log, open until ``stack`` closes."""
    cfg = session.config
    path = log_path or cfg.log_path
    if not path:
        raise UserError(
            "no violation log configured", file=config, hint="set logging.violations or --log"
        )
    _ros_log_dir(stack)
    return stack.enter_context(
        ViolationLog(
            path,
            cfg.component,
            cfg.sha256,
            retry_buffer=cfg.log_retry_buffer,
            durability=cfg.log_durability,
        )
    )


def _log_start(log: ViolationLog, config: str, session: Session, skipped: list[str]) -> None:
    """The start record, and what the validation could not judge or warned of."""
    log.supervisor("start", config=str(config), pid=os.getpid(), **session.config.log_fields())
    for why in skipped:  # run validates as check does; say what it could not judge
        log.supervisor("analysis_skipped", why=why)
    for w in session.project.warnings:  # e.g. an SSH key the robot does not hold
        log.supervisor("check_warning", detail=w)


def run_daemon(
    config: str,
    log_path: str | None = None,
    build_dir: str | None = None,
    record: str | None = None,
) -> NoReturn:
    """Raises UserError for a bad config at start (exit 1 with FILE:LINE); otherwise
    ends the process once stopped (see :func:`_exit`)."""
    # A crash in native code (rclpy, the DDS) leaves every Python thread's stack
    # on stderr, so in the journal: the one clue a SIGSEGV at shutdown gives.
    faulthandler.enable(all_threads=True)
    notifier = Notifier(unset_environment=True)
    build_root: Path

    logs: list[ViolationLog] = []  # the open log, for the reload thread's records

    def reload_session() -> Session:
        def skipped(why: str) -> None:
            for log in logs:
                log.supervisor("analysis_skipped", why=why, reload=True)

        return prepare_session(config, build_root, skipped)

    signals = _Signals(reload_session)
    signals.install()

    with contextlib.ExitStack() as stack:
        if build_dir is None:
            build_root = Path(
                stack.enter_context(tempfile.TemporaryDirectory(prefix="safety-supervisor-run-"))
            )
        else:
            build_root = Path(build_dir)
        skipped: list[str] = []
        session = prepare_session(config, build_root, skipped.append)
        cfg = session.config
        log = _open_log(stack, session, config, log_path)
        logs.append(log)
        _log_start(log, config, session, skipped)
        # The operator's socket exists before READY=1 (docs/reference/ros-interfaces.md).
        control = open_control(cfg.control)
        stack.callback(control.close)
        log.supervisor("control_socket", socket=control.path, group=control.group)
        recorder = open_recorder(cfg, record, log)
        # UDP only unless the operator chose: no shared-memory ports to crash on
        # at stop (supervisor/daemon/transport.py; docs/reference/faults.md, "Stop").
        with udp_only():
            ctx = init_ros()
            stack.callback(_shutdown_ros, ctx)
            node = SupervisorNode(
                session,
                log,
                context=ctx,
                notifier=notifier,
                watchdog_s=watchdog_interval(),
                control=control,
                recorder=recorder,
                reload=reload_session,  # `safety-supervisor reload` on the control socket
            )
        stack.callback(node.close)
        signals.attach(node)
        n_req = len(session.requirements)
        heap.freeze()  # no full collection of start-up's objects on the halt's path
        heap.take_over()  # and no young one: the loop collects between turns (receive.py)
        log.supervisor("ready", requirements=n_req, inputs=len(cfg.inputs), policy=cfg.step.policy)
        notifier.ready(status=f"monitoring {n_req} requirements on {len(cfg.inputs)} inputs")
        node.run()
        notifier.stopping(status="stopping")
        log.supervisor(
            "stop",
            ticks=node.core.tick,
            violations=node.core.violations,
            reloads=node.reloads,
            inputs=node.stop_stats(),
        )
    notifier.close()
    _exit()


def _exit() -> NoReturn:
    """Everything is done (the stop record and the log closed, the recording and the
    temporary files gone, the node destroyed and the context shut down): exit
    without the interpreter's teardown, which would finalise rclpy's remaining
    native objects in no particular order (docs/reference/faults.md, "Stop")."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(0)
