"""One bag as one task (supervisor/tools/fleet/task.py): a worker compiles its config
once for all its bags, each bag still judged from a fresh session, and compiles it
again when the config's bytes change."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest

from supervisor.tools.fleet import task
from supervisor.tools.fleet.task import BagTask, run_task
from supervisor.tools.replay.session import replay_files
from tests.supervisor.tools.replay.test_replay import config, messages, write_bag

pytest.importorskip("pyarrow")


def _per_requirement(result: task.BagResult) -> dict[str, int]:
    out: dict[str, int] = {}
    for q in result.violations.column("requirement").to_pylist():
        out[q] = out.get(q, 0) + 1
    return out


def _replayed(cfg: Path, bag: Path) -> dict[str, int]:
    """What ``replay`` counts for the bag, its config compiled afresh."""
    return {
        q["id"]: q["violations"]
        for q in replay_files(cfg, [bag], None, None)["requirements"]
        if q["violations"]
    }


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_one_compile_serves_every_bag_and_an_edited_config_is_compiled_again(tmp_path):
    bags = [write_bag(tmp_path / f"b{i}", messages(20 + i, 3000)) for i in range(3)]
    # a damaged bag between two good ones: its half-judged run leaves nothing behind
    damaged = write_bag(tmp_path / "bad", messages(30, 3000))
    mcap = next(damaged.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    cfg = config(tmp_path, limit=2.0)
    task._prepared.clear()
    order = [bags[0], damaged, bags[1], bags[2]]
    results = [run_task(BagTask(str(b), "r", str(cfg), _sha(cfg))) for b in order]
    assert [r.status for r in results] == ["read", "damaged", "read", "read"]
    assert len(task._prepared) == 1  # compiled once, for the first bag
    for bag, result in zip(order, results, strict=True):
        if bag is not damaged:
            assert _per_requirement(result) == _replayed(cfg, bag) != {}
    # The config edited in place (a higher limit): its next task compiles it again.
    before = _per_requirement(results[0])
    stat = cfg.stat()
    cfg.write_text(cfg.read_text().replace("speed <= 2.0", "speed <= 2.3"))
    os.utime(cfg, ns=(stat.st_atime_ns, stat.st_mtime_ns))  # a same-time edit changes nothing
    again = run_task(BagTask(str(bags[0]), "r", str(cfg), _sha(cfg)))
    assert _per_requirement(again) == _replayed(cfg, bags[0])
    assert _per_requirement(again)["limit"] < before["limit"]
    assert set(again.violations.column("config_sha256").to_pylist()) == {_sha(cfg)}


def test_a_worker_loads_the_monitor_library_once_and_resets_it_for_each_bag(tmp_path):
    """A new copy of the library per bag (a file copy, a dlopen never undone) cost
    milliseconds a bag and memory that grew with the bags; the next bag's session
    resets the one loaded monitor instead, and judges as a fresh replay does."""
    from monitors.backends import load

    bags = [write_bag(tmp_path / f"b{i}", messages(40 - 10 * i, 3000)) for i in range(3)]
    cfg = config(tmp_path, limit=2.0)
    task._prepared.clear()
    first = run_task(BagTask(str(bags[0]), "r", str(cfg), _sha(cfg)))
    libraries = len(load._loaded)
    rest = [run_task(BagTask(str(b), "r", str(cfg), _sha(cfg))) for b in bags[1:]]
    assert len(load._loaded) == libraries  # no new copy loaded for the later bags
    for bag, result in zip(bags, [first, *rest], strict=True):
        assert result.status == "read"
        assert _per_requirement(result) == _replayed(cfg, bag) != {}


# A worker's compile of a config that an audit hook (real opens, observed, nothing
# replaced) rewrites just before any second open of it: read twice, the bytes hashed
# for the cache's key and the bytes compiled would be two versions of the file.
_EDITED_BETWEEN_READS = """
import json, os, sys
from pathlib import Path
from supervisor.tools.fleet import task

cfg, edited = sys.argv[1], Path(sys.argv[2]).read_bytes()
opens, editing = 0, False

def hook(event, args):
    global opens, editing
    if event != "open" or editing or not isinstance(args[0], (str, bytes, os.PathLike)):
        return
    if os.fsdecode(args[0]) != cfg:
        return
    opens += 1
    if opens == 2:
        editing = True
        Path(cfg).write_bytes(edited)
        editing = False

sys.addaudithook(hook)
prepared = task._compiled(cfg)
print(json.dumps({"opens": opens, "key": task._prepared[cfg][0],
                  "compiled": prepared.project.config.sha256}))
"""


def test_a_worker_reads_its_config_once_and_keys_its_compile_by_those_bytes(tmp_path):
    import json
    import subprocess
    import sys

    cfg = config(tmp_path, limit=2.0)
    edited = config(tmp_path, "edited.yaml", limit=2.3)
    run = subprocess.run(
        [sys.executable, "-c", _EDITED_BETWEEN_READS, str(cfg), str(edited)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr
    seen = json.loads(run.stdout)
    assert seen["opens"] == 1
    assert seen["key"] == seen["compiled"]


def test_a_config_edited_during_the_run_is_a_failed_bag_not_rows_under_the_old_identity(
    tmp_path,
):
    """The run keys its rows by the config's identity taken as it began: a worker
    that compiles the edited file (its first task, or one after the edit) would
    write what the new version judged under the old version's identity.  The bag is
    failed instead, with the reason, and the next run replays it under the new one."""
    bag = write_bag(tmp_path / "b", messages(20, 3000))
    cfg = config(tmp_path, limit=2.0)
    began = _sha(cfg)
    task._prepared.clear()
    assert run_task(BagTask(str(bag), "r", str(cfg), began)).status == "read"
    cfg.write_text(cfg.read_text().replace("speed <= 2.0", "speed <= 2.3"))
    result = run_task(BagTask(str(bag), "r", str(cfg), began))
    assert result.status == "failed" and result.violations.num_rows == 0
    assert "changed during the run" in result.reason
    again = run_task(BagTask(str(bag), "r", str(cfg), _sha(cfg)))  # the next run's
    assert again.status == "read" and _per_requirement(again) == _replayed(cfg, bag)


def test_a_bag_changed_between_its_hash_and_its_replay_is_failed_not_a_verdict(
    tmp_path, monkeypatch
):
    """Cut short right after its content was hashed, a bag's row said ``damaged``
    under the intact content's hash, and a later run skipped that content as
    replayed.  Its files are no longer those hashed: failed, and replayed next run."""
    bag = write_bag(tmp_path / "b", messages(20, 3000))
    cfg = config(tmp_path, limit=2.0)
    storage = bag if bag.is_file() else max(bag.iterdir(), key=lambda f: f.stat().st_size)
    hashed = task.content_hash

    def hash_then_cut(path: Path) -> str:
        digest = hashed(path)
        data = storage.read_bytes()
        storage.write_bytes(data[: len(data) // 2])
        return digest

    monkeypatch.setattr(task, "content_hash", hash_then_cut)
    result = run_task(BagTask(str(bag), "r", str(cfg), _sha(cfg)))
    assert result.status == "failed", (result.status, result.reason)
    assert "its files changed while it was replayed" in result.reason
    assert result.violations.num_rows == 0
