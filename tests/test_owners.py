"""One owner each (docs/ARCHITECTURE.md): a name, a check or a way of doing a thing
is written in one place, and the others use it.

These read the source with ``ast`` rather than running it: what they guard is where
code lives, which no behaviour test can see.
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

from mitigations.actions.base import Action
from mitigations.settings import MITIGATION_KINDS

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("monitors", "mitigations", "supervisor")


def _sources(*packages: str) -> list[tuple[Path, ast.Module]]:
    return [
        (path, ast.parse(path.read_text(encoding="utf-8")))
        for top in packages
        for path in sorted((ROOT / top).rglob("*.py"))
    ]


def _calls(tree: ast.Module, name: str) -> list[int]:
    """Lines that call ``name`` (``x.name(...)`` or ``name(...)``)."""
    return [
        node.lineno
        for node in ast.walk(tree)
        if isinstance(node, ast.Call)
        and (
            (isinstance(node.func, ast.Attribute) and node.func.attr == name)
            or (isinstance(node.func, ast.Name) and node.func.id == name)
        )
    ]


def test_only_children_py_starts_a_child_in_the_application() -> None:
    # supervisor/children.py gives every child its environment, process group and
    # parent-death signal; a Popen or subprocess.run elsewhere in supervisor/ would
    # skip them, short-lived children included.
    found = [
        f"{path.relative_to(ROOT)}:{line}"
        for path, tree in _sources("supervisor")
        if path != ROOT / "supervisor" / "children.py"
        for name in ("Popen", "run", "call", "check_call", "check_output")
        for line in _calls(tree, name)
        if _on_subprocess(tree, line, name)
    ]
    assert not found, found


def _on_subprocess(tree: ast.Module, line: int, name: str) -> bool:
    """Whether the call ``name`` on ``line`` is subprocess's (``subprocess.run``, or a
    bare ``Popen`` imported from it), not a method of the same name."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and node.lineno == line:
            f = node.func
            if isinstance(f, ast.Attribute) and f.attr == name:
                return isinstance(f.value, ast.Name) and f.value.id == "subprocess"
            if isinstance(f, ast.Name) and f.id == name:
                return name == "Popen"
    return False


@pytest.mark.parametrize("kind", MITIGATION_KINDS)
def test_each_action_kind_is_a_class_named_after_it(kind: str) -> None:
    module = importlib.import_module(f"mitigations.actions.{kind}")
    name = f"{kind.capitalize()}Action"
    cls = getattr(module, name, None)
    assert isinstance(cls, type), f"mitigations/actions/{kind}.py has no class {name}"
    assert cls.kind == kind
    # the interface the engine relies on, declared in mitigations/actions/base.py
    for attribute in ("inline", "run"):
        assert attribute in Action.__annotations__ or hasattr(Action, attribute)
        assert hasattr(cls, attribute), f"{name} lacks {attribute}"
    assert isinstance(cls.inline, bool)


def test_the_engine_reads_actions_through_their_interface_only() -> None:
    tree = ast.parse((ROOT / "mitigations" / "engine.py").read_text(encoding="utf-8"))
    assert _calls(tree, "getattr") == [] and _calls(tree, "hasattr") == []


@pytest.mark.parametrize(
    "literal",
    ["/safety_supervisor/records", "/safety_supervisor/violations", "/safety_supervisor/status"],
)
def test_each_of_the_daemons_topics_is_written_once(literal: str) -> None:
    found = [
        f"{path.relative_to(ROOT)}:{node.lineno}"
        for path, tree in _sources(*PACKAGES)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and node.value == literal
    ]
    assert len(found) == 1 and found[0].startswith("supervisor/names.py:"), found


def test_a_policy_is_validated_where_its_settings_live() -> None:
    # mitigations/settings.py owns what a policy may be; the loader only walks the YAML
    # and points errors at lines, so it names none of the policy's keys' checks.
    from mitigations.settings import SettingsError, parse_policy

    with pytest.raises(SettingsError) as e:
        parse_policy("r1", {"reset": {"after_ms": 0}}, mitigations={}, variables={})
    assert (e.value.key, e.value.setting) == ("reset", "after_ms")
    with pytest.raises(SettingsError) as e:
        parse_policy(
            "r1", {"escalate": {"after_ms": 5, "actions": ["off"]}}, mitigations={}, variables={}
        )
    assert e.value.key == "escalate" and "undefined mitigation 'off'" in e.value.message
    tree = ast.parse((ROOT / "supervisor/config/requirements.py").read_text(encoding="utf-8"))
    assert _calls(tree, "parse_policy"), "the loader does not use mitigations.settings"
    texts = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)}
    assert not texts & {"debounce_steps", "cooldown_ms", "within_ms"}


def test_one_atomic_write() -> None:
    # A second hand-written temp-file-and-rename would drift (the directory fsync,
    # the O_EXCL open); every writer of a whole file uses supervisor/files.py.
    found = [
        f"{path.relative_to(ROOT)}:{node.lineno}"
        for path, tree in _sources("supervisor")
        if path != ROOT / "supervisor" / "files.py"
        for node in ast.walk(tree)
        if isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and node.func.attr in ("replace", "rename")
        and isinstance(node.func.value, ast.Name)
        and node.func.value.id == "os"
    ]
    assert not found, found


def test_one_ros_type_lookup() -> None:
    # mitigations/rosmsg.py writes type names for the actions, the inputs and replay;
    # the recorder's and replay's type resolution uses it rather than a copy.
    from mitigations import rosmsg
    from supervisor.inputs import rostypes
    from supervisor.tools.replay import sources, storage

    assert rostypes.normalise_type is rosmsg.normalise_type
    assert storage.normalise_type is rosmsg.normalise_type
    assert sources.package_hint is rosmsg.package_hint
    assert rosmsg.normalise_type("std_msgs::msg::Int64") == "std_msgs/msg/Int64"
    assert rosmsg.message_class("std_msgs/Int64") is rosmsg.message_class("std_msgs/msg/Int64")


def test_one_progress_line() -> None:
    # supervisor/progress.py decides whether a person is watching (a terminal, not
    # --quiet) and redraws the line; a second copy would print \r lines into a pipe
    # or the journal when it forgets one check.
    found = [
        f"{path.relative_to(ROOT)}:{node.lineno}"
        for path, tree in _sources("supervisor")
        if path != ROOT / "supervisor" / "progress.py"
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant)
        and isinstance(node.value, str)
        and node.value.startswith("\r")
        and not node.value.startswith("\r\n")  # HTTP's line ends, not a redraw
    ]
    assert not found, found


def test_every_record_kind_the_core_writes_has_one_discarding_default() -> None:
    # Sinks that keep some records (fleet's table, report's windows) inherit the rest
    # from DiscardingLog; the shipped MemoryLog and the writer have every kind too.
    from mitigations.violationlog.discard import DiscardingLog
    from mitigations.violationlog.testing import MemoryLog
    from mitigations.violationlog.writer import ViolationLog
    from supervisor.daemon.core import Log
    from supervisor.tools.fleet.task import _Records
    from supervisor.tools.report.inputs import _Capture

    kinds = {n for n in vars(Log) if not n.startswith("_")}
    assert {"violation", "prediction_expired"} <= kinds
    for cls in (DiscardingLog, MemoryLog, ViolationLog):
        assert kinds <= set(dir(cls)), (cls, kinds - set(dir(cls)))
    for sink in (_Records, _Capture):
        assert issubclass(sink, DiscardingLog)
        assert DiscardingLog.prediction_expired is sink.prediction_expired  # not repeated
