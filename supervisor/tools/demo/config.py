"""The demo's copy of the shipped ``srobot.yaml``.

Written to the demo's temp dir at start, so the shipped config stays the single
source of truth.  The only changes: the violation log path, and ``power_off``
runs a local marker program instead of SSH to a robot PC that does not exist here.
"""

from __future__ import annotations

import sys
from pathlib import Path

from supervisor import data
from supervisor.tools.demo.errors import DemoError

SHIPPED_CONFIG = data.example("srobot.yaml")


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
    path = workdir / "srobot-demo.yaml"
    header = (
        f"# Written by 'safety-supervisor demo' from {shipped}:\n"
        "# the violation log is the demo's, and power_off runs a local marker program\n"
        "# instead of SSH to the robot PC (there is none in the demo).\n"
    )
    path.write_text(header + yaml.safe_dump(doc, sort_keys=False, width=100))
    return path
