"""The Parquet footer checked before pyarrow is given it
(supervisor/tools/fleet/footer.py): pyarrow ends the process (SIGABRT) on an enum
out of its range in a footer; the dataset's reader says which file, in one line."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from supervisor.tools.fleet import footer
from tests.supervisor.tools.fleet.test_dataset import _small_fleet
from tests.supervisor.tools.fleet.test_fleet_replay import fleet
from tests.supervisor.tools.replay.test_replay import config


def _footer(data: bytes) -> bytes:
    n = footer.footer_length(len(data), data[-8:])
    assert n is not None
    return data[len(data) - 8 - n : len(data) - 8]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("footer")
    _small_fleet(tmp / "fleet", 2)
    cfg = config(tmp, limit=2.0)
    fleet(cfg, tmp / "fleet", "-o", tmp / "ds", "--jobs", "1", ok=(0,))
    return tmp, tmp / "ds"


def test_the_footers_fleet_replay_writes_pass(dataset: tuple[Path, Path]) -> None:
    files = sorted(dataset[1].rglob("*.parquet"))
    assert len(files) > 2
    for f in files:
        footer.check(_footer(f.read_bytes()))


def _report_fails(ds: Path, tmp_path: Path) -> str:
    """``fleet report`` of ``ds``: exit 1 and its one line (not a signal's death)."""
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "fleet", "report", str(ds), "-o",
         str(tmp_path / "f.html"), "--quiet"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert run.returncode == 1 and len(lines) == 1, (run.returncode, run.stderr)
    return lines[0]


def _with_codec(data: bytes, column: str, codec: int) -> bytes:
    """``data`` with ``column``'s compression codec set to ``codec``: in the compact
    protocol, its path's last string (length, bytes) is followed by the codec's field
    header (field 4, after 3; an i32: 0x15) and its zigzag value (one byte here)."""
    needle = bytes([len(column)]) + column.encode() + b"\x15"
    at = data.rindex(needle) + len(needle)
    return data[:at] + bytes([codec << 1]) + data[at + 1 :]


def _made_required(data: bytes, column: str) -> bytes:
    """``data`` with ``column`` made REQUIRED: a schema element's repetition (field 3,
    an i32: 0x25 after field 1) then its name (field 4, a string: 0x18), OPTIONAL
    (zigzag 2) made REQUIRED (0).  Its chunks' definition-level histograms (two
    levels) no longer fit it."""
    needle = b"\x25\x02\x18" + bytes([len(column)]) + column.encode()
    at = data.rindex(needle)
    return data[:at] + b"\x25\x00" + data[at + 2 :]


@pytest.mark.parametrize(
    "damage, said",
    [
        (lambda data: _with_codec(data, "status", 9), "unknown compression codec (9)"),
        (lambda data: _made_required(data, "status"), "level histograms of the wrong length"),
    ],
    ids=["codec 9", "a column made required"],
)
def test_what_pyarrow_aborts_on_is_one_line(
    dataset: tuple[Path, Path], tmp_path: Path, damage: Callable[[bytes], bytes], said: str
) -> None:
    bad = tmp_path / "ds"
    shutil.copytree(dataset[1], bad)
    row = sorted(bad.glob("bags/*.parquet"))[0]
    row.write_bytes(damage(row.read_bytes()))
    with pytest.raises(footer.BadFooter, match=re.escape(said)):
        footer.check(_footer(row.read_bytes()))
    line = _report_fails(bad, tmp_path)
    assert line.startswith(f"{row}: ") and said in line, line


@pytest.mark.parametrize(
    "cut", [1, 2, 7, 100], ids=["last byte", "last 2 bytes", "last 7", "last 100"]
)
def test_a_footer_cut_short_is_a_bad_footer(dataset: tuple[Path, Path], cut: int) -> None:
    row = sorted(dataset[1].glob("bags/*.parquet"))[0]
    with pytest.raises(footer.BadFooter):
        footer.check(_footer(row.read_bytes())[:-cut])


def test_nesting_past_the_bound_is_a_bad_footer() -> None:
    # a struct field (0x1c: field 1, a struct) in each struct, deeper than any footer
    with pytest.raises(footer.BadFooter, match="nests too deep"):
        footer.check(b"\x1c" * (footer.MAX_DEPTH + 2))


def test_a_footer_too_large_to_walk_is_refused_not_given_unwalked() -> None:
    size = footer.MAX_FOOTER + 100
    tail = (footer.MAX_FOOTER + 1).to_bytes(4, "little") + footer.MAGIC
    with pytest.raises(footer.BadFooter, match="over 16 MB"):
        footer.footer_length(size, tail)
    # one longer than the file is no footer: pyarrow says so itself
    assert footer.footer_length(100, (89).to_bytes(4, "little") + footer.MAGIC) is None
    assert footer.footer_length(100, (88).to_bytes(4, "little") + footer.MAGIC) == 88
