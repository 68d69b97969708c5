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
