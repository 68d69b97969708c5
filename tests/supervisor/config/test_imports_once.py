"""The files a config imports are read once per load, as the config is: a FRET file
that gives both variables and requirements is one version of it, and the analyses'
child judges the bytes the monitor was compiled from (supervisor/config/imported.py
``Imports``)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

CONFIG = """\
component: sw
step: {policy: periodic, period_ms: 100}
variables_from: vars.json
requirements_from: reqs.json
analysis: {k: 1000}
"""
# FRET's export with variables: the variables and the requirements come from it
FRET = {
    "requirements": [
        {"reqid": "r1", "fulltext": "upon x > 3 sw shall within 1 second satisfy p"},
    ],
    "variables": [
        {"component_name": "sw", "variable_name": "p", "dataType": "boolean", "idType": "Input"},
        {"component_name": "sw", "variable_name": "x", "dataType": "integer", "idType": "Input"},
    ],
}
OGMA = {  # OGMA 1.7's variable database (tests/data/ogma/ros2-001-db.json)
    "inputs": [
        {"name": n, "type": t, "connections": [{"scope": "ros/message", "topic": f"/{n}"}]}
        for n, t in (("p", "bool"), ("x", "int64_t"))
    ],
    "topics": [
        {"scope": "ros/message", "topic": "/p", "type": "std_msgs::msg::Bool"},
        {"scope": "ros/message", "topic": "/x", "type": "std_msgs::msg::Int64"},
    ],
    "types": [],
}


@pytest.mark.skipif(shutil.which("strace") is None, reason="strace is not installed")
def test_check_opens_each_imported_file_once(tmp_path: Path) -> None:
    (tmp_path / "c.yaml").write_text(CONFIG)
    (tmp_path / "reqs.json").write_text(json.dumps(FRET))
    (tmp_path / "vars.json").write_text(json.dumps(OGMA))
    trace = tmp_path / "strace.txt"
    argv = ["strace", "-f", "-qq", "-e", "trace=open,openat,openat2", "-o", str(trace)]
    argv += [sys.executable, "-m", "supervisor", "check", str(tmp_path / "c.yaml")]
    r = subprocess.run(argv, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    opened = re.findall(r'open(?:at2?)?\((?:[^,]*, )?"([^"]*)"', trace.read_text())
    for name in ("c.yaml", "reqs.json", "vars.json"):
        assert sum(1 for p in opened if Path(p).name == name) == 1, (name, opened)
