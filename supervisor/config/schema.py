"""The config file's keys as the reference shows them: type, default and meaning.

The loaders own which keys a section takes and their defaults; this table owns what
each key means, and names where the loader keeps the key set (``keys_of``) and each
default (``default_of``), so that ``python -m supervisor.docs`` writes the
reference tables of docs/reference/config.md and the shipped ``template.yaml`` from
one source, and refuses to when a section's keys and this table disagree.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Key:
    """One row of a section's table (``name`` may list keys that go together)."""

    name: str
    type: str
    # As the table shows it; with default_of, "{}" stands for the code's value.
    default: str
    meaning: str
    # "module:NAME.attr": the loader's default, shown and written into template.yaml.
    default_of: str | None = None


@dataclass(frozen=True)
class Section:
    """A table of docs/reference/config.md (``name`` is its marker's name)."""

    name: str
    # "module:NAME[.part]": the set of keys the loader accepts ("" for a single key).
    keys_of: str
    keys: tuple[Key, ...]
    # The first column's title: "key", or "setting" for a mitigation kind's settings.
    column: str = "key"

    @property
    def key_names(self) -> list[str]:
        return [n.strip() for k in self.keys for n in k.name.split(",")]


SECTIONS: tuple[Section, ...] = (
    Section(
        "component",
        "",
        (
            Key(
                "component",
                "string",
                "required",
                "the FRETISH component. Every requirement must name it (`sRobot shall ...`); a requirement in the config naming another component is an error, while requirements of other components in an imported FRET project export are left out with a note (see the import section)",
            ),
        ),
    ),
    Section(
        "step",
        "supervisor.config.step:STEP_KEYS",
        (
            Key(
                "policy",
                "`periodic`, `on_message`, `on_trigger`, `synchronized`",
                "`{}`",
                "when the monitor steps, one of the four policies in the table below",
                default_of="supervisor.config.model:StepConfig.policy",
            ),
            Key(
                "trigger",
                "variable name",
                "",
                "`on_trigger`: the topic variable whose message ends a tick. Required for `on_trigger`; must be a topic variable, not a define",
            ),
            Key(
                "period_ms",
                "number > 0",
                "none",
                "the tick length. Converts durations with units in requirements (`within 2 seconds` at 100 ms is 20 ticks; a duration that is not a whole number of ticks is an error naming a period that would work). `periodic`: the timer period, required",
            ),
            Key(
                "stale_after_ms",
                "number > 0",
                "none (no stale check)",
                "an input silent for longer is *stale*, at that moment (not at the next check): logged, shown in `/diagnostics`, and `on_stale` runs. A variable's own `stale_after_ms` overrides it",
            ),
            Key(
                "max_skew_ms",
                "number > 0",
                "none",
                "`synchronized`: step anyway this long after the first new message of a round. `check` warns when it is missing",
            ),
            Key(
                "prefix",
                "C identifier",
                "none",
                "names the C functions `<prefix>_step` and `<prefix>_reset` instead of `step` and `monitor_reset` (Copilot's `cSettingsStepFunctionName`); with the Copilot backend, also the generated files' name",
            ),
            Key(
                "recent",
                "",
                "",
                "accepted and ignored; the number of recent ticks in a violation record is `logging.recent`",
            ),
            Key(
                "margins",
                "`true`, `false` or number > 0",
                "`false`",
                "the step also computes each requirement's *margin*, how far it is from breaking, in its inputs' units ([margins.md](margins.md)); a number is a boolean atom's margin (`true`: infinite). Native backend only",
            ),
        ),
    ),
    Section(
        "variables",
        "supervisor.config.variables:VAR_KEYS",
        (
            Key(
                "type",
                "`bool`, `int64`, `double`",
                "required (or from `variables_from`)",
                "the monitor's type. Aliases: `boolean`; `int`, `integer`, `int64_t`; `real`, `float64`",
            ),
            Key(
                "topic",
                "absolute topic name",
                "required for a topic variable",
                "where the value comes from (`/scan`, not `scan`)",
            ),
            Key(
                "msg",
                "ROS 2 message type",
                "required for a topic variable",
                "`pkg/msg/Name` (also `pkg/Name`, `pkg::msg::Name`). Any installed type; `check` imports it",
            ),
            Key(
                "field",
                "path",
                "`{}`",
                "the field read from each message (`twist.twist.linear.x`). A name may be followed by `[N]`, element N of an array (`ranges[0]`; `[-1]` the last), or `[]`, every element (`status[].level`: the level of each status; then `reduce:` makes one value of them). `check` verifies every name and index against the message type and that the type at the end can feed the variable: `bool` from `bool`; `int64` from any integer field (`int8` ... `uint64`, `byte`, `char`); `double` from `float32`, `float64` or any integer field. A message whose array is too short for `[N]` gives no value: `input_rejected` says which array had how many elements",
                default_of="supervisor.config.model:Variable.field",
            ),
            Key(
                "define",
                "expression",
                "",
                "makes it an internal variable computed from topic variables (`distance_to_target > 7`). May not use another internal variable. Its type must be `type` (an `int64` expression may define a `double`). FRET's `constant 7` is read as `7`. A define cannot have `topic` or `msg`",
            ),
            Key(
                "qos",
                "`auto`, `reliable`, `best_effort`, `sensor_data`",
                "`{}`",
                "the subscription's QoS. `auto` matches the publishers found at start (best effort if any publisher is, transient local only if all are; reliable and volatile when there is no publisher yet, with a warning), and resubscribes when a later publisher cannot be matched",
                default_of="supervisor.config.model:Variable.qos",
            ),
            Key(
                "depth",
                "whole number >= 1",
                "`{}`",
                "the subscription's history depth: messages queued while the loop is busy (a burst, an fsync). The loop takes at most 20 ms of messages per turn, so 1000 holds a burst of 1000 messages per topic, 50 ms at 20k msg/s on one topic; overflow is counted as lost ([ros-interfaces.md](ros-interfaces.md#lost-messages)). Lower it for large messages (images, point clouds): it bounds the memory a backlog takes",
                default_of="supervisor.config.variables:DEFAULT_DEPTH",
            ),
            Key(
                "initial",
                "a value of `type`",
                "none",
                "the value before the first message, so the monitor can step before this input has spoken",
            ),
            Key(
                "stale_after_ms",
                "number > 0",
                "`step.stale_after_ms`",
                "this input's silence limit",
            ),
            Key(
                "role",
                "`input`, `output`, `internal`",
                "`internal` for a define, else `input`",
                "for the analyses and `inject`: an `input` is sensed (chosen by the environment), an `output` is set by the robot's controller. Realizability is only checked when some variable is an `output`",
            ),
            Key(
                "range",
                "`[min, max]`",
                "none",
                "for the analyses and `inject`: on an input an assumption, on an output a limit of what the controller may choose. Not enforced at run time: a value outside the range reaches the monitor as it is",
            ),
            Key(
                "reduce",
                "`min`, `max`, `mean`, `sum`, `count`, `len`, `any`, `all`",
                "none",
                "one value from the array `field` (`field: ranges, reduce: min`: the closest obstacle of a `sensor_msgs/msg/LaserScan`). NaN elements are not readings; a LaserScan's `ranges` also leave out infinite readings and those outside its `range_min`..`range_max` (REP 117). With no reading left: `min` is `+inf` (nothing seen), `max` `-inf`, `mean` NaN, `sum` 0, `count` 0; `len` counts every element. `count`/`len` feed `int64` (or `double`), `any`/`all` a `bool` from a boolean array, `min`/`max`/`sum` of integers an `int64` or `double`, the rest a `double`; `check` says when the field is not an array or the result cannot feed the variable. Reduced in the loop with numpy: 12 µs for a 1,440-reading scan here",
            ),
            Key(
                "age_of, stamp",
                "an input variable; a path",
                "`stamp: header.stamp`",
                "makes this `double` the *age* of that input's latest message at each tick, in milliseconds: the tick's time minus the message's stamp (`scan_age_ms: {type: double, age_of: obstacle}`). A driver that freezes and keeps republishing old data is caught though its topic is alive. Read on the same subscription as the input; see [Ages and rates](#ages-and-rates)",
            ),
            Key(
                "rate_of, window_ms",
                "an input variable; ms",
                "`window_ms: {}`",
                "makes this `double` that input's receive rate: messages per second over the last `window_ms` (at most an hour). See [Ages and rates](#ages-and-rates)",
                default_of="supervisor.config.model:Variable.window_ms",
            ),
            Key(
                "service, srv, call",
                "absolute name; `pkg/srv/Name`; `request` or `response`",
                "",
                "reads the service's calls, from ROS 2 service introspection. With `field:` (a field of the request or response, paths as above, `initial:` required) the latest call's value; with `event: true`, true at the tick a request was made or a response came back. See [Services and actions](#services-and-actions)",
            ),
            Key(
                "action, status",
                "absolute name; a goal state or a list of them",
                "",
                "reads the action's goal states (`accepted`, `executing`, `canceling`, `succeeded`, `canceled`, `aborted`). A `bool` is true while some goal is in one of them, an `int64` counts those goals (both start `false`/0: no goal); with `event: true`, true at the tick a goal entered one of them. See [Services and actions](#services-and-actions)",
            ),
            Key(
                "event",
                "`true` / `false`",
                "`{}`",
                "an *event*: `true` only at the tick at which its message arrived (the first step after it), `false` at every other tick, for messages whose arrival is the fact (an estop button, `std_msgs/msg/Empty`): `upon estop base shall within 10 ticks satisfy halt`. `type: bool`; no `field` is read and no `initial` is given (it is `false` until a message comes, so it never holds back the first step). Silence is an event's normal state: it is stale only with a `stale_after_ms` of its own, never by `step.stale_after_ms`",
                default_of="supervisor.config.model:Variable.event",
            ),
        ),
    ),
    Section(
        "functions",
        "supervisor.config.functions:FUNCTION_KEYS",
        (
            Key("params", "list of names", "", "the parameters, in call order"),
            Key(
                "define",
                "expression",
                "",
                "the value, over the parameters only: arithmetic and C functions, `ite`, past-time operators, other functions of this section",
            ),
        ),
    ),
    Section(
        "requirements",
        "supervisor.config.requirements:REQ_KEYS",
        (
            Key(
                "id",
                "C identifier",
                "required",
                "unique; letters, digits and `_`, not starting with a digit, at most 128 characters (anything else is an error at the id). The C handler is `handler<id>`",
            ),
            Key(
                "text",
                "FRETISH sentence",
                "required (unless refining an imported id)",
                '`[scope] [condition] [the] COMPONENT shall [timing] satisfy RESPONSE`; see the README\'s "Writing requirements"',
            ),
            Key("rationale", "string", "", "shown by `explain`"),
            Key(
                "on_violation",
                "list of mitigation names (or one name)",
                "`requirement_defaults.on_violation`, else none",
                "the actions run when the requirement is violated. Without any, a violation is logged and nothing else happens",
            ),
            Key(
                "policy",
                "mapping",
                "`requirement_defaults.policy`, else the defaults below",
                "[policy](#policy)",
            ),
            Key(
                "predict",
                "mapping",
                "none",
                "warn ahead: from the requirement's margins, estimate the time until it is violated and act early ([predict](#predict), [prediction.md](prediction.md)). Turns the monitor's margins on",
            ),
            Key(
                "assumption",
                "`true` / `false`",
                "`true` when the id contains `assumption` (any case)",
                "an assumption constrains the inputs for the analyses (what the environment does); it is still monitored like any other requirement",
            ),
            Key("on_pending", "", "", "accepted and ignored"),
        ),
    ),
    Section(
        "requirement_defaults",
        "supervisor.config.requirements:DEFAULTS_KEYS",
        (
            Key(
                "on_violation",
                "",
                "",
                "for every requirement that does not set its own, imported ones included",
            ),
            Key("policy", "", "", "the same, for `policy`"),
            Key("on_pending", "", "", "accepted and ignored"),
        ),
    ),
    Section(
        "predict",
        "mitigations.settings:PREDICT_KEYS",
        (
            Key(
                "horizon_ms",
                "number > 0",
                "`{}`",
                "a time to violation estimated within this is a prediction (a `prediction` record, then `actions`); one not followed by a violation within it is logged as expired",
                default_of="mitigations.settings:PredictConfig.horizon_ms",
            ),
            Key(
                "window_ms",
                "number > 0, at most 60000",
                "`{}`",
                "the margins of the last `window_ms` are fitted by a straight line (least squares); its slope and spread give the time to violation and its interval",
                default_of="mitigations.settings:PredictConfig.window_ms",
            ),
            Key(
                "min_confidence",
                "number above 0, at most 1",
                "`{}`",
                "the least probability, under the fit's errors, that the margin is gone within the horizon",
                default_of="mitigations.settings:PredictConfig.min_confidence",
            ),
            Key(
                "actions",
                "list of mitigation names (or one name)",
                "none (the prediction is logged only)",
                "the early actions, through the requirement's policy (its cooldown counts them)",
            ),
        ),
    ),
    Section(
        "policy",
        "mitigations.settings:POLICY_KEYS",
        (
            Key(
                "debounce_steps",
                "whole number >= 1",
                "`{}`",
                "an episode starts only after this many consecutive flagged ticks ...",
                default_of="mitigations.settings:PolicyConfig.debounce_steps",
            ),
            Key(
                "debounce_ms",
                "number >= 0",
                "`{}`",
                "... and this long since the first of them",
                default_of="mitigations.settings:PolicyConfig.debounce_ms",
            ),
            Key(
                "cooldown_ms",
                "number >= 0",
                "`{}`",
                "the actions are not run again within this time of their last run; the violation is still logged, with `policy_state.cooldown: suppressed`",
                default_of="mitigations.settings:PolicyConfig.cooldown_ms",
            ),
            Key(
                "reset",
                "`never`, `after_mitigation`, `{after_ms: T}`",
                "`{}` (`after_mitigation` with `latch`)",
                "when this requirement's monitor state is reset, so that it is judged afresh. `after_mitigation`: right after its actions are issued, before the next tick; no tick is skipped, and a violation at the very next tick is a new episode (this replaces the thesis's node relaunch, blind for 1.5 s). `{after_ms: T}`: T ms after the episode started. `never`: a violated `always` (`H ...`) stays violated and is reported once, until an operator reset. Other requirements' state (a running `within 5 ticks`) is never touched",
                default_of="mitigations.settings:PolicyConfig.reset",
            ),
            Key(
                "latch",
                "`true` / `false`",
                "`{}`",
                "keep the mitigation in force: after the first action the requirement is *latched*; its `publish` actions are repeated every `repeat_ms` until an operator reset, which is accepted only if the requirement holds at the last tick. New episodes while latched are logged (`cooldown: latched`) without running the actions again. `latch` with `reset: never` is an error (the latch could never be released)",
                default_of="mitigations.settings:PolicyConfig.latch",
            ),
            Key(
                "repeat_ms",
                "number > 0",
                "`{}`",
                "`latch`: the repeat period",
                default_of="mitigations.settings:PolicyConfig.repeat_ms",
            ),
            Key(
                "escalate",
                "`{after_ms: T, actions: [...]}`",
                "none",
                "if the incident still lasts T ms after its first action, run these actions once (`stage: escalation`). Also run when a confirmation fails",
            ),
            Key(
                "confirm",
                "`{variable: V, equals: X, within_ms: T}`",
                "none",
                "check that the action took effect on the robot: topic variable V must equal X within T ms of the incident's start. A `mitigation` record with `kind: confirm` says whether it did; if not, the escalation runs (`stage: confirm_failed`). V must also be read by a requirement (or be the trigger), or `check` reports it as unused",
            ),
        ),
    ),
    Section(
        "publish",
        "mitigations.settings:SETTING_KEYS.publish.1",
        (
            Key("topic", "absolute topic name", "required", ""),
            Key("msg", "ROS 2 message type", "required", "any installed type"),
            Key(
                "value",
                "mapping",
                "all fields default",
                "nested field values, `{linear: {x: 0.0}, angular: {z: 0.0}}`",
            ),
            Key(
                "qos",
                "`latched`, `reliable`, `best_effort`",
                "`{}`",
                "`latched` is reliable + transient local, depth 1: a controller that starts after the violation still receives the halt",
                default_of="mitigations.settings:PublishSettings.qos",
            ),
            Key(
                "repeat_ms",
                "",
                "",
                "accepted and ignored; the repeat period of a latched requirement is its policy's `repeat_ms`",
            ),
        ),
        column="setting",
    ),
    Section(
        "ssh",
        "mitigations.settings:SETTING_KEYS.ssh.1",
        (
            Key("host", "string", "required", ""),
            Key("port", "1..65535", "`{}`", "", default_of="mitigations.settings:SshSettings.port"),
            Key("user", "string", "required", ""),
            Key(
                "key",
                "path",
                "required",
                "private key without passphrase; the only authentication tried (no agent, no `~/.ssh`, no password)",
            ),
            Key(
                "known_hosts",
                "path",
                "required",
                "the only host keys trusted, under `host` (port 22) or `[host]:port`; an unknown or different key is refused, never added, never retried",
            ),
            Key(
                "command",
                "string",
                "required",
                "set it to the robot's forced command so the log says what runs",
            ),
            Key(
                "connect_timeout_s",
                "number > 0",
                "`{}`",
                "bounds TCP connect, banner, authentication and opening the session",
                default_of="mitigations.settings:SshSettings.connect_timeout_s",
            ),
            Key(
                "command_timeout_s",
                "number > 0",
                "`{}`",
                "bounds the command; success is exit status 0",
                default_of="mitigations.settings:SshSettings.command_timeout_s",
            ),
            Key(
                "retries",
                "whole number >= 1",
                "`{}`",
                "total attempts. Only failures before the command was sent are retried (refused, unreachable, timed out, name not resolved); a non-zero exit, a command timeout or a connection lost while the command ran are not (it may already have had its effect)",
                default_of="mitigations.settings:SshSettings.retries",
            ),
            Key(
                "backoff_s",
                "number >= 0",
                "`{}`",
                "wait after the first failure, doubling, at most 5 s",
                default_of="mitigations.settings:SshSettings.backoff_s",
            ),
        ),
        column="setting",
    ),
    Section(
        "command",
        "mitigations.settings:SETTING_KEYS.command.1",
        (
            Key(
                "argv",
                "non-empty list of strings",
                "required",
                "executed directly (`$HOME`, `;`, `*` reach it literally); a bare name is looked up in `PATH`",
            ),
            Key(
                "timeout_s",
                "number > 0",
                "`{}`",
                "then the program and its whole process group are killed",
                default_of="mitigations.settings:CommandSettings.timeout_s",
            ),
            Key(
                "env",
                "mapping",
                "",
                "added to a minimal environment (`PATH`, `LANG=C.UTF-8`); the daemon's own environment is not passed",
            ),
            Key(
                "retries",
                "whole number >= 1",
                "`{}`",
                "total attempts; a program that cannot be started is not retried",
                default_of="mitigations.settings:CommandSettings.retries",
            ),
            Key(
                "backoff_s",
                "number >= 0",
                "`{}`",
                "as for `ssh`",
                default_of="mitigations.settings:CommandSettings.backoff_s",
            ),
        ),
        column="setting",
    ),
    Section(
        "log",
        "mitigations.settings:SETTING_KEYS.log.1",
        (
            Key(
                "message",
                "string",
                "`{}`",
                "written into the record's `detail`",
                default_of="mitigations.settings:LogSettings.message",
            ),
        ),
        column="setting",
    ),
    Section(
        "on_stale",
        "",
        (
            Key(
                "on_stale",
                "list of mitigation names (or one name)",
                "none",
                "run each time an input becomes stale (see `stale_after_ms`): a silent classifier can stop the robot. Recorded with `requirement: on_stale:<input>` and `stage: stale`. An input that never sent anything is not stale (it is shown as missing)",
            ),
        ),
    ),
    Section(
        "logging",
        "supervisor.config.violation_log:LOG_KEYS",
        (
            Key(
                "violations",
                "path",
                "none",
                "the violation log. `run --log` overrides it; one of the two is required by `run`. A relative path is relative to the daemon's working directory (the unit's is `/var/lib/safety-supervisor`)",
            ),
            Key(
                "recent",
                "whole number",
                "`{}`",
                "how many ticks of inputs a violation record keeps (`recent`), the violating tick included",
                default_of="supervisor.config.violation_log:RECENT",
            ),
            Key(
                "retry_buffer",
                "whole number, 1 to 1000000",
                "`{}`",
                "records kept in memory while the log cannot be written (a full disk); retried in order, and a `records_lost` record names any dropped beyond this ([log.md](log.md#when-the-log-cannot-be-written))",
                default_of="supervisor.config.violation_log:RETRY_BUFFER",
            ),
            Key(
                "durability",
                "`after_publish` or `before_action`",
                "`{}`",
                "when a violation record is fsynced. `after_publish`: written to the file (the page cache) before the actions, fsynced once the halt publish is out: a crash of the daemon loses nothing, a power loss within that fsync window can lose the last records. `before_action`: fsynced before any action runs, so the halt waits for the disk ([log.md](log.md#durability)). Reload applies it",
                default_of="supervisor.config.violation_log:DURABILITY",
            ),
            Key("stderr", "", "", "accepted and ignored"),
        ),
    ),
    Section(
        "analysis",
        "supervisor.config.analysis:ANALYSIS_KEYS",
        (
            Key(
                "k",
                "whole number, 1 to 100000",
                "the largest time bound + 2, at least 3",
                "length of the analysed traces in ticks (`--k` overrides it)",
            ),
            Key(
                "rlimit",
                "whole number, 1 to 4294967295",
                "`{}`",
                "z3's resource limit per query: a count of z3's own steps, so the same config gives the same findings on any machine and under any load. A query that reaches it is reported as `z3 gave up: resource limit N` (raise it to decide more)",
                default_of="supervisor.config.analysis:AnalysisConfig.rlimit",
            ),
            Key(
                "timeout_s",
                "number > 0",
                "`{}`",
                "wall-clock cap per z3 query, a safety net far above what `rlimit` takes; a query it stops is reported as `z3 gave up: wall-clock cap S s`",
                default_of="supervisor.config.analysis:AnalysisConfig.timeout_s",
            ),
            Key(
                "enabled",
                "boolean",
                "`{}`",
                "`false` (also `no`, `0`, `off`) skips the analyses",
                default_of="supervisor.config.analysis:AnalysisConfig.enabled",
            ),
        ),
    ),
    Section(
        "ros",
        "supervisor.config.ros:ROS_KEYS",
        (
            Key(
                "node_name",
                "letters, digits, `_`",
                "`{}`",
                "the daemon's node name. Its topics and service keep their absolute names",
                default_of="supervisor.config.model:RosConfig.node_name",
            ),
            Key(
                "namespace",
                "absolute ROS namespace",
                "`{}`",
                "the daemon's own topics (`safety_supervisor/violations`, `/heartbeat`, `/status`) and reset service are named relative to it: `/robot1` gives `/robot1/safety_supervisor/status`, so supervisors of several robots on one graph stay apart. Inputs, mitigation topics and `/diagnostics` keep their configured, absolute names",
                default_of="supervisor.config.model:RosConfig.namespace",
            ),
            Key(
                "heartbeat_ms",
                "number > 0",
                "`{}`",
                "period of `/safety_supervisor/heartbeat`",
                default_of="supervisor.config.model:RosConfig.heartbeat_ms",
            ),
            Key(
                "diagnostics_ms",
                "number > 0",
                "`{}`",
                "period of `/diagnostics` and of the check of the ROS graph (publishers, types, QoS)",
                default_of="supervisor.config.model:RosConfig.diagnostics_ms",
            ),
            Key(
                "status_ms",
                "number >= 0",
                "`{}`",
                "period of `/safety_supervisor/status` (what `ui` shows, [ros-interfaces.md](ros-interfaces.md#status)); 0: not published",
                default_of="supervisor.config.model:RosConfig.status_ms",
            ),
            Key(
                "reset_service",
                "boolean",
                "`{}`",
                "serve `/safety_supervisor/reset` (`std_srvs/Trigger`, no credentials): only on an SROS2 graph with access control; `check` warns when it is on",
                default_of="supervisor.config.model:RosConfig.reset_service",
            ),
        ),
    ),
    Section(
        "control",
        "supervisor.config.control:CONTROL_KEYS",
        (
            Key(
                "socket",
                "path, at most 107 bytes",
                "`$RUNTIME_DIRECTORY/control.sock` under systemd, else per user and `ROS_DOMAIN_ID`",
                "where the daemon listens; relative to the config's folder",
            ),
            Key(
                "group",
                "group name",
                "`safety-operators` under systemd, else none",
                "members may reset (socket mode 0660); the daemon's user must belong to it. Without a group: the daemon's user and root only (0600)",
            ),
            Key(
                "max_resets",
                "whole number >= 1",
                "`{}`",
                "resets carried out per interval (socket and ROS service together)",
                default_of="supervisor.config.model:ControlConfig.max_resets",
            ),
            Key(
                "interval_ms",
                "number > 0",
                "`{}`",
                "the rate limit's window, and the period of the `reset_refused` summary",
                default_of="supervisor.config.model:ControlConfig.interval_ms",
            ),
        ),
    ),
    Section(
        "limits",
        "supervisor.config.limits:LIMITS_KEYS",
        (
            Key(
                "monitor_memory_mb",
                "number > 0",
                "`{}`",
                "static state of the generated monitor, all requirements together. Computed from the bounds before any C is written: a lower time bound of L ticks above 64 costs a delay line of L bytes; every other operator costs a few bytes whatever its bound (a saturating counter). A requirement over it fails at its line: `FILE:LINE: requirement 'r1' needs 33.5 GB of monitor state, limit 64.0 MB (limits.monitor_memory_mb): ...`; requirements each under it but together over it are an error at `limits:` (or the file) naming the largest",
                default_of="supervisor.config.limits:Limits.monitor_memory_mb",
            ),
            Key(
                "analysis_budget_s",
                "number > 0",
                "`{}`",
                "wall-clock time of all the analyses of one `check` or `explain` together (each z3 query also stays within `analysis.timeout_s`). An unrolling of k ticks estimated to need more than the budget is not started, and one projected (from its first half second) to take more than half of the budget is given up at once ([faults.md](faults.md)); what runs out is stopped. `check` and `explain` print which analyses were skipped and why: `skipped: realizability, vacuity, redundancy: stopped: the time budget of 30 s ran out during it (limits.analysis_budget_s)`. Findings made before stay; a skipped analysis is not an error, and the monitor is still compiled",
                default_of="supervisor.config.limits:Limits.analysis_budget_s",
            ),
            Key(
                "analysis_memory_mb",
                "number > 0",
                "`{}`",
                "what z3 may hold during the analyses (its `max_memory`). Reached, the analysis running stops, the later ones and `explain`'s example traces are skipped: `skipped: vacuity: stopped: z3 reached its memory limit of 512 MB (limits.analysis_memory_mb)`. z3 looks at its memory only at points of its search, so one hard query can hold more before it stops (3.7 GB in one 10 s query of 10 generated requirements, [BENCHMARKS.md](../BENCHMARKS.md#scaling)); the time budget bounds that query",
                default_of="supervisor.config.limits:Limits.analysis_memory_mb",
            ),
            Key(
                "replay_chunk_mb",
                "number > 0, at most 65536",
                "`{}`",
                "what `replay` and `report --bag` may inflate one chunk of an MCAP bag to (uncompressed chunks too). A chunk declaring more is damage before anything is inflated; one inflating past it (its declared size a lie) is stopped there: `FILE: damaged: the zstd chunk at byte N: inflates to more than ... (limits.replay_chunk_mb 64, limits.replay_ratio 100) (...)`. rosbag2 writes chunks of about 1 MB",
                default_of="supervisor.config.limits:Limits.replay_chunk_mb",
            ),
            Key(
                "replay_ratio",
                "number > 0, at most 1e6",
                "`{}`",
                "... and to at most this many times its compressed size (zstd and lz4 rarely reach 20 on robot data; a decompression bomb reaches thousands)",
                default_of="supervisor.config.limits:Limits.replay_ratio",
            ),
        ),
    ),
    Section(
        "record",
        "supervisor.config.record:RECORD_KEYS",
        (
            Key(
                "path",
                "directory",
                "none",
                "where the bags go; created if missing. A relative path is relative to the daemon's working directory, as `logging.violations` is",
            ),
            Key(
                "max_bag_mb",
                "number > 0, at most 1e6",
                "`{}`",
                "a bag is closed and the next one begun once it holds about this many MB (payload and MCAP's per-message overhead)",
                default_of="supervisor.config.record:RecordConfig.max_bag_mb",
            ),
            Key(
                "max_bag_s",
                "number > 0, at most 1e6",
                "`{}`",
                "... or once its messages span this many seconds, whichever comes first",
                default_of="supervisor.config.record:RecordConfig.max_bag_s",
            ),
            Key(
                "keep",
                "whole number, 1 to 1000000",
                "`{}`",
                "bags kept in the directory, the one being written included; beginning a bag deletes the oldest beyond it. With the defaults the recording takes at most about 2 GB",
                default_of="supervisor.config.record:RecordConfig.keep",
            ),
            Key(
                "queue_messages",
                "whole number, 1 to 10000000",
                "`{}`",
                "messages waiting for the writer (5 s at 20k msg/s); beyond it (or beyond 64 MB of messages) new ones are dropped and counted, never waited for",
                default_of="supervisor.config.record:RecordConfig.queue_messages",
            ),
        ),
    ),
)
