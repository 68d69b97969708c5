"""The demo's examples, and its copy of an example's shipped config.

:data:`EXAMPLES` is the one table of what ``demo --example NAME`` runs: the shipped
config, the simulated robot's processes, which of them starts on ``go``, and how
the screen shows it (docs/reference/commands.md, "demo").

The config is written to the demo's temp dir at start, so the shipped config stays
the single source of truth.  The only changes: the violation log path, and
``power_off`` (sRobot) runs a local marker program instead of SSH to a robot PC
that does not exist here.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from supervisor import data
from supervisor.tools.demo import view
from supervisor.tools.demo.errors import DemoError
from supervisor.tools.demo.state import DemoState

SHIPPED_CONFIG = data.example("srobot.yaml")


@dataclass(frozen=True)
class Example:
    """One ``--example``: what runs and how the demo shows it."""

    config: Path  # the shipped config
    robot: str  # what the first line says is started
    processes: Callable[[argparse.Namespace, DemoState], dict[str, list[str]]]  # name -> argv
    go: str  # the process whose ``go`` starts the scenario
    started: str  # what the demo says once it has
    screen: Callable[[DemoState, bool], str]  # the live view
    status_line: Callable[[DemoState], str]  # --no-live, once a second ('' says nothing)
    summary: Callable[[DemoState, float, bool], str]
    note: str = ""  # the first line's end: what is simulated
    options: tuple[str, ...] = ()  # the command's robot options it takes (--fault-rate ...)


def _srobot(args: argparse.Namespace, st: DemoState) -> dict[str, list[str]]:
    robot = [sys.executable, "-m", "supervisor.tools.demo.robot"]
    seed = ["--seed", str(st.seed)]
    return {
        "perception": [*robot, "perception", "--rate-hz", f"{args.rate_hz:g}", *seed],
        "controller": [*robot, "controller", "--fault-rate", repr(st.fault_rate), *seed],
    }


def _mobile_base(_args: argparse.Namespace, st: DemoState) -> dict[str, list[str]]:
    return {"base": [sys.executable, "-m", "supervisor.tools.demo.base", "--seed", str(st.seed)]}


EXAMPLES: dict[str, Example] = {
    "srobot": Example(
        config=SHIPPED_CONFIG,
        robot="the simulated robot",
        processes=_srobot,
        go="perception",
        started="the walk starts",
        screen=view.screen,
        status_line=view.status_line,
        summary=view.summary,
        note="; power_off is simulated: a local marker program, no SSH",
        options=("fault_rate", "rate_hz"),
    ),
    "mobile-base": Example(
        config=data.example("mobile-base.yaml"),
        robot="the simulated mobile base",
        processes=_mobile_base,
        go="base",
        started="the scenario starts",
        screen=view.base_screen,
        status_line=view.base_status_line,
        summary=view.base_summary,
    ),
}
DEFAULT_EXAMPLE = "srobot"


def requirement_ids(config: Path) -> tuple[str, ...]:
    """The ids of a config's requirements, in its order (for the summary's list)."""
    import yaml

    try:
        doc = yaml.safe_load(config.read_text())
    except (OSError, yaml.YAMLError) as e:
        raise DemoError(f"cannot read {config}: {e}") from e
    reqs = doc.get("requirements") if isinstance(doc, dict) else None
    if not isinstance(reqs, list):
        return ()
    return tuple(str(r["id"]) for r in reqs if isinstance(r, dict) and "id" in r)


def demo_config(shipped: Path, workdir: Path, log: Path) -> Path:
    """The shipped config with the demo's log and a local stand-in for ``power_off``."""
    import yaml

    try:
        doc = yaml.safe_load(shipped.read_text())
    except (OSError, yaml.YAMLError) as e:
        raise DemoError(f"cannot read {shipped}: {e}") from e
    if not isinstance(doc, dict):
        raise DemoError(f"{shipped}: not a configuration mapping")
    mitigations = doc.setdefault("mitigations", {})
    if "power_off" in mitigations:
        mitigations["power_off"] = {
            "command": {
                "argv": [
                    sys.executable,
                    "-m",
                    "supervisor.tools.demo.robot",
                    "poweroff-marker",
                    str(workdir),
                ],
                "timeout_s": 10,
            }
        }
    doc.setdefault("logging", {})["violations"] = str(log)
    path = workdir / f"{shipped.stem}-demo.yaml"
    header = (
        f"# Written by 'safety-supervisor demo' from {shipped}:\n# the violation log is the demo's"
    )
    if "power_off" in mitigations:
        header += (
            ", and power_off runs a local marker program\n"
            "# instead of SSH to the robot PC (there is none in the demo)"
        )
    path.write_text(header + ".\n" + yaml.safe_dump(doc, sort_keys=False, width=100))
    return path
