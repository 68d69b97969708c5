"""``python -m supervisor.docs [--check]``: write the generated parts of the docs.

One source each: the config's reference tables (docs/reference/config.md) and the
shipped ``template.yaml`` come from :mod:`supervisor.config.schema` with the loaders'
key sets and defaults; the commands' synopses and option tables
(docs/reference/commands.md) from the argparse parsers of :mod:`supervisor.cli`.
A generated part sits between ``<!-- BEGIN GENERATED NAME ... -->`` and
``<!-- END GENERATED -->``; the prose around it is written by hand.
``--check`` changes nothing and exits 1 when a file differs from what it would write.
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import json
import re
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from supervisor.config.schema import SECTIONS, Key, Section

ROOT = Path(__file__).resolve().parents[1]
CONFIG_MD = Path("docs/reference/config.md")
COMMANDS_MD = Path("docs/reference/commands.md")
TEMPLATE = Path("supervisor/data/examples/template.yaml")
COMMAND = "python -m supervisor.docs"
BLOCK = re.compile(
    r"(<!-- BEGIN GENERATED (?P<name>\S+) [^\n]*-->\n).*?(<!-- END GENERATED -->)", re.S
)


class DocsError(Exception):
    """A schema that disagrees with its loader, or a doc without a block it needs."""


# ------------------------------------------------------------------ the schema's sources


def resolve(ref: str) -> Any:
    """``module:NAME.part.part``: an attribute, a mapping's key or a sequence's index."""
    module, _, path = ref.partition(":")
    value: Any = importlib.import_module(module)
    for part in path.split("."):
        if hasattr(value, part):
            value = getattr(value, part)
        elif isinstance(value, dict):
            value = value[part]
        else:
            value = value[int(part)]
    return value


def default_of(key: Key) -> Any:
    if key.default_of is None:
        raise DocsError(f"{key.name}: no default_of")
    return resolve(key.default_of)


def yaml_value(value: Any) -> str:
    """A default as YAML writes it (100.0 as 100, True as true, '' as "")."""
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    if isinstance(value, bool | int | float | str):
        return json.dumps(value)
    raise DocsError(f"a default of type {type(value).__name__} has no YAML form here")


def checked(section: Section) -> Section:
    """The section, once its keys are the loader's keys exactly."""
    if section.keys_of:
        code = set(resolve(section.keys_of))
        documented = set(section.key_names)
        if code != documented:
            raise DocsError(
                f"supervisor/config/schema.py, section {section.name}: keys the loader "
                f"takes and the table lacks: {sorted(code - documented)}; keys the table "
                f"has and the loader refuses: {sorted(documented - code)}"
            )
    return section


# ------------------------------------------------------------------ config.md


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def config_table(section: Section) -> str:
    rows = [
        f"| {section.column} | type | default | meaning |",
        "| --- | --- | --- | --- |",
    ]
    for key in checked(section).keys:
        names = ", ".join(f"`{n.strip()}`" for n in key.name.split(","))
        default = key.default
        if key.default_of is not None:
            value = default_of(key)
            shown = yaml_value(value).strip('"') if value != "" else '""'
            default = default.replace("{}", shown)
        cells = [names, _cell(key.type), _cell(default), _cell(key.meaning)]
        rows.append("| " + " | ".join(cells) + " |")
    return "\n".join(rows) + "\n"


def config_blocks() -> dict[str, str]:
    return {f"config:{s.name}": config_table(s) for s in SECTIONS}


# ------------------------------------------------------------------ commands.md


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:  # argparse has no public accessor for them
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _usage(parser: argparse.ArgumentParser) -> str:
    # A fixed width, so the text does not depend on the terminal that generates it.
    parser.formatter_class = lambda prog: argparse.HelpFormatter(prog, width=92)
    return parser.format_usage().removeprefix("usage: ").rstrip() + "\n"


def _option_row(action: argparse.Action) -> str:
    if action.option_strings:
        name = ", ".join(f"`{o}`" for o in action.option_strings)
    else:
        name = f"`{action.metavar or action.dest.upper()}`"
    if action.choices is not None:
        arg = " \\| ".join(f"`{c}`" for c in action.choices)
    elif action.nargs == 0:
        arg = ""
    else:
        arg = f"`{action.metavar or action.dest.upper()}`" if action.option_strings else ""
    if action.nargs in ("*", "+") or isinstance(action, argparse._AppendAction):
        arg += " ..." if arg else "..."
    default = action.default
    shown = (
        ""
        if default in (None, False, [], argparse.SUPPRESS) or action.nargs == 0
        else f"`{default}`"
    )
    help_text = (action.help or "").replace("%%", "%")
    return f"| {name} | {arg} | {_cell(shown)} | {_cell(help_text)} |"


def command_block(name: str, parser: argparse.ArgumentParser) -> str:
    lines = ["```", _usage(parser).rstrip(), "```", ""]
    actions = [a for a in parser._actions if not isinstance(a, argparse._HelpAction)]
    if actions:
        lines += ["| option | argument | default | meaning |", "| --- | --- | --- | --- |"]
        lines += [_option_row(a) for a in actions]
    return "\n".join(lines) + "\n"


def command_blocks() -> dict[str, str]:
    from supervisor.cli import build_parser

    blocks = {}
    for name, sub in _subparsers(build_parser()).items():
        blocks[f"command:{name}"] = command_block(name, sub)
        # a command of commands (fleet replay): each its own block, named command:a.b
        for inner, parser in _subparsers(sub).items():
            blocks[f"command:{name}.{inner}"] = command_block(f"{name} {inner}", parser)
    return blocks


# ------------------------------------------------------------------ template.yaml

# The template's example robot: the values written live (uncommented); every other
# key of a section is written commented, with its default or the example value here.
_HEADER = """\
# safety-supervisor configuration template: every section and key, each with a
# one-line comment (docs/reference/config.md has the whole meaning of each). It is
# valid as written (`safety-supervisor check template.yaml` passes); replace its
# example robot, a mobile base with an obstacle sensor, with yours. A line '#key: value'
# is an optional key, shown with its default (or an example value): uncomment to set it.
# srobot.yaml is a complete real configuration.
# (Written by `python -m supervisor.docs` from the same table as the reference.)
"""


def _brief(meaning: str) -> str:
    """The meaning's first clause, without markdown, as one comment line."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", meaning).replace("`", "")
    text = re.split(r"(?<=[a-z0-9)])[.;] ", text, maxsplit=1)[0].rstrip(".")
    return text if len(text) <= 96 else text[:93].rsplit(" ", 1)[0] + " ..."


def _section(name: str) -> Section:
    return checked(next(s for s in SECTIONS if s.name == name))


def _keys(name: str, indent: int, live: dict[str, str], examples: dict[str, str]) -> list[str]:
    """Every key of a section: a comment line, then the key live or commented."""
    pad = " " * indent
    out: list[str] = []
    for key in _section(name).keys:
        brief = _brief(key.meaning or key.type)
        if key.default_of is not None and any(n.strip() in live for n in key.name.split(",")):
            brief += f" (default {yaml_value(default_of(key))})"
        for i, n in enumerate(x.strip() for x in key.name.split(",")):
            out.append(f"{pad}# {brief}" if i == 0 else f"{pad}# ... with {key.name.split(',')[0]}")
            if n in live:
                out.append(f"{pad}{n}: {live[n]}")
            elif n in examples:
                out.append(f"{pad}#{n}: {examples[n]}")
            elif key.default_of is not None and n == key.name.split(",")[-1].strip():
                out.append(f"{pad}#{n}: {yaml_value(default_of(key))}")
            else:
                raise DocsError(f"template: key {name}.{n} has neither an example nor a default")
    return out


def _item(lines: list[str], first: str) -> list[str]:
    """The lines of a mapping as a list item: '- ' before the line of key ``first``."""
    out = []
    for line in lines:
        if line.lstrip().startswith(f"{first}:"):
            indent = len(line) - len(line.lstrip())
            line = " " * (indent - 2) + "- " + line.lstrip()
        out.append(line)
    return out


def _commented(lines: Iterable[str]) -> list[str]:
    return [("#" + line) if not line.lstrip().startswith("#") else line for line in lines]


def template_yaml() -> str:
    out = [_HEADER]
    out += ["# " + _brief(_section("component").keys[0].meaning), "component: Robot", ""]
    out += ["# When the monitor steps: each tick judges every requirement on the latest inputs."]
    out += ["step:"]
    out += _keys(
        "step",
        2,
        {"policy": "periodic", "period_ms": "100", "stale_after_ms": "500"},
        {
            "trigger": "halted",
            "max_skew_ms": "20",
            "prefix": "Robot",
            "recent": "10",
            "margins": "true",
        },
    )
    out += [
        "",
        "# Imported from FRET and OGMA (paths relative to this file; see srobot-from-fret.yaml):",
        "# FRET's Copilot export or project export: its requirements join the list below.",
        "#requirements_from: fret-export.json",
        "# OGMA's variable database: its variables join the ones below.",
        "#variables_from: ogma-variables.json",
        "",
        "# What the requirements read: topic inputs and internal (computed) variables.",
        "variables:",
        "  # A topic input, with every key (the ones of other sources commented).",
        "  obstacle_mm:",
    ]
    out += _keys(
        "variables",
        4,
        {
            "type": "int64",
            "topic": "/obstacle_distance_mm",
            "msg": "std_msgs/msg/UInt16",
            "field": "data",
            "role": "input",
            "qos": "sensor_data",
            "depth": "5",
            "stale_after_ms": "300",
            "initial": "10000",
            "range": "[0, 65535]",
        },
        {
            "define": "other_input < 500",
            "reduce": "min",
            "age_of": "obstacle_mm",
            "stamp": "header.stamp",
            "rate_of": "obstacle_mm",
            "service": "/dock",
            "srv": "std_srvs/srv/Trigger",
            "call": "response",
            "action": "/navigate",
            "status": "[accepted, executing]",
            "event": "false",
        },
    )
    out += [
        "  # The commanded forward speed (m/s), a field inside a Twist.",
        "  speed: {type: double, topic: /cmd_vel, msg: geometry_msgs/msg/Twist, field: linear.x,"
        " role: output, range: [-2, 2]}",
        "  # The robot echoes its halt state here (not the supervisor's own command topic).",
        "  halted: {type: bool, topic: /robot/halted, msg: std_msgs/msg/Bool, role: output,"
        " initial: false}",
        "  # An internal variable: an expression over inputs, with no topic.",
        "  too_close: {type: bool, define: obstacle_mm < 500}",
        "",
        "# Functions FRET's formulas call, defined here (none needed by this robot).",
        "functions:",
        "  # A function's name, as FRET's formulas call it: clamp(v, lo, hi).",
        "  #clamp:",
    ]
    out += _commented(
        _keys("functions", 4, {}, {"params": "[v, lo, hi]", "define": "'min(max(v, lo), hi)'"})
    )
    out += ["", "# Defaults for requirements that do not set these keys (and for imported ones)."]
    out += ["requirement_defaults:"]
    out += _keys(
        "requirement_defaults",
        2,
        {
            "on_violation": "[record]",
            "policy": "{debounce_steps: 1, cooldown_ms: 1000, reset: after_mitigation}",
        },
        {"on_pending": "[]"},
    )
    out += [
        "",
        "# The requirements, in FRETISH: [scope] [condition] COMPONENT shall [timing]"
        " satisfy RESPONSE.",
        "requirements:",
        "  # An assumption: it constrains the inputs (the analyses rely on it).",
    ]
    out += _item(
        _keys(
            "requirements",
            4,
            {
                "id": "distance_assumption",
                "text": "Robot shall always satisfy obstacle_mm <= 10000",
                "rationale": "The obstacle sensor reaches 10 m and never reports more.",
                "assumption": "true",
            },
            {"on_violation": "[record]", "policy": "{}", "predict": "{}", "on_pending": "[]"},
        ),
        "id",
    )
    out += ["", "  # A guarantee, with every policy key."]
    guarantee = _keys(
        "requirements",
        4,
        {
            "id": "halt_when_close",
            "text": "Whenever too_close Robot shall within 500 milliseconds satisfy halted",
            "rationale": "An obstacle closer than 0.5 m must stop the robot within half a second.",
            "on_violation": "[stop, zero_speed]",
            "policy": "",
        },
        {
            "assumption": "false",
            "predict": "{horizon_ms: 1500, window_ms: 500, actions: [stop]}",
            "on_pending": "[]",
        },
    )
    at = next(i for i, line in enumerate(guarantee) if line.strip() == "policy:") + 1
    guarantee[at:at] = _keys(
        "policy",
        6,
        {
            "debounce_steps": "2",
            "debounce_ms": "100",
            "cooldown_ms": "1000",
            "latch": "true",
            "repeat_ms": "500",
            "reset": "after_mitigation",
            "confirm": "{variable: halted, equals: true, within_ms: 300}",
            "escalate": "{after_ms: 1000, actions: [estop_relay]}",
        },
        {},
    )
    out += _item(guarantee, "id")
    out += [
        "",
        "  # Policy and mitigations from requirement_defaults, except for reset.",
        "  - id: stopped_when_halted",
        "    text: Whenever halted Robot shall immediately satisfy speed = 0",
        "    policy: {reset: {after_ms: 2000}}",
        "",
        "# " + _brief(_section("on_stale").keys[0].meaning),
        "on_stale: [stop]",
        "",
        "# The actions requirements name: each has exactly one kind (publish, ssh, command"
        " or log).",
        "mitigations:",
        "  # A record in the violation log only.",
        "  record:",
        "    # log: a record in the violation log, nothing on the robot.",
        "    log:",
    ]
    out += _keys("log", 6, {"message": "requirement violated"}, {})
    out += [
        "  # Ask the robot to halt.",
        "  stop:",
        "    # publish: one message; check builds it, so a wrong field is a config error.",
        "    publish:",
    ]
    out += _keys(
        "publish",
        6,
        {
            "topic": "/safety/halt",
            "msg": "std_msgs/msg/Bool",
            "value": "{data: true}",
            "qos": "latched",
        },
        {"repeat_ms": "1000"},
    )
    out += [
        "  # Zero speed on the highest-priority input of the robot's command multiplexer.",
        "  zero_speed: {publish: {topic: /cmd_vel_safety, msg: geometry_msgs/msg/Twist,"
        " value: {linear: {x: 0.0}}, qos: reliable}}",
        "  # Open the emergency-stop relay.",
        "  estop_relay:",
        "    # command: a local program with arguments (no shell); its exit status counts.",
        "    command:",
    ]
    out += _keys(
        "command",
        6,
        {
            "argv": "[/usr/local/bin/estop, --on]",
            "timeout_s": "2",
            "env": "{ESTOP_DEVICE: /dev/ttyUSB0}",
            "retries": "2",
            "backoff_s": "0.5",
        },
        {},
    )
    out += [
        "  # Switch the robot's computer off (check warns while the key files are missing).",
        "  #power_off:",
        "    # ssh: one command on another computer (its key and known_hosts only).",
        "  #  ssh:",
    ]
    out += _commented(
        _keys(
            "ssh",
            6,
            {},
            {
                "host": "robot-pc.local",
                "user": "robot",
                "key": "/etc/safety-supervisor/id_ed25519",
                "known_hosts": "/etc/safety-supervisor/known_hosts",
                "command": "sudo systemctl poweroff",
            },
        )
    )
    out += ["", "# The violation log.", "logging:"]
    out += _keys(
        "logging",
        2,
        {"violations": "/var/log/safety-supervisor/violations.jsonl"},
        {"stderr": "true"},
    )
    for name, title in (
        ("analysis", "The formal analyses check runs with z3."),
        ("ros", "The supervisor's own ROS interfaces."),
        ("control", "The operator's control socket and its reset rate limit."),
        ("limits", "How much memory and time check may spend, and replay may inflate."),
        ("record", "Recording the inputs into rosbag2 bags (also: run --record DIR)."),
    ):
        examples = {
            "k": "10",
            "socket": "/run/safety-supervisor/control.sock",
            "group": "safety-operators",
            "path": "/var/lib/safety-supervisor/record",
        }
        out += ["", f"# {title}", f"{name}:"]
        out += _keys(name, 2, {}, examples)
    return "\n".join(out) + "\n"


# ------------------------------------------------------------------ the files


def fill(text: str, blocks: dict[str, str], file: Path) -> str:
    """``text`` with each generated block replaced; every block must have its place."""
    seen: set[str] = set()

    def one(m: re.Match[str]) -> str:
        name = m.group("name")
        if name not in blocks:
            raise DocsError(f"{file}: a generated block '{name}' that nothing generates")
        seen.add(name)
        return m.group(1) + blocks[name] + m.group(3)

    out = BLOCK.sub(one, text)
    missing = sorted(set(blocks) - seen)
    if missing:
        raise DocsError(
            f"{file}: no place for the generated block(s) {', '.join(missing)}: add "
            f"'<!-- BEGIN GENERATED NAME ({COMMAND}) -->' and '<!-- END GENERATED -->'"
        )
    return out


def generated(root: Path | None = None) -> dict[Path, str]:
    """Every generated file's new text, by its path under ``root`` (the checkout's)."""
    root = root or ROOT
    return {
        CONFIG_MD: fill((root / CONFIG_MD).read_text(), config_blocks(), CONFIG_MD),
        COMMANDS_MD: fill((root / COMMANDS_MD).read_text(), command_blocks(), COMMANDS_MD),
        TEMPLATE: template_yaml(),
    }


def differences(root: Path | None = None) -> list[str]:
    """A unified diff of each file that differs from what would be written."""
    root = root or ROOT
    out: list[str] = []
    for rel, text in generated(root).items():
        old = (root / rel).read_text() if (root / rel).exists() else ""
        if old != text:
            out += difflib.unified_diff(
                old.splitlines(keepends=True),
                text.splitlines(keepends=True),
                f"{rel} (as committed)",
                f"{rel} (as generated)",
            )
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=COMMAND, description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="change nothing; exit 1 on a diff")
    args = parser.parse_args(argv)
    try:
        if args.check:
            diff = differences(ROOT)
            sys.stdout.writelines(diff)
            if diff:
                print(f"the generated docs are stale: run `{COMMAND}`", file=sys.stderr)
            return 1 if diff else 0
        for rel, text in generated(ROOT).items():
            if (ROOT / rel).read_text() != text:
                (ROOT / rel).write_text(text)
                print(f"wrote {rel}")
    except DocsError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
