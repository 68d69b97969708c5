"""What a mitigation and a requirement's policy ARE: typed settings, keys, types and ranges.

The config loader walks the YAML and hands each mitigation's mapping to
:func:`parse_mitigation`; the actions receive the typed settings it returns and
trust them.  A bad setting raises :class:`SettingsError` naming the key of the
mitigation's mapping it is about, so the loader can point at its FILE:LINE.
A requirement's ``policy:`` is here too: :func:`parse_policy` checks it against
the names of the config's mitigations and the types of its variables, which the
loader passes in, and :mod:`mitigations.policy` runs the :class:`PolicyConfig`
it returns.
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from monitors.untrusted import printable

# ------------------------------------------------------------------ mitigations

MITIGATION_KINDS = ("publish", "ssh", "command", "log")
PUBLISH_QOS = ("latched", "reliable", "best_effort")  # latched: reliable + transient_local
# Keys of a mitigation's mapping beside its kind; retries and timeout_s there
# count as settings of the kinds that have them.
ENTRY_KEYS = {"retries", "timeout_s", "description", "expected"}
# ``expected``: why the warnings ``check`` gives about this mitigation are expected
# in this config, printed at the end of each (docs/reference/config.md, "mitigations").
MAX_EXPECTED_CHARS = 300

# kind: (required settings, allowed settings)
SETTING_KEYS: dict[str, tuple[set[str], set[str]]] = {
    # repeat_ms is accepted but unused: the repeat period is the policy's repeat_ms.
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
# The longest time setting, in seconds (1e9 ms, as the config's durations):
# waits and timers built from it stay inside what threading and sockets take.
MAX_SECONDS = 1e6
_STRINGS = {"host", "user", "command", "key", "known_hosts"}


@dataclass(frozen=True)
class PublishSettings:
    """Publish ``value`` (a mapping of fields, or None for defaults) as ``msg`` on ``topic``."""

    topic: str
    msg: str
    value: Any = None
    qos: str = "latched"


@dataclass(frozen=True)
class SshSettings:
    """Run ``command`` as ``user`` on ``host`` (see mitigations.actions.ssh)."""

    host: str
    user: str
    key: str
    known_hosts: str
    command: str
    port: int = 22
    connect_timeout_s: float = 5.0
    command_timeout_s: float = 10.0
    retries: int = 3  # total attempts
    backoff_s: float = 0.5


@dataclass(frozen=True)
class CommandSettings:
    """Run ``argv`` locally, no shell (see mitigations.actions.command)."""

    argv: tuple[str, ...]
    timeout_s: float = 10.0
    env: Mapping[str, str] = field(default_factory=dict)
    retries: int = 1  # total attempts
    backoff_s: float = 0.5


@dataclass(frozen=True)
class LogSettings:
    """Only a record: ``message`` says what it means."""

    message: str = ""


Settings = PublishSettings | SshSettings | CommandSettings | LogSettings


@dataclass
class Mitigation:
    name: str
    kind: str  # one of MITIGATION_KINDS
    line: int | None
    settings: Settings
    expected: str = ""  # why check's warnings about it are expected here


class SettingsError(ValueError):
    """A mitigation's setting is missing, unknown, or of the wrong type or range.

    ``key`` is the key of the mitigation's mapping the error is about (its kind,
    or a key beside it), None for the mapping as a whole; ``setting`` is the
    offending setting inside the kind's mapping, if any.
    """

    def __init__(
        self,
        message: str,
        key: str | None = None,
        *,
        setting: str | None = None,
        hint: str | None = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        self.key = key
        self.setting = setting
        self.hint = hint


def parse_mitigation(name: str, entry: Mapping[str, Any], line: int | None = None) -> Mitigation:
    """One entry of ``mitigations:`` (``{<kind>: {settings}, retries: N, ...}``) -> Mitigation."""
    kinds = [k for k in entry if k in MITIGATION_KINDS]
    if len(kinds) != 1:
        raise SettingsError(
            f"mitigation '{name}' must have exactly one of: {', '.join(MITIGATION_KINDS)}"
        )
    kind = kinds[0]
    extra = sorted(set(entry) - {kind} - ENTRY_KEYS)
    if extra:
        raise SettingsError(f"mitigation '{name}': unknown key '{extra[0]}'", extra[0])
    raw = entry[kind] if entry[kind] is not None else {}
    if kind != "log" and not isinstance(raw, Mapping):
        raise SettingsError(f"mitigation '{name}': {kind} needs a mapping of settings", kind)
    params = dict(raw) if isinstance(raw, Mapping) else {"message": str(raw)}
    _check_settings(name, kind, params, kind)
    allowed = SETTING_KEYS[kind][1]
    for k in ("retries", "timeout_s"):
        if k in entry:
            if k in allowed:
                _check_types(name, kind, {k: entry[k]}, k)
            params[k] = entry[k]  # kept as written even where the kind ignores it
    return Mitigation(name, kind, line, _typed(kind, params), _expected(name, entry))


def _expected(name: str, entry: Mapping[str, Any]) -> str:
    """The entry's ``expected`` reason: one line of text, bounded."""
    text = entry.get("expected", "")
    if text is None:
        return ""
    if (
        not isinstance(text, str)
        or len(text) > MAX_EXPECTED_CHARS
        or any(not c.isprintable() for c in text)
    ):
        raise SettingsError(
            f"mitigation '{name}': expected must be one line of text of at most "
            f"{MAX_EXPECTED_CHARS} characters (why check's warnings about it are expected)",
            "expected",
        )
    return text.strip()


def parse_settings(kind: str, params: Mapping[str, Any], name: str = "") -> Settings:
    """A kind's settings mapping -> its typed settings (validated)."""
    if kind not in SETTING_KEYS:
        raise SettingsError(f"unknown mitigation kind '{kind}'", hint=", ".join(MITIGATION_KINDS))
    _check_settings(name, kind, params, kind)
    return _typed(kind, params)


def _check_settings(name: str, kind: str, params: Mapping[str, Any], key: str | None) -> None:
    """Required, allowed, types and ranges of ``kind``'s settings; errors name ``key``."""
    required, allowed = SETTING_KEYS[kind]
    missing = sorted(required - set(params))
    if missing:
        raise SettingsError(
            f"mitigation '{name}' ({kind}) needs '{missing[0]}'", key, setting=missing[0]
        )
    unknown = sorted(set(params) - allowed)
    if unknown:
        raise SettingsError(
            f"mitigation '{name}' ({kind}): unknown setting '{unknown[0]}'",
            key,
            setting=unknown[0],
            hint="known: " + ", ".join(sorted(allowed)),
        )
    if kind == "command":
        argv = params["argv"]
        if not isinstance(argv, list) or not argv or not all(isinstance(a, str) for a in argv):
            raise SettingsError(
                f"mitigation '{name}': argv must be a non-empty list of strings (no shell)",
                key,
                setting="argv",
            )
    _check_types(name, kind, params, key)
    if kind == "publish" and not str(params["topic"]).startswith("/"):
        raise SettingsError(f"mitigation '{name}': topic must start with '/'", key, setting="topic")
    if kind == "publish" and params.get("qos", "latched") not in PUBLISH_QOS:
        raise SettingsError(
            f"mitigation '{name}': unknown qos '{params['qos']}'",
            key,
            setting="qos",
            hint="one of: " + ", ".join(PUBLISH_QOS),
        )


def _check_types(name: str, kind: str, params: Mapping[str, Any], key: str | None) -> None:
    """Types and ranges of ssh/command settings, so the daemon never meets them first."""
    what = f"mitigation '{name}' ({kind})"
    for k, v in params.items():
        bad = None
        if k == "port":
            if isinstance(v, bool) or not isinstance(v, int) or not 0 < v < 65536:
                bad = "must be a port number 1..65535"
        elif k == "retries":
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 1_000_000:
                bad = "must be a whole number of attempts from 1 to 1000000"
        elif k in _POSITIVE or k == "backoff_s":
            if isinstance(v, bool) or not isinstance(v, int | float):
                bad = "must be a number of seconds"
            elif v < 0 or (k in _POSITIVE and v == 0):
                bad = "must be positive" if k in _POSITIVE else "must not be negative"
            elif not v <= MAX_SECONDS:  # an int beyond a double compares exactly
                bad = f"must be at most {MAX_SECONDS:g} seconds"
        elif k in _STRINGS:
            if not isinstance(v, str) or not v.strip():
                bad = "must be a non-empty string"
        elif k == "env":
            if not isinstance(v, dict) or not all(
                isinstance(x, str | int | float) and not isinstance(x, bool) for x in v.values()
            ):
                bad = "must be a mapping of variable names to values"
        if bad:
            raise SettingsError(f"{what}: '{k}' {bad}, got {v!r}", key, setting=k)


def _typed(kind: str, p: Mapping[str, Any]) -> Settings:
    """Validated settings -> their dataclass (its defaults for what is not given)."""
    if kind == "publish":
        return PublishSettings(
            str(p["topic"]), str(p["msg"]), p.get("value"), str(p.get("qos", "latched"))
        )
    if kind == "ssh":
        return SshSettings(
            *(str(p[k]) for k in ("host", "user", "key", "known_hosts", "command")),
            **_given(p, port=int, retries=int),
            **_given(p, connect_timeout_s=float, command_timeout_s=float, backoff_s=float),
        )
    if kind == "command":
        env = {str(k): str(v) for k, v in (p.get("env") or {}).items()}
        return CommandSettings(
            tuple(p["argv"]), env=env, **_given(p, timeout_s=float, retries=int, backoff_s=float)
        )
    return LogSettings(str(p.get("message", "")))


def _given(p: Mapping[str, Any], **convert: Callable[[Any], Any]) -> dict[str, Any]:
    return {k: f(p[k]) for k, f in convert.items() if k in p}


# ------------------------------------------------------------------ policies

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
# How ``reset:`` is written: one of these words, or ``{after_ms: N}``.
RESET_WORDS = ("never", "after_mitigation")


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


# A requirement's ``predict:`` (docs/reference/prediction.md).
PREDICT_KEYS = {"horizon_ms", "window_ms", "actions", "min_confidence"}
# The longest margin window: the trend's ring is bounded anyway
# (mitigations.prediction.DEFAULT_CAPACITY), and a longer window is no longer a trend.
MAX_PREDICT_WINDOW_MS = 60_000.0


@dataclass(frozen=True)
class PredictConfig:
    """A requirement's ``predict:`` (validated; see mitigations.prediction)."""

    horizon_ms: float = 1500.0  # a zero crossing estimated within this is a prediction
    # The margins the line is fitted to.  window_ms and min_confidence are tuned on
    # bench --predict's sRobot scenarios, seed 1 (docs/BENCHMARKS.md, "Prediction").
    window_ms: float = 1500.0
    actions: tuple[str, ...] = ()  # the early actions; none: the prediction is logged
    min_confidence: float = 0.9


@dataclass(frozen=True)
class PolicyConfig:
    """A requirement's ``policy:`` (validated; see mitigations.policy for meaning),
    with its ``predict:`` when it has one."""

    debounce_steps: int = 1
    debounce_ms: float = 0.0
    cooldown_ms: float = 0.0
    latch: bool = False
    reset: str = "never"  # one of RESET_WORDS, or "after_ms"
    reset_after_ms: float | None = None
    escalate: Escalation | None = None
    confirm: Confirm | None = None
    repeat_ms: float = 1000.0  # latch: re-publish period
    predict: PredictConfig | None = None


# The longest duration of a policy, in ms: the config's bound on every duration.
MAX_MS = MAX_SECONDS * 1000
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1


def parse_policy(
    requirement: str,
    pol: Mapping[str, Any],
    *,
    mitigations: Mapping[str, object],
    variables: Mapping[str, str | None],
) -> PolicyConfig:
    """A requirement's ``policy:`` mapping -> its PolicyConfig (validated).

    ``mitigations`` are the config's mitigations by name (escalation names them);
    ``variables`` maps each variable to its monitor type, None for a define
    (confirmation reads a topic variable). A bad setting raises SettingsError
    whose ``key`` is the policy's key and, for a key inside a nested mapping
    (``reset``, ``escalate``, ``confirm``), whose ``setting`` is that key.
    """
    what = f"policy of '{requirement}'"
    out: dict[str, Any] = {}
    if "debounce_steps" in pol:
        v = pol["debounce_steps"]
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise SettingsError(
                f"{what}: debounce_steps must be a whole number >= 1", "debounce_steps"
            )
        out["debounce_steps"] = v
    for key in ("debounce_ms", "cooldown_ms"):
        if key in pol:
            out[key] = _duration(pol, key, what, positive=False)
    if "repeat_ms" in pol:
        out["repeat_ms"] = _duration(pol, "repeat_ms", what)
    if "latch" in pol:
        if not isinstance(pol["latch"], bool):
            raise SettingsError(f"{what}: latch must be true or false", "latch")
        out["latch"] = pol["latch"]
    if "reset" in pol:
        out.update(_reset(pol["reset"], what))
    if out.get("latch"):
        if out.get("reset") == "never":
            raise SettingsError(
                f"{what}: latch with reset: never cannot be released",
                "reset",
                hint="a latched requirement is judged afresh after its mitigation so an "
                "operator reset can see that it holds again; drop 'reset' or use "
                "after_mitigation",
            )
        out.setdefault("reset", "after_mitigation")
    if "escalate" in pol:
        out["escalate"] = _escalation(pol["escalate"], what, mitigations)
    if "confirm" in pol:
        out["confirm"] = _confirm(pol["confirm"], what, variables)
    return PolicyConfig(**out)


def _reset(v: Any, what: str) -> dict[str, Any]:
    if isinstance(v, dict) and set(v) == {"after_ms"}:
        after = _duration(v, "after_ms", f"{what}.reset", key="reset")
        return {"reset": "after_ms", "reset_after_ms": after}
    if v in RESET_WORDS:
        return {"reset": v}
    raise SettingsError(
        f"{what}: reset must be never, after_mitigation or {{after_ms: N}}, got '{v}'", "reset"
    )


def _escalation(esc: Any, what: str, mitigations: Mapping[str, object]) -> Escalation:
    if not isinstance(esc, dict) or set(esc) != {"after_ms", "actions"}:
        raise SettingsError(
            f"{what}: escalate needs exactly after_ms and actions",
            "escalate",
            hint="e.g. escalate: {after_ms: 500, actions: [power_off]}",
        )
    actions = esc["actions"]
    if isinstance(actions, str):
        actions = [actions]
    elif not isinstance(actions, list) or not all(isinstance(x, str) for x in actions):
        raise SettingsError(
            "'actions' must be a list of mitigation names", "escalate", setting="actions"
        )
    for name in actions:
        if name not in mitigations:
            raise SettingsError(
                f"{what}: escalate names undefined mitigation '{name}'",
                "escalate",
                hint=_suggest(name, mitigations),
            )
    # An empty after_ms (``after_ms:``) escalates at once, as 0 does.
    after = (
        0.0
        if esc["after_ms"] is None
        else _duration(esc, "after_ms", f"{what}.escalate", positive=False, key="escalate")
    )
    return Escalation(float(after), tuple(str(a) for a in actions))


def _confirm(c: Any, what: str, variables: Mapping[str, str | None]) -> Confirm:
    if not isinstance(c, dict) or set(c) != {"variable", "equals", "within_ms"}:
        raise SettingsError(
            f"{what}: confirm needs exactly variable, equals and within_ms",
            "confirm",
            hint="e.g. confirm: {variable: halt, equals: true, within_ms: 200}",
        )
    name = str(c["variable"])
    vtype = variables.get(name)
    if vtype is None:
        raise SettingsError(
            f"{what}: confirm variable '{name}' is not a topic variable",
            "confirm",
            hint=_suggest(name, variables),
        )
    equals = _typed_value(c["equals"], vtype, name)
    within = _duration(c, "within_ms", f"{what}.confirm", key="confirm")
    return Confirm(name, equals, float(within))


def _suggest(name: str, known: Mapping[str, object]) -> str | None:
    close = difflib.get_close_matches(name, list(known), n=1)
    return f"did you mean '{close[0]}'?" if close else None


def _shown(v: Any) -> str:
    """A value as an error shows it: long numbers and texts cut short."""
    text = str(v) if not isinstance(v, int) or abs(v) < 10**30 else f"{str(v)[:20]}..."
    return text if len(text) <= 40 else text[:37] + "..."


def _finite(v: Any, what: str, key: str | None, setting: str | None) -> float:
    """``v`` as a finite float: true/false, text that is no number, nan/inf and
    integers beyond a double are errors."""
    x = math.nan
    if not isinstance(v, bool):
        try:
            x = float(v)
        except (TypeError, ValueError, OverflowError):
            raise SettingsError(
                f"{what} must be a number, got '{_shown(v)}'", key, setting=setting
            ) from None
    if not math.isfinite(x):
        raise SettingsError(
            f"{what} must be a finite number, got '{_shown(v)}'", key, setting=setting
        )
    return x


def _duration(
    d: Mapping[str, Any], name: str, what: str, *, positive: bool = True, key: str | None = None
) -> float:
    """``d[name]``, a duration in ms: finite, never negative, at most MAX_MS and
    positive unless told otherwise. ``key`` is the policy's key when ``d`` is a
    mapping nested under it."""
    v = d[name]
    setting = name if key is not None else None
    key = key or name
    x = _finite(v, f"{what}.{name}", key, setting)
    if positive and x <= 0:
        raise SettingsError(f"{what}.{name} must be positive", key, setting=setting)
    if x < 0:
        raise SettingsError(f"{what}.{name} must not be negative", key, setting=setting)
    if x > MAX_MS:
        raise SettingsError(
            f"{what}.{name} must be at most {MAX_MS:g}, got {_shown(v)}",
            key,
            setting=setting,
            hint="durations are in milliseconds" if name.endswith("_ms") else None,
        )
    return x


def parse_predict(
    requirement: str, pred: Mapping[str, Any], *, mitigations: Mapping[str, object]
) -> PredictConfig:
    """A requirement's ``predict:`` mapping -> its PredictConfig (validated).  A bad
    setting raises SettingsError whose ``key`` is the offending key of ``pred``."""
    what = f"predict of '{requirement}'"
    unknown = sorted(set(pred) - PREDICT_KEYS)
    if unknown:
        raise SettingsError(
            f"{what}: unknown key '{unknown[0]}'",
            unknown[0],
            hint=_suggest(str(unknown[0]), dict.fromkeys(PREDICT_KEYS)),
        )
    out: dict[str, Any] = {}
    for name in ("horizon_ms", "window_ms"):
        if name in pred:
            out[name] = _duration(pred, name, what)
    if out.get("window_ms", 0.0) > MAX_PREDICT_WINDOW_MS:
        raise SettingsError(
            f"{what}.window_ms must be at most {MAX_PREDICT_WINDOW_MS:g}",
            "window_ms",
            hint="the trend is a straight line over the last window of margins",
        )
    if "min_confidence" in pred:
        c = _finite(pred["min_confidence"], f"{what}.min_confidence", "min_confidence", None)
        if not 0.0 < c <= 1.0:
            raise SettingsError(
                f"{what}.min_confidence must be above 0 and at most 1, got {_shown(c)}",
                "min_confidence",
                hint="the probability that the margin is gone within the horizon",
            )
        out["min_confidence"] = c
    if "actions" in pred:
        actions = pred["actions"]
        if isinstance(actions, str):
            actions = [actions]
        if not isinstance(actions, list) or not all(isinstance(x, str) for x in actions):
            raise SettingsError(f"{what}: actions must be a list of mitigation names", "actions")
        for name in actions:
            if name not in mitigations:
                raise SettingsError(
                    f"{what}: actions names undefined mitigation '{printable(name)}'",
                    "actions",
                    hint=_suggest(name, mitigations),
                )
        out["actions"] = tuple(actions)
    return PredictConfig(**out)


def integral_value(text: str, vtype: str) -> bool | int | None:
    """``text`` as a value of the monitor's ``bool`` or ``int64`` type, None when it is
    not one: the one reading of such values, for the config's and the policies'."""
    s = text.strip()
    if vtype == "bool":
        return {"true": True, "1": True, "false": False, "0": False}.get(s.lower())
    if vtype == "int64" and re.fullmatch(r"-?\d{1,19}", s) and INT64_MIN <= int(s) <= INT64_MAX:
        return int(s)
    return None


def _typed_value(v: Any, vtype: str, name: str) -> Any:
    """Confirmation's ``equals`` as a value of the variable's monitor type."""
    if vtype not in ("bool", "int64"):
        return _finite(v, f"variable '{name}': equals", "confirm", "equals")
    value = integral_value(_shown(v), vtype)
    if value is not None:
        return value
    raise SettingsError(
        f"variable '{name}': equals '{_shown(v)}' is not a {vtype}", "confirm", setting="equals"
    )
