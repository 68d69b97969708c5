"""The archive's listing (supervisor/tools/fleet/archive.py): what a bag is, the
robot of each, globs, links, and the fingerprint that resume trusts."""

from __future__ import annotations

import os

import pytest

from monitors.errors import UserError
from supervisor.tools.fleet.archive import content_hash, list_archive


def touch(path, data=b"x"):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


def test_bags_of_every_shape_and_their_robots(tmp_path):
    root = tmp_path / "fleet"
    touch(root / "r1" / "bag-a" / "metadata.yaml")  # a rosbag2 directory
    touch(root / "r1" / "bag-a" / "bag-a_0.mcap")  # ... whose files are not bags of their own
    touch(root / "r1" / "2026-11" / "loose.db3")  # storage files without metadata.yaml
    touch(root / "r2" / "split" / "s_0.db3.zstd")  # compressed per file
    touch(root / "r2" / "split" / "s_1.db3.zstd")
    touch(root / "r2" / "day" / "run.mcap.zstd")
    touch(root / "r2" / "notes" / "notes.txt")
    touch(root / "r2" / "rec" / "violations.jsonl")  # a recording's log is no bag
    bags = {os.path.relpath(b.path, root): b.robot for b in list_archive([str(root)])}
    assert bags == {"r1/bag-a": "r1", "r1/2026-11": "r1", "r2/split": "r2", "r2/day": "r2"}
    # a bag given itself: the robot is the directory it is in
    (one,) = list_archive([str(root / "r2" / "day" / "run.mcap.zstd")])
    assert one.robot == "day"


def test_a_glob_roots_at_its_first_wildcard_and_a_rule_names_the_robot(tmp_path):
    touch(tmp_path / "data" / "unit-1" / "day" / "a.mcap")
    touch(tmp_path / "data" / "unit-2" / "day" / "b.mcap")
    got = list_archive([str(tmp_path / "data" / "*" / "day")])
    assert [b.robot for b in got] == ["unit-1", "unit-2"]
    got = list_archive([str(tmp_path / "data")], robot_from="unit-{robot}/**")
    assert [b.robot for b in got] == ["1", "2"]


def test_links_are_not_followed_and_a_bad_name_is_the_bags_reason(tmp_path):
    outside = touch(tmp_path / "elsewhere" / "x.mcap").parent
    (tmp_path / "fleet" / "r1").mkdir(parents=True)
    (tmp_path / "fleet" / "r1" / "link").symlink_to(outside)
    touch(tmp_path / "fleet" / "bad name" / "bag" / "a.mcap")
    (bag,) = list_archive([str(tmp_path / "fleet")])
    assert bag.robot is None and "not a plain name" in (bag.robot_error or "")


def test_the_fingerprint_changes_with_a_file_and_the_content_hash_with_its_bytes(tmp_path):
    f = touch(tmp_path / "r" / "a.mcap", b"abc")
    (before,) = list_archive([str(tmp_path)])
    st = f.stat()
    f.write_bytes(b"abd")  # same size
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns))
    (same,) = list_archive([str(tmp_path)])
    assert same.fingerprint == before.fingerprint  # resume trusts names, sizes, times
    assert content_hash(f) != content_hash(touch(tmp_path / "s" / "a.mcap", b"abc"))
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 1))
    assert list_archive([str(tmp_path)])[0].fingerprint != before.fingerprint


@pytest.mark.parametrize("rule", ["no-robot", "{robot}/{robot}"])
def test_a_rule_without_one_robot_is_refused(tmp_path, rule):
    touch(tmp_path / "r" / "a.mcap")
    with pytest.raises(UserError, match="must hold"):
        list_archive([str(tmp_path)], robot_from=rule)
