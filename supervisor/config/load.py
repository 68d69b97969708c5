"""The configuration file: load, validate, and import FRET/OGMA files.

Produces a Config of plain dataclasses.  Everything a safety engineer can get
wrong is reported here as ``FILE:LINE: what is wrong``: unknown keys (with a
suggestion), missing topics, undefined mitigations, duplicate ids, reserved or
unusable variable names.  Requirement texts are only collected here; the
requirements stage parses and formalizes them.
"""

from __future__ import annotations

import difflib
import hashlib
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from monitors.ir.formula import Formula, FormulaSyntaxError, parse_formula
from monitors.ir.spec import TYPE_ALIASES
from supervisor.config.yamlload import LineDict, LineList, load_yaml
from supervisor.names import NODE_NAME

STEP_POLICIES = ("periodic", "on_message", "on_trigger", "synchronized")
ROLES = ("input", "output", "internal")
QOS_PRESETS = ("auto", "reliable", "best_effort", "sensor_data")
MITIGATION_KINDS = ("publish", "ssh", "command", "log")
PUBLISH_QOS = ("latched", "reliable", "best_effort")  # latched: reliable + transient_local
# FRET's reserved words plus our formula keywords: a variable may not be called so.
RESERVED = frozenset(
    "O H S Y Z X F G U V T A E abs max min mode next FTP TRUE FALSE xor mod inf".split()
)
NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_.]*$")

TOP_KEYS = {
    "component",
    "step",
    "variables",
    "variables_from",
    "requirements",
    "requirements_from",
    "requirement_defaults",
    "mitigations",
    "logging",
    "on_stale",
    "analysis",
    "ros",
}
STEP_KEYS = {"policy", "trigger", "period_ms", "stale_after_ms", "max_skew_ms", "prefix", "recent"}
VAR_KEYS = {
    "type",
    "topic",
    "msg",
    "field",
    "define",
    "qos",
    "depth",
    "initial",
    "stale_after_ms",
    "role",
    "range",
}
REQ_KEYS = {"id", "text", "rationale", "on_violation", "policy", "assumption", "on_pending"}
POLICY_KEYS = {
    "debounce_steps",
    "debounce_ms",
    "cooldown_ms",
    "latch",
    "reset",
    "escalate",
    "confirm",
    "repeat_ms",
}
LOG_KEYS = {"violations", "recent", "stderr"}
ROS_KEYS = {"node_name", "heartbeat_ms", "diagnostics_ms"}


@dataclass
class StepConfig:
    policy: str = "periodic"
    trigger: str | None = None
    period_ms: float | None = None
    stale_after_ms: float | None = None
    max_skew_ms: float | None = None
    prefix: str = ""
    line: int | None = None


@dataclass
class RosConfig:
    """The supervisor's own ROS interfaces (``ros:``)."""

    node_name: str = NODE_NAME
    heartbeat_ms: float = 100.0  # /safety_supervisor/heartbeat period
    diagnostics_ms: float = 1000.0  # /diagnostics period (1 Hz, REP 107)


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


@dataclass(frozen=True)
class Escalation:
    after_ms: float
    actions: tuple[str, ...]


@dataclass(frozen=True)
class Confirm:
    """The action took effect: ``variable`` equals ``equals`` within ``within_ms``."""

    variable: str
    equals: Any
    within_ms: float


RESET_MODES = ("never", "after_mitigation", "after_ms")


@dataclass(frozen=True)
class PolicyConfig:
    """A requirement's ``policy:`` (validated; see mitigations.policy for meaning)."""

    debounce_steps: int = 1
    debounce_ms: float = 0.0
    cooldown_ms: float = 0.0
    latch: bool = False
    reset: str = "never"
    reset_after_ms: float | None = None
    escalate: Escalation | None = None
    confirm: Confirm | None = None
    repeat_ms: float = 1000.0  # latch: re-publish period


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


@dataclass
class Mitigation:
    name: str
    kind: str
    params: dict[str, Any]
    line: int | None


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
    analysis: dict[str, Any]
    ros: RosConfig = field(default_factory=RosConfig)

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


# ------------------------------------------------------------------ helpers


def _err(
    msg: str, where: Any, key: str | None = None, hint: str | None = None, file: str = ""
) -> UserError:
    line = (
        where.key_line(key)
        if (key is not None and isinstance(where, LineDict))
        else getattr(where, "line", None)
    )
    return UserError(msg, file=getattr(where, "file", file) or file, line=line, hint=hint)


def _check_keys(d: LineDict, allowed: set[str], what: str) -> None:
    for k in d:
        if k not in allowed:
            close = difflib.get_close_matches(k, sorted(allowed), n=1)
            hint = (
                f"did you mean '{close[0]}'?"
                if close
                else f"known keys: {', '.join(sorted(allowed))}"
            )
            raise _err(f"unknown key '{k}' in {what}", d, k, hint)


def _mapping(value: Any, where: Any, what: str, key: str | None = None) -> LineDict:
    if not isinstance(value, dict):
        raise _err(f"{what} must be a mapping", where, key)
    return value  # type: ignore[return-value]


def _number(d: LineDict, key: str, what: str, *, positive: bool = True) -> float | None:
    v = d.get(key)
    if v is None:
        return None
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise _err(f"{what}.{key} must be a number, got '{v}'", d, key) from None
    if positive and x <= 0:
        raise _err(f"{what}.{key} must be positive", d, key)
    return x


def _names(value: Any, where: LineDict, key: str) -> list[str]:
    if value is None:
        return []
    if isinstance(value, str):
        return [str(value)]
    if not isinstance(value, list) or not all(isinstance(x, str) for x in value):
        raise _err(f"'{key}' must be a list of mitigation names", where, key)
    return [str(x) for x in value]


def _relative(base: Path, name: str) -> Path:
    p = Path(name)
    return p if p.is_absolute() else base.parent / p


def _check_name(name: str, where: Any, key: str | None = None) -> None:
    if not NAME_RE.match(name):
        raise _err(
            f"'{name}' is not a usable variable name",
            where,
            key,
            "use letters, digits, '_' and '.'",
        )
    if name in RESERVED:
        raise _err(
            f"'{name}' is a reserved word in FRETISH and cannot name a variable",
            where,
            key,
            f"rename it, e.g. '{name}_'",
        )


# ------------------------------------------------------------------ OGMA / FRET import


_OGMA_LINE = re.compile(r'^\(\s*"([^"]+)"\s*,\s*"([^"]+)"\s*,\s*"([^"]*)"\s*,\s*"([^"]+)"\s*\)\s*$')
# OGMA's old topic datatypes (thesis Table 11) -> ROS 2 message types.
_OGMA_TOPIC_TYPES = {
    "int64_t": ("std_msgs/msg/Int64", "int64"),
    "int32_t": ("std_msgs/msg/Int32", "int64"),
    "bool": ("std_msgs/msg/Bool", "bool"),
    "double": ("std_msgs/msg/Float64", "double"),
    "float": ("std_msgs/msg/Float32", "double"),
    "uint8_t": ("std_msgs/msg/UInt8", "int64"),
}


def load_ogma_variables(path: Path) -> list[dict[str, Any]]:
    """OGMA's variable database: JSON (OGMA 1.7+) or the older one-tuple-per-line format."""
    file = str(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise UserError(f"cannot read OGMA variable database: {e.strerror}", file=file) from None
    out: list[dict[str, Any]] = []
    if text.lstrip().startswith("{"):
        try:
            db = json.loads(text)
        except json.JSONDecodeError as e:
            raise UserError(
                f"invalid JSON: {e.msg}", file=file, line=e.lineno, col=e.colno
            ) from None
        topics = {t.get("topic"): t for t in db.get("topics", []) if isinstance(t, dict)}
        for item in db.get("inputs", []):
            name, ctype = item.get("name"), item.get("type", "")
            conns = [
                c for c in item.get("connections", []) if str(c.get("scope", "")).startswith("ros")
            ]
            if not name or not conns:
                continue
            topic = conns[0].get("topic")
            msg = str(topics.get(topic, {}).get("type", "")).replace("::", "/")
            vtype = TYPE_ALIASES.get(str(ctype).replace("_t", "").lower()) or TYPE_ALIASES.get(
                str(ctype)
            )
            if vtype is None:
                raise UserError(f"variable '{name}' has unsupported type '{ctype}'", file=file)
            out.append(
                {
                    "name": name,
                    "type": vtype,
                    "topic": topic,
                    "msg": msg or None,
                    "field": conns[0].get("field") or "data",
                    "line": None,
                }
            )
        return out
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith(("#", "--")):
            continue
        m = _OGMA_LINE.match(line)
        if not m:
            raise UserError('expected ("name","type","/topic","TopicType")', file=file, line=lineno)
        name, ctype, topic, ttype = m.groups()
        msg, vtype = _OGMA_TOPIC_TYPES.get(ttype.lower(), (None, None))
        if msg is None:
            raise UserError(
                f"unknown topic type '{ttype}'",
                file=file,
                line=lineno,
                hint="known: " + ", ".join(_OGMA_TOPIC_TYPES),
            )
        declared = TYPE_ALIASES.get(ctype.replace("_t", "").lower(), TYPE_ALIASES.get(ctype))
        if declared is not None and declared != vtype:
            raise UserError(
                f"variable '{name}' is {ctype} but its topic carries {ttype}",
                file=file,
                line=lineno,
            )
        out.append(
            {
                "name": name,
                "type": vtype,
                "topic": topic,
                "msg": msg,
                "field": "data",
                "line": lineno,
            }
        )
    return out


def load_fret_export(
    path: Path,
) -> tuple[list[RequirementEntry], list[dict[str, Any]], list[dict[str, Any]]]:
    """FRET's Copilot export (the file OGMA reads): requirements, internal and other variables."""
    file = str(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise UserError(f"cannot read FRET export: {e.strerror}", file=file) from None
    except json.JSONDecodeError as e:
        raise UserError(f"invalid JSON: {e.msg}", file=file, line=e.lineno, col=e.colno) from None
    if (
        not isinstance(data, dict)
        or len(data) != 1
        or not isinstance(next(iter(data.values())), dict)
    ):
        raise UserError(
            'not a FRET Copilot export (expected {"<Component>Spec": {...}})', file=file
        )
    spec = next(iter(data.values()))
    reqs: list[RequirementEntry] = []
    for r in spec.get("Requirements", []):
        if not r.get("name") or not r.get("fretish"):
            raise UserError("a requirement in the export has no name or fretish text", file=file)
        reqs.append(
            RequirementEntry(
                id=r["name"],
                text=r["fretish"],
                file=file,
                line=None,
                col=1,
                fret_ptltl=r.get("ptLTL") or None,
                assumption="assumption" in r["name"].lower(),
            )
        )
    internal = [
        {
            "name": v["name"],
            "type": v.get("type", "bool"),
            "define": v.get("assignmentCopilot") or v.get("assignmentLustre"),
        }
        for v in spec.get("Internal_variables", [])
    ]
    other = [
        {"name": v["name"], "type": v.get("type", "")} for v in spec.get("Other_variables", [])
    ]
    return reqs, internal, other


def parse_define(text: str, file: str, line: int | None) -> Formula:
    # FRET's variable mapper writes constants as 'constant 7' (thesis Fig. 29).
    cleaned = re.sub(r"\bconstant\s+", "", str(text))
    try:
        return parse_formula(cleaned)
    except FormulaSyntaxError as e:
        raise UserError(f"cannot parse define '{text}': {e}", file=file, line=line) from None


# ------------------------------------------------------------------ main loader


def load_config(path: str | Path) -> Config:
    path = Path(path)
    file = str(path)
    try:
        raw_bytes = path.read_bytes()
    except OSError as e:
        raise UserError(f"cannot read config: {e.strerror}", file=file) from None
    doc = load_yaml(path, raw_bytes.decode("utf-8", errors="replace"))
    if not isinstance(doc, dict):
        raise UserError(
            "the config must be a YAML mapping (component:, variables:, requirements:, ...)",
            file=file,
            line=1,
        )
    _check_keys(doc, TOP_KEYS, "the config")

    component = doc.get("component")
    if not isinstance(component, str) or not component:
        raise _err(
            "'component' is required: the FRETISH component the requirements name",
            doc,
            "component",
            file=file,
        )

    step = _load_step(doc)
    variables = _load_variables(doc, path)
    requirements = _load_requirements(doc, path)
    mitigations = _load_mitigations(doc)

    logging = _mapping(doc.get("logging") or LineDict(), doc, "logging", "logging")
    if logging:
        _check_keys(logging, LOG_KEYS, "logging")
    recent = int(logging.get("recent", 10)) if str(logging.get("recent", 10)).isdigit() else None
    if recent is None:
        raise _err("logging.recent must be a whole number of ticks", logging, "recent")
    log_path = logging.get("violations")

    on_stale = _names(doc.get("on_stale"), doc, "on_stale")
    for name in on_stale:
        if name not in mitigations:
            raise _err(
                f"on_stale names undefined mitigation '{name}'",
                doc,
                "on_stale",
                _suggest(name, mitigations),
            )
    for r in requirements:
        for name in r.on_violation:
            if name not in mitigations:
                raise UserError(
                    f"requirement '{r.id}' names undefined mitigation '{name}'",
                    file=r.file,
                    line=r.on_violation_line or r.id_line or r.line,
                    hint=_suggest(name, mitigations),
                )
    for r in requirements:
        r.policy_config = _policy_config(r, mitigations, variables, file)
    if step.policy == "on_trigger":
        if not step.trigger:
            raise _err(
                "step.policy on_trigger needs step.trigger: the variable whose message ends a tick",
                doc,
                "step",
            )
        if step.trigger not in variables or variables[step.trigger].define is not None:
            raise _err(
                f"step.trigger '{step.trigger}' is not a topic variable",
                doc,
                "step",
                _suggest(step.trigger, variables),
            )
    analysis = doc.get("analysis") or {}
    ros = _load_ros(doc)
    return Config(
        path=file,
        sha256=hashlib.sha256(raw_bytes).hexdigest(),
        component=str(component),
        step=step,
        variables=variables,
        requirements=requirements,
        mitigations=mitigations,
        log_path=str(log_path) if log_path else None,
        recent=recent,
        on_stale=on_stale,
        analysis=dict(analysis),
        ros=ros,
    )


def _policy_config(
    r: RequirementEntry,
    mitigations: dict[str, Mitigation],
    variables: dict[str, Variable],
    file: str,
) -> PolicyConfig:
    raw = r.policy
    if not raw:
        return PolicyConfig()
    pol = raw if isinstance(raw, LineDict) else _as_linedict(raw, None, r.policy_line or r.id_line)
    pol.file = pol.file or r.file
    what = f"policy of '{r.id}'"
    out: dict[str, Any] = {}
    if "debounce_steps" in pol:
        v = pol["debounce_steps"]
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise _err(f"{what}: debounce_steps must be a whole number >= 1", pol, "debounce_steps")
        out["debounce_steps"] = v
    for key in ("debounce_ms", "cooldown_ms"):
        if key in pol:
            out[key] = _number(pol, key, what, positive=False)
            if out[key] < 0:
                raise _err(f"{what}: {key} must not be negative", pol, key)
    if "repeat_ms" in pol:
        out["repeat_ms"] = _number(pol, "repeat_ms", what)
    if "latch" in pol:
        if not isinstance(pol["latch"], bool):
            raise _err(f"{what}: latch must be true or false", pol, "latch")
        out["latch"] = pol["latch"]
    if "reset" in pol:
        v = pol["reset"]
        if isinstance(v, dict) and set(v) == {"after_ms"}:
            out["reset"] = "after_ms"
            out["reset_after_ms"] = _number(_as_linedict(v, pol), "after_ms", f"{what}.reset")
        elif v in ("never", "after_mitigation"):
            out["reset"] = v
        else:
            raise _err(
                f"{what}: reset must be never, after_mitigation or {{after_ms: N}}, got '{v}'",
                pol,
                "reset",
            )
    if out.get("latch"):
        if out.get("reset") == "never":
            raise _err(
                f"{what}: latch with reset: never cannot be released",
                pol,
                "reset",
                "a latched requirement is judged afresh after its mitigation so an operator "
                "reset can see that it holds again; drop 'reset' or use after_mitigation",
            )
        out.setdefault("reset", "after_mitigation")
    if "escalate" in pol:
        esc = _as_linedict(pol["escalate"], pol)
        if not isinstance(pol["escalate"], dict) or set(esc) != {"after_ms", "actions"}:
            raise _err(
                f"{what}: escalate needs exactly after_ms and actions",
                pol,
                "escalate",
                "e.g. escalate: {after_ms: 500, actions: [power_off]}",
            )
        actions = _names(esc["actions"], esc, "actions")
        for name in actions:
            if name not in mitigations:
                raise _err(
                    f"{what}: escalate names undefined mitigation '{name}'",
                    pol,
                    "escalate",
                    _suggest(name, mitigations),
                )
        out["escalate"] = Escalation(
            float(_number(esc, "after_ms", f"{what}.escalate", positive=False) or 0.0),
            tuple(actions),
        )
    if "confirm" in pol:
        c = _as_linedict(pol["confirm"], pol)
        if not isinstance(pol["confirm"], dict) or set(c) != {"variable", "equals", "within_ms"}:
            raise _err(
                f"{what}: confirm needs exactly variable, equals and within_ms",
                pol,
                "confirm",
                "e.g. confirm: {variable: halt, equals: true, within_ms: 200}",
            )
        name = str(c["variable"])
        var = variables.get(name)
        if var is None or var.define is not None:
            raise _err(
                f"{what}: confirm variable '{name}' is not a topic variable",
                pol,
                "confirm",
                _suggest(name, variables),
            )
        equals = _typed_value(c["equals"], var.type, c, "equals", name)
        out["confirm"] = Confirm(name, equals, float(_number(c, "within_ms", f"{what}.confirm")))
    return PolicyConfig(**out)


def _as_linedict(value: Any, parent: LineDict | None, line: int | None = None) -> LineDict:
    """A nested mapping with line numbers (falls back to the parent's line)."""
    if isinstance(value, LineDict):
        return value
    d = LineDict(value if isinstance(value, dict) else {})
    d.line = parent.line if parent is not None else (line or 0)
    d.file = parent.file if parent is not None else ""
    d._key_lines = {}
    return d


def _load_ros(doc: LineDict) -> RosConfig:
    raw = doc.get("ros")
    if raw is None:
        return RosConfig()
    r = _mapping(raw, doc, "ros", "ros")
    _check_keys(r, ROS_KEYS, "ros")
    out = RosConfig()
    name = r.get("node_name")
    if name is not None:
        if not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", str(name)):
            raise _err(f"ros.node_name '{name}' is not a valid ROS node name", r, "node_name")
        out.node_name = str(name)
    for key in ("heartbeat_ms", "diagnostics_ms"):
        v = _number(r, key, "ros")
        if v is not None:
            setattr(out, key, v)
    return out


def _suggest(name: str, known: dict) -> str | None:
    close = difflib.get_close_matches(name, list(known), n=1)
    return f"did you mean '{close[0]}'?" if close else None


def _load_step(doc: LineDict) -> StepConfig:
    raw = doc.get("step")
    if raw is None:
        return StepConfig()
    s = _mapping(raw, doc, "step", "step")
    _check_keys(s, STEP_KEYS, "step")
    policy = str(s.get("policy", "periodic"))
    if policy not in STEP_POLICIES:
        raise _err(
            f"unknown step policy '{policy}'", s, "policy", "one of: " + ", ".join(STEP_POLICIES)
        )
    step = StepConfig(
        policy=policy,
        trigger=str(s["trigger"]) if s.get("trigger") else None,
        period_ms=_number(s, "period_ms", "step"),
        stale_after_ms=_number(s, "stale_after_ms", "step"),
        max_skew_ms=_number(s, "max_skew_ms", "step"),
        prefix=str(s.get("prefix") or ""),
        line=s.line,
    )
    if policy == "periodic" and step.period_ms is None:
        raise _err("step.policy periodic needs step.period_ms", s, "policy")
    if step.prefix and not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", step.prefix):
        raise _err(f"step.prefix '{step.prefix}' is not a C identifier", s, "prefix")
    return step


def _load_variables(doc: LineDict, path: Path) -> dict[str, Variable]:
    out: dict[str, Variable] = {}
    for entry_path in _as_list(doc.get("variables_from"), doc, "variables_from"):
        for v in load_ogma_variables(_relative(path, entry_path)):
            _check_name(v["name"], doc, "variables_from")
            out[v["name"]] = Variable(
                name=v["name"],
                type=v["type"],
                role="input",
                line=doc.key_line("variables_from"),
                topic=v["topic"],
                msg=v["msg"],
                field=v["field"],
            )
    raw = doc.get("variables")
    if raw is None:
        return out
    vs = _mapping(raw, doc, "variables", "variables")
    for name, spec in vs.items():
        line = vs.key_line(name)
        _check_name(name, vs, name)
        if spec is None:
            spec = LineDict()
        spec = _mapping(spec, vs, f"variable '{name}'", name)
        _check_keys(spec, VAR_KEYS, f"variable '{name}'")
        base = out.get(name)  # a YAML entry may refine one imported from OGMA
        tname = spec.get("type", base.type if base else None)
        if tname is None:
            raise _err(f"variable '{name}' needs a type (bool, int64 or double)", vs, name)
        vtype = TYPE_ALIASES.get(str(tname))
        if vtype is None:
            raise _err(
                f"variable '{name}' has unknown type '{tname}'",
                spec,
                "type",
                "use bool, int64 or double",
            )
        define_text = spec.get("define")
        role = str(spec.get("role") or ("internal" if define_text is not None else "input"))
        if role not in ROLES:
            raise _err(f"variable '{name}': role must be one of {', '.join(ROLES)}", spec, "role")
        var = Variable(name=name, type=vtype, role=role, line=line)
        if define_text is not None:
            if spec.get("topic") or spec.get("msg"):
                raise _err(
                    f"variable '{name}' has both define and topic: an internal variable is computed, not subscribed",
                    spec,
                    "define",
                )
            var.define_text = str(define_text)
            var.define = parse_define(str(define_text), vs.file, spec.key_line("define"))
        else:
            var.topic = str(spec.get("topic") or (base.topic if base else "") or "") or None
            var.msg = str(spec.get("msg") or (base.msg if base else "") or "") or None
            var.field = str(spec.get("field") or (base.field if base else "data"))
            if not var.topic:
                raise _err(
                    f"variable '{name}' has no topic (and no define)",
                    vs,
                    name,
                    "add topic: /name and msg: pkg/msg/Type, or define: <expression>",
                )
            if not var.topic.startswith("/"):
                raise _err(
                    f"variable '{name}': topic '{var.topic}' must be absolute (start with '/')",
                    spec,
                    "topic",
                )
            if not var.msg:
                raise _err(
                    f"variable '{name}' needs msg: the ROS 2 message type of {var.topic}", vs, name
                )
        var.qos = str(spec.get("qos", "auto"))
        if var.qos not in QOS_PRESETS:
            raise _err(
                f"variable '{name}': unknown qos '{var.qos}'",
                spec,
                "qos",
                "one of: " + ", ".join(QOS_PRESETS),
            )
        depth = spec.get("depth", 10)
        if not str(depth).isdigit() or int(depth) < 1:
            raise _err(f"variable '{name}': depth must be a positive whole number", spec, "depth")
        var.depth = int(depth)
        var.stale_after_ms = _number(spec, "stale_after_ms", f"variable '{name}'")
        if "initial" in spec:
            var.initial = _typed_value(spec["initial"], vtype, spec, "initial", name)
        if "range" in spec:
            rng = spec["range"]
            if not isinstance(rng, list) or len(rng) != 2:
                raise _err(f"variable '{name}': range must be [min, max]", spec, "range")
            var.range = (float(rng[0]), float(rng[1]))
        out[name] = var
    return out


def _typed_value(v: Any, vtype: str, where: LineDict, key: str, name: str) -> Any:
    s = str(v).strip()
    if vtype == "bool":
        if s.lower() in ("true", "1"):
            return True
        if s.lower() in ("false", "0"):
            return False
    elif vtype == "int64":
        if re.fullmatch(r"-?\d+", s):
            return int(s)
    else:
        try:
            return float(s)
        except ValueError:
            pass
    raise _err(f"variable '{name}': {key} '{v}' is not a {vtype}", where, key)


def _as_list(value: Any, where: LineDict, key: str) -> list[str]:
    if value is None:
        return []
    if isinstance(value, str):
        return [value]
    if isinstance(value, list) and all(isinstance(x, str) for x in value):
        return [str(x) for x in value]
    raise _err(f"'{key}' must be a file name or a list of file names", where, key)


def _load_requirements(doc: LineDict, path: Path) -> list[RequirementEntry]:
    defaults = _mapping(
        doc.get("requirement_defaults") or LineDict(),
        doc,
        "requirement_defaults",
        "requirement_defaults",
    )
    if defaults:
        _check_keys(defaults, {"on_violation", "policy", "on_pending"}, "requirement_defaults")
    reqs: list[RequirementEntry] = []
    by_id: dict[str, RequirementEntry] = {}
    for entry_path in _as_list(doc.get("requirements_from"), doc, "requirements_from"):
        imported, _internal, _other = load_fret_export(_relative(path, entry_path))
        for r in imported:
            if r.id in by_id:
                raise _err(
                    f"duplicate requirement id '{r.id}' in {entry_path}", doc, "requirements_from"
                )
            r.on_violation = _names(defaults.get("on_violation"), defaults, "on_violation")
            r.policy = dict(defaults.get("policy") or {})
            r.id_line = doc.key_line("requirements_from")
            reqs.append(r)
            by_id[r.id] = r
    raw = doc.get("requirements")
    if raw is None:
        if not reqs:
            raise _err("no requirements: add 'requirements:' or 'requirements_from:'", doc, None)
        return reqs
    if not isinstance(raw, list):
        raise _err("'requirements' must be a list of {id, text, ...}", doc, "requirements")
    for i, item in enumerate(raw):
        item_line = raw.item_line(i) if isinstance(raw, LineList) else None
        if not isinstance(item, dict):
            raise UserError(
                "each requirement must be a mapping with id and text",
                file=str(path),
                line=item_line,
            )
        _check_keys(item, REQ_KEYS, "a requirement")
        rid = item.get("id")
        if not rid or not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", str(rid)):
            raise _err(
                f"requirement id '{rid}' must be a C identifier (letters, digits, '_')",
                item,
                "id" if rid else None,
            )
        rid = str(rid)
        text = item.get("text")
        existing = by_id.get(rid)
        if existing is not None and existing.line is not None:
            raise _err(
                f"duplicate requirement id '{rid}' (first at line {existing.id_line})", item, "id"
            )
        if existing is None and not text:
            raise _err(
                f"requirement '{rid}' has no text", item, "id", "add text: <FRETISH sentence>"
            )
        entry = existing or RequirementEntry(id=rid, text="", file=str(path), line=None, col=1)
        if text:
            entry.text = str(text)
            entry.line = getattr(text, "line", item.key_line("text"))
            entry.col = getattr(text, "col", 1)
            entry.file = str(path)
            entry.fret_ptltl = None if existing is None else entry.fret_ptltl
        entry.id_line = item.key_line("id")
        entry.rationale = str(item.get("rationale") or "")
        entry.on_violation_line = (
            item.key_line("on_violation") if "on_violation" in item else entry.id_line
        )
        if "on_violation" in item or existing is None:
            entry.on_violation = _names(
                item.get("on_violation", defaults.get("on_violation")), item, "on_violation"
            )
        pol = item.get("policy", defaults.get("policy"))
        if pol is not None:
            pol = _mapping(pol, item, "policy", "policy")
            _check_keys(pol, POLICY_KEYS, f"policy of '{rid}'")
            entry.policy = pol
            entry.policy_line = pol.line if isinstance(pol, LineDict) else item.key_line("policy")
        if "assumption" in item:
            entry.assumption = str(item["assumption"]).lower() == "true"
        else:
            entry.assumption = entry.assumption or "assumption" in rid.lower()
        if existing is None:
            reqs.append(entry)
            by_id[rid] = entry
    return reqs


def _load_mitigations(doc: LineDict) -> dict[str, Mitigation]:
    raw = doc.get("mitigations")
    if raw is None:
        return {}
    ms = _mapping(raw, doc, "mitigations", "mitigations")
    out: dict[str, Mitigation] = {}
    for name, spec in ms.items():
        spec = _mapping(spec, ms, f"mitigation '{name}'", name)
        kinds = [k for k in spec if k in MITIGATION_KINDS]
        if len(kinds) != 1:
            raise _err(
                f"mitigation '{name}' must have exactly one of: {', '.join(MITIGATION_KINDS)}",
                ms,
                name,
            )
        kind = kinds[0]
        extra = set(spec) - {kind, "retries", "timeout_s", "description"}
        if extra:
            raise _err(
                f"mitigation '{name}': unknown key '{sorted(extra)[0]}'", spec, sorted(extra)[0]
            )
        params = spec[kind] if spec[kind] is not None else {}
        if kind != "log" and not isinstance(params, dict):
            raise _err(f"mitigation '{name}': {kind} needs a mapping of settings", spec, kind)
        params = dict(params) if isinstance(params, dict) else {"message": str(params)}
        _check_mitigation(name, kind, params, spec)
        for k in ("retries", "timeout_s"):
            if k in spec:
                params[k] = spec[k]
        out[str(name)] = Mitigation(
            name=str(name), kind=kind, params=params, line=ms.key_line(name)
        )
    return out


_REQUIRED = {
    "publish": ({"topic", "msg"}, {"topic", "msg", "value", "qos", "repeat_ms"}),
    "ssh": (
        {"host", "user", "key", "known_hosts", "command"},
        {
            "host",
            "port",
            "user",
            "key",
            "known_hosts",
            "command",
            "connect_timeout_s",
            "command_timeout_s",
            "retries",
            "backoff_s",
        },
    ),
    "command": ({"argv"}, {"argv", "timeout_s", "env", "retries", "backoff_s"}),
    "log": (set(), {"message"}),
}


_POSITIVE = {"connect_timeout_s", "command_timeout_s", "timeout_s"}


def _check_setting_types(name: str, kind: str, params: dict, where: LineDict) -> None:
    """Types and ranges of ssh/command settings, so the daemon never meets them first."""
    what = f"mitigation '{name}' ({kind})"
    for key, v in params.items():
        bad = None
        if key == "port":
            if isinstance(v, bool) or not isinstance(v, int) or not 0 < v < 65536:
                bad = "must be a port number 1..65535"
        elif key == "retries":
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                bad = "must be a whole number of attempts >= 1"
        elif key in _POSITIVE or key == "backoff_s":
            if isinstance(v, bool) or not isinstance(v, int | float):
                bad = "must be a number of seconds"
            elif v < 0 or (key in _POSITIVE and v == 0):
                bad = "must be positive" if key in _POSITIVE else "must not be negative"
        elif key in ("host", "user", "command", "key", "known_hosts"):
            if not isinstance(v, str) or not v.strip():
                bad = "must be a non-empty string"
        elif key == "env":
            if not isinstance(v, dict) or not all(
                isinstance(x, str | int | float) and not isinstance(x, bool) for x in v.values()
            ):
                bad = "must be a mapping of variable names to values"
        if bad:
            raise _err(f"{what}: '{key}' {bad}, got {v!r}", where, kind)


def _check_mitigation(name: str, kind: str, params: dict, where: LineDict) -> None:
    required, allowed = _REQUIRED[kind]
    missing = sorted(required - set(params))
    if missing:
        raise _err(f"mitigation '{name}' ({kind}) needs '{missing[0]}'", where, kind)
    unknown = sorted(set(params) - allowed)
    if unknown:
        raise _err(
            f"mitigation '{name}' ({kind}): unknown setting '{unknown[0]}'",
            where,
            kind,
            "known: " + ", ".join(sorted(allowed)),
        )
    if kind == "command":
        argv = params["argv"]
        if not isinstance(argv, list) or not argv or not all(isinstance(a, str) for a in argv):
            raise _err(
                f"mitigation '{name}': argv must be a non-empty list of strings (no shell)",
                where,
                kind,
            )
    _check_setting_types(name, kind, params, where)
    if kind == "publish" and not str(params["topic"]).startswith("/"):
        raise _err(f"mitigation '{name}': topic must start with '/'", where, kind)
    if kind == "publish" and params.get("qos", "latched") not in PUBLISH_QOS:
        raise _err(
            f"mitigation '{name}': unknown qos '{params['qos']}'",
            where,
            kind,
            "one of: " + ", ".join(PUBLISH_QOS),
        )
