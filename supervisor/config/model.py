"""A loaded config: plain dataclasses, validated by the section modules beside this one.

The mitigation and policy settings are :mod:`mitigations.settings`' (the actions
and policies run them); this module holds what only the supervisor reads.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from mitigations.settings import Mitigation, PolicyConfig
from monitors.errors import UserError
from monitors.ir.formula import Formula
from monitors.ir.functions import Function
from supervisor.config.analysis import AnalysisConfig
from supervisor.config.limits import Limits
from supervisor.config.record import RecordConfig
from supervisor.names import NODE_NAME


@dataclass
class StepConfig:
    policy: str = "periodic"
    trigger: str | None = None
    period_ms: float | None = None
    stale_after_ms: float | None = None
    max_skew_ms: float | None = None
    prefix: str = ""
    line: int | None = None
    # Each requirement's margin in the step (docs/reference/margins.md): None off, else
    # a boolean atom's margin (inf for `margins: true`).
    margins: float | None = None


@dataclass
class RosConfig:
    """The supervisor's own ROS interfaces (``ros:``)."""

    node_name: str = NODE_NAME
    namespace: str = "/"  # the daemon's own topics and service live under it
    heartbeat_ms: float = 100.0  # /safety_supervisor/heartbeat period
    diagnostics_ms: float = 1000.0  # /diagnostics period (1 Hz, REP 107)
    status_ms: float = 500.0  # /safety_supervisor/status period; 0: not published
    reset_service: bool = False  # /safety_supervisor/reset: opt-in, no credentials
    reset_service_line: int | None = None


@dataclass
class ControlConfig:
    """The operator's control socket (``control:``)."""

    socket: str | None = None  # None: names.daemon_control_socket()
    group: str | None = None  # may connect besides the daemon's user and root
    max_resets: int = 1  # accepted operator resets per interval
    interval_ms: float = 1000.0  # also the period of the refusal summary
    file: str = ""
    line: int | None = None
    socket_line: int | None = None
    group_line: int | None = None


@dataclass
class Variable:
    name: str
    type: str
    role: str
    line: int | None
    topic: str | None = None
    msg: str | None = None
    field: str = "data"
    define: Formula | None = None
    define_text: str | None = None
    qos: str = "auto"
    depth: int = 10
    initial: Any = None
    stale_after_ms: float | None = None
    range: tuple[float, float] | None = None
    imported_from: str | None = None  # the FRET or OGMA file that declared it, if any
    # true only at the tick at which its message arrived (an estop button, any
    # message whose arrival is the fact); no field is read
    event: bool = False
    reduce: str | None = None  # min, max, ... over an array (supervisor/inputs/reductions.py)
    # Services and actions (supervisor/inputs/interfaces.py): topic and msg are
    # then the introspection or status topic's, field is within the call's part.
    service: str | None = None
    srv: str | None = None
    call: str | None = None  # request | response
    action: str | None = None
    statuses: tuple[str, ...] = ()
    # Derived from another input's messages (topic and msg are that input's).
    age_of: str | None = None
    stamp: str | None = None  # the time stamp's field; None: header.stamp
    rate_of: str | None = None
    window_ms: float = 1000.0


@dataclass
class RequirementEntry:
    id: str
    text: str
    file: str
    line: int | None  # line of the text (for error positions)
    col: int
    rationale: str = ""
    on_violation: list[str] = field(default_factory=list)
    policy: dict[str, Any] = field(default_factory=dict)
    assumption: bool = False
    fret_ptltl: str | None = None  # from a FRET export: FRET's own formula, cross-checked
    id_line: int | None = None
    on_violation_line: int | None = None
    policy_config: PolicyConfig = field(default_factory=PolicyConfig)
    policy_line: int | None = None
    # ``predict:`` as written (None: no prediction); checked into policy_config.predict
    predict: dict[str, Any] | None = None
    predict_line: int | None = None
    # The name as written (FRET's, before mapping it to the C identifier ``id``;
    # docs/reference/config.md, "requirements"): for display only, through
    # monitors.untrusted.printable.
    display: str = ""


@dataclass
class Config:
    path: str
    sha256: str
    component: str
    step: StepConfig
    variables: dict[str, Variable]
    requirements: list[RequirementEntry]
    mitigations: dict[str, Mitigation]
    log_path: str | None
    recent: int
    on_stale: list[str]
    analysis: AnalysisConfig
    ros: RosConfig = field(default_factory=RosConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    # functions: the definitions of the functions FRET passes through its formulas
    functions: dict[str, Function] = field(default_factory=dict)
    limits: Limits = field(default_factory=Limits)
    log_retry_buffer: int = 1000  # logging.retry_buffer
    log_durability: str = "after_publish"  # logging.durability
    record: RecordConfig | None = None  # record: (None: no section; run --record may still record)
    # "file:line: note: ..." lines the loader found worth saying (an import leaving
    # requirements out); check prints them with its other notes.
    notes: list[str] = field(default_factory=list)
    # The config with the files it imports, as one SHA-256 (ConfigSource.identity):
    # what fleet replay keys its dataset by.  Empty when not made by load_config.
    identity: str = ""
    # Each imported file's SHA-256 by its name relative to the config
    # (ConfigSource.import_digests): kept in the violation log's start record.
    import_digests: dict[str, str] = field(default_factory=dict)

    def log_fields(self) -> dict[str, Any]:
        """What the violation log's start, reload and replay records say of the config
        beside its hash (in every record): its imports' hashes, when it has any
        (docs/reference/log.md, "supervisor records")."""
        return {"imports": dict(self.import_digests)} if self.import_digests else {}

    @property
    def inputs(self) -> list[Variable]:
        """Variables read from topics, in declaration order."""
        return [v for v in self.variables.values() if v.define is None]

    @property
    def defines(self) -> list[Variable]:
        return [v for v in self.variables.values() if v.define is not None]

    def requirement(self, rid: str) -> RequirementEntry:
        for r in self.requirements:
            if r.id == rid:
                return r
        known = ", ".join(r.id for r in self.requirements)
        raise UserError(f"no requirement '{rid}' (requirements: {known})", file=self.path)
