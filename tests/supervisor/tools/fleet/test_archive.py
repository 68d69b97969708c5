"""The archive's listing (supervisor/tools/fleet/archive.py): what a bag is, the
robot of each, globs, links, and the fingerprint that resume trusts."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from monitors.errors import UserError
from supervisor.tools.fleet.archive import MAX_DEPTH, content_hash, list_archive


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


def test_a_bag_whose_path_is_not_utf8_is_a_failed_row_not_a_crash(tmp_path):
    # a directory name in Latin-1, as an old recorder may have written it
    bad = os.fsdecode(bytes(tmp_path / "fleet" / "r1") + b"/caf\xe9")
    touch(tmp_path / "fleet" / "r1" / "ok" / "a.mcap")
    os.makedirs(bad)
    with open(os.path.join(bad, "a.mcap"), "wb") as f:
        f.write(b"x")
    got = {b.path: b for b in list_archive([str(tmp_path / "fleet")])}
    assert len(got) == 2
    (shown,) = [p for p in got if "caf" in p]
    assert shown.endswith("caf\\xe9") and shown.encode()  # a string the dataset can hold
    assert got[shown].robot is None and "not UTF-8" in (got[shown].robot_error or "")
    assert got[str(tmp_path / "fleet" / "r1" / "ok")].robot == "r1"
    # a file so named inside a bag: its bytes hashed as they are
    with open(os.fsdecode(bytes(tmp_path / "fleet" / "r1" / "ok") + b"/b\xe9.mcap"), "wb") as f:
        f.write(b"y")
    (ok,) = [b for b in list_archive([str(tmp_path / "fleet")]) if b.robot]
    assert ok.size == 2 and len(content_hash(Path(ok.path))) == 64


def test_a_bags_linked_storage_files_are_in_its_content_hash(tmp_path):
    """Two bags whose files are links to different data (as git-annex lays them out)
    are two contents: replay reads through the links, so the hash does too."""
    one = touch(tmp_path / "store" / "one.mcap", b"one")
    two = touch(tmp_path / "store" / "two.mcap", b"two")
    for name, target in (("x", one), ("y", two)):
        (tmp_path / "fleet" / "r1" / name).mkdir(parents=True)
        (tmp_path / "fleet" / "r1" / name / f"{name}.mcap").symlink_to(target)
    x, y = list_archive([str(tmp_path / "fleet")])
    assert content_hash(Path(x.path)) != content_hash(Path(y.path))
    assert x.size == y.size == 3


@pytest.mark.parametrize("what", ["fifo", "text", "empty-dir", "device"])
def test_an_archive_that_holds_no_bag_is_one_error(tmp_path, what):
    path = tmp_path / "a.mcap"
    if what == "fifo":
        os.mkfifo(path)
    elif what == "text":
        path = touch(tmp_path / "notes.txt")
    elif what == "empty-dir":
        path = tmp_path / "empty"
        path.mkdir()
    else:
        path = Path("/dev/null")
    with pytest.raises(UserError, match="no bag") as e:
        list_archive([str(path)])
    assert e.value.file == str(path)


def test_a_tree_deeper_than_the_bound_is_an_error_not_a_silent_skip(tmp_path):
    deep = tmp_path / "fleet" / "r1"
    for i in range(MAX_DEPTH + 1):
        deep = deep / f"d{i}"
    touch(deep / "bag" / "a.mcap")
    touch(tmp_path / "fleet" / "r1" / "shallow" / "a.mcap")
    with pytest.raises(UserError, match=f"deeper than {MAX_DEPTH}"):
        list_archive([str(tmp_path / "fleet")])


def test_a_glob_follows_no_link_loop_and_ends(tmp_path):
    """``**`` never descends into a link: two loops made glob.glob walk every path
    they spell, without end."""
    touch(tmp_path / "fleet" / "r1" / "b" / "a.mcap")
    touch(tmp_path / "fleet" / "r2" / "b" / "a.mcap")
    (tmp_path / "fleet" / "r1" / "loop").symlink_to("..")
    (tmp_path / "fleet" / "r2" / "loop").symlink_to("..")
    (tmp_path / "fleet" / "r2" / "out").symlink_to(touch(tmp_path / "else" / "b" / "a.mcap").parent)
    got = list_archive([str(tmp_path / "fleet" / "**")])  # a timeout of the suite if it loops
    assert [os.path.relpath(b.path, tmp_path / "fleet") for b in got] == ["r1/b", "r2/b"]
    assert [b.robot for b in got] == ["r1", "r2"]
    # a component that is no wildcard still follows a link, as a path does
    (tmp_path / "linked").symlink_to(tmp_path / "fleet")
    assert len(list_archive([str(tmp_path / "linked" / "*" / "b")])) == 2


def test_a_glob_as_deep_as_the_bound_is_an_error(tmp_path):
    deep = tmp_path / "fleet"
    for i in range(MAX_DEPTH + 2):
        deep = deep / f"d{i}"
    touch(deep / "a.mcap")
    with pytest.raises(UserError, match=f"deeper than {MAX_DEPTH}"):
        list_archive([str(tmp_path / "fleet" / "**" / "*.mcap")])


def _listed_as_nobody(archive: Path) -> str:
    """What ``list_archive([archive])`` says run as an unprivileged user (root reads
    any directory): the count of bags, or the UserError's line."""
    import subprocess
    import sys

    as_user = (
        [] if os.geteuid() else ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups"]
    )
    code = (
        "from monitors.errors import UserError\n"
        "from supervisor.tools.fleet.archive import list_archive\n"
        "try:\n"
        f"    print(len(list_archive([{str(archive)!r}])))\n"
        "except UserError as e:\n"
        "    print(e)\n"
    )
    run = subprocess.run(
        [*as_user, sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=Path(__file__).parents[4],
    )
    assert run.returncode == 0, run.stderr
    return run.stdout


def test_a_directory_that_cannot_be_listed_is_an_error_not_a_silent_skip():
    """Its bags were missing from the run without a word."""
    import shutil
    import tempfile

    top = Path(tempfile.mkdtemp(dir="/tmp"))  # reachable by the unprivileged user
    try:
        top.chmod(0o755)
        touch(top / "fleet" / "r1" / "b" / "a.mcap")
        (top / "fleet" / "r2" / "closed").mkdir(parents=True)
        for d in (top / "fleet", top / "fleet" / "r1", top / "fleet" / "r1" / "b"):
            d.chmod(0o755)
        (top / "fleet" / "r2").chmod(0o755)
        (top / "fleet" / "r2" / "closed").chmod(0o000)
        said = _listed_as_nobody(top / "fleet")
        assert "cannot list: Permission denied" in said and "r2/closed" in said, said
    finally:
        (top / "fleet" / "r2" / "closed").chmod(0o755)
        shutil.rmtree(top)


def test_an_archive_behind_a_closed_directory_is_called_unreadable_not_missing():
    """It was "no such directory, bag or match": the user looked for a typo in a path
    that exists."""
    import shutil
    import tempfile

    top = Path(tempfile.mkdtemp(dir="/tmp"))
    try:
        touch(top / "fleet" / "r1" / "b" / "a.mcap")
        top.chmod(0o700)  # root's: the unprivileged user cannot look inside
        said = _listed_as_nobody(top / "fleet" / "r1")
        assert "r1: cannot read it: Permission denied" in said, said
        assert "no such" not in said
    finally:
        shutil.rmtree(top)


def test_a_rules_double_star_is_any_depth_zero_too(tmp_path):
    """``fleet/**/{robot}/bags`` names the robot of ``fleet/r1/bags`` as of
    ``fleet/2026/r2/bags`` (the whole path was one expression, and its ``**`` needed a
    directory)."""
    touch(tmp_path / "fleet" / "r1" / "bags" / "b" / "a.mcap")
    touch(tmp_path / "fleet" / "2026" / "r2" / "bags" / "b" / "a.mcap")
    got = list_archive([str(tmp_path / "fleet")], robot_from="fleet/**/{robot}/bags")
    assert [b.robot for b in got] == ["r2", "r1"]
    # each ** takes as many directories as it can, as before; a leading / is the root
    assert [b.robot for b in list_archive([str(tmp_path)], robot_from="**/{robot}/b")] == [
        "bags",
        "bags",
    ]
    rooted = list_archive([str(tmp_path)], robot_from="/fleet/**/{robot}")
    assert [b.robot for b in rooted] == [None, None]


@pytest.mark.parametrize("rule", ["**x**{robot}", "a*b*{robot}", "x/{robot}**"])
def test_a_rule_that_would_backtrack_is_refused(tmp_path, rule):
    touch(tmp_path / "r" / "a.mcap")
    with pytest.raises(UserError, match=r"\*\* is a directory of its own"):
        list_archive([str(tmp_path)], robot_from=rule)


def test_one_bag_by_two_paths_in_one_run_is_listed_once(tmp_path):
    """The archive and a link to it (or a bind mount): each bag was replayed twice
    in one run, and every violation was two rows of the dataset."""
    touch(tmp_path / "fleet" / "r1" / "b" / "a.mcap")
    touch(tmp_path / "fleet" / "r2" / "one.mcap")
    (tmp_path / "again").symlink_to(tmp_path / "fleet")
    got = list_archive(
        [
            str(tmp_path / "fleet"),
            str(tmp_path / "again"),
            str(tmp_path / "again" / "r2" / "one.mcap"),
        ]
    )
    assert [os.path.relpath(b.path, tmp_path) for b in got] == ["fleet/r1/b", "fleet/r2"]


def test_a_storage_file_beside_bag_directories_is_an_error_not_their_loss(tmp_path):
    # a stray .mcap dropped in a robot's directory made it one bag, and its 100 bag
    # directories were left out without a word
    root = tmp_path / "fleet"
    for i in range(3):
        touch(root / "robot-00" / f"bag-{i}" / f"bag-{i}_0.mcap")
    touch(root / "robot-00" / "stray.mcap")
    with pytest.raises(UserError) as e:
        list_archive([str(root)])
    assert "a bag inside the bag" in str(e.value)
    assert "robot-00/bag-" in e.value.file and "robot-00" in str(e.value)


def test_a_bag_directory_with_a_plain_subdirectory_is_still_one_bag(tmp_path):
    root = tmp_path / "fleet"
    touch(root / "r1" / "bag-a" / "metadata.yaml")
    touch(root / "r1" / "bag-a" / "bag-a_0.mcap")
    touch(root / "r1" / "bag-a" / "plots" / "speed.png")
    bags = [os.path.relpath(b.path, root) for b in list_archive([str(root)])]
    assert bags == ["r1/bag-a"]


def test_a_fifo_named_as_a_storage_file_is_a_bag_not_left_out(tmp_path):
    root = tmp_path / "fleet"
    touch(root / "r1" / "good" / "good.mcap")
    (root / "r1" / "odd").mkdir()
    os.mkfifo(root / "r1" / "odd" / "odd.mcap")
    bags = sorted(os.path.relpath(b.path, root) for b in list_archive([str(root)]))
    assert bags == ["r1/good", "r1/odd"]


def test_the_content_hash_of_a_fifo_is_an_error_not_a_wait(tmp_path):
    # a bag's file swapped for a FIFO after the listing: the hash waited for a writer
    import subprocess
    import sys

    bag = tmp_path / "bag"
    bag.mkdir()
    os.mkfifo(bag / "bag_0.mcap")
    code = (  # the listing taken while the file was a regular one
        "import sys; from pathlib import Path\n"
        "from supervisor.tools.fleet import archive\n"
        "archive.bag_files = lambda bag: [bag / 'bag_0.mcap']\n"
        "try:\n    archive.content_hash(Path(sys.argv[1]))\n"
        "except OSError as e:\n    print(e.strerror); sys.exit(1)\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", code, str(bag)], capture_output=True, text=True, timeout=30
    )
    assert run.returncode == 1 and run.stdout.strip() == "not a regular file", run
