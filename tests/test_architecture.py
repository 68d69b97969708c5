"""The architecture holds: dependencies point one way and no module imports itself back.

The contracts live in pyproject.toml ([tool.importlinter]) and are described in
docs/ARCHITECTURE.md; import-linter (grimp) reads every import statement, function-level
ones included.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import grimp

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("monitors", "mitigations", "supervisor")


def test_import_contracts_hold() -> None:
    exe = shutil.which("lint-imports") or str(Path(sys.executable).parent / "lint-imports")
    r = subprocess.run(
        [exe, "--config", str(ROOT / "pyproject.toml"), "--no-cache"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert "0 broken" in r.stdout, r.stdout


def test_no_import_cycle_between_any_two_modules() -> None:
    # acyclic_siblings judges packages by their children; this also catches a cycle
    # between a package's __init__ and one of its own modules.
    graph = grimp.build_graph(*PACKAGES, include_external_packages=False)
    cycles = set()
    for importer in graph.modules:
        for imported in graph.find_modules_directly_imported_by(importer):
            back = graph.find_shortest_chain(importer=imported, imported=importer)
            if imported != importer and back:
                cycles.add(" -> ".join((importer, *back)))
    assert not cycles, "\n".join(sorted(cycles))


def test_code_refers_to_the_repository_docs_not_to_issues() -> None:
    pattern = re.compile(r"CONTRACT|issue [0-9]")
    hits = [
        f"{path.relative_to(ROOT)}:{n}: {line.strip()}"
        for folder in (*PACKAGES, "tests")
        for path in sorted((ROOT / folder).rglob("*.py"))
        if path.name != "test_architecture.py"
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if pattern.search(line)
    ]
    assert not hits, "\n".join(hits)


def _table_paths(doc: Path) -> set[str]:
    """Paths named in the first column of a Markdown table (`a/`, `b.py`, `c/`, `d.py`)."""
    paths = set()
    for line in doc.read_text(encoding="utf-8").splitlines():
        if line.startswith("| `"):
            first = line.split("|")[1]
            paths.update(p.rstrip("/") for p in re.findall(r"`([^`]+)`", first))
    return paths


def test_architecture_tables_match_the_tree() -> None:
    packages = {
        str(p.parent.relative_to(ROOT))
        for top in PACKAGES
        for p in (ROOT / top).rglob("__init__.py")
        if len(p.parent.relative_to(ROOT).parts) <= 3
    }
    for doc in (ROOT / "README.md", ROOT / "docs" / "ARCHITECTURE.md"):
        named = _table_paths(doc)
        missing = sorted(
            p for p in named if p.split("/")[0] in PACKAGES and not (ROOT / p).exists()
        )
        assert not missing, f"{doc.name} names paths that do not exist: {missing}"
    named = _table_paths(ROOT / "docs" / "ARCHITECTURE.md")
    unnamed = sorted(p for p in packages if p not in named)
    assert not unnamed, f"docs/ARCHITECTURE.md does not describe: {unnamed}"


# The daemon's ROS side: the node and the parts it composes, and what they hand
# their figures to (docs/ARCHITECTURE.md, supervisor/daemon/).
NODE_PARTS = (
    "node",
    "receive",
    "graph",
    "interfaces",
    "resets",
    "reload",
    "loss",
    "status",
    "process",
)


def test_the_daemons_ros_side_talks_to_the_core_only() -> None:
    """No part of the node reads or drives the runtime itself: what it needs goes
    through Core, so the core stays the one place that decides."""
    import ast

    hits = []
    for name in NODE_PARTS:
        path = ROOT / "supervisor" / "daemon" / f"{name}.py"
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            reached = isinstance(node, ast.Attribute) and node.attr == "runtime"
            imported = (
                isinstance(node, ast.ImportFrom) and node.module == "supervisor.daemon.runtime"
            )
            if reached or imported:
                hits.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not hits, "reaches past Core into Runtime: " + ", ".join(hits)
