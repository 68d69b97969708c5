"""What a mitigation and a requirement's policy ARE: typed settings, keys, types and ranges.

The config loader walks the YAML and hands each mitigation's mapping to
:func:`parse_mitigation`; the actions receive the typed settings it returns and
trust them.  A bad setting raises :class:`SettingsError` naming the key of the
mitigation's mapping it is about, so the loader can point at its FILE:LINE.
The policy dataclasses live here too, since :mod:`mitigations.policy` runs them;
their validation needs the config's variables and mitigations, so it is the
loader's (``supervisor.config``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

# ------------------------------------------------------------------ mitigations

MITIGATION_KINDS = ("publish", "ssh", "command", "log")
PUBLISH_QOS = ("latched", "reliable", "best_effort")  # latched: reliable + transient_local
# Keys of a mitigation's mapping beside its kind; retries and timeout_s there
# count as settings of the kinds that have them.
ENTRY_KEYS = {"retries", "timeout_s", "description"}

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
    return Mitigation(name, kind, line, _typed(kind, params))


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
RESET_MODES = ("never", "after_mitigation", "after_ms")


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


@dataclass(frozen=True)
class PolicyConfig:
    """A requirement's ``policy:`` (validated; see mitigations.policy for meaning)."""

    debounce_steps: int = 1
    debounce_ms: float = 0.0
    cooldown_ms: float = 0.0
    latch: bool = False
    reset: str = "never"  # one of RESET_MODES
    reset_after_ms: float | None = None
    escalate: Escalation | None = None
    confirm: Confirm | None = None
    repeat_ms: float = 1000.0  # latch: re-publish period
