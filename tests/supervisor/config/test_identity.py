"""``ConfigSource.identity``: a config's hash with the files it imports, what fleet
replay keys its dataset by (docs/reference/fleet.md)."""

from __future__ import annotations

import shutil
from pathlib import Path

from supervisor.config.load import load_config, read_config


def config_identity(path: Path) -> str:
    return load_config(path).identity


ROOT = Path(__file__).resolve().parents[3]
FRET = ("srobot-from-fret.yaml", "srobot-fret-export.json", "srobot-ogma-variables.txt")


def _fret_config(where: Path) -> Path:
    where.mkdir()
    for name in FRET:
        shutil.copy(ROOT / "config" / name, where / name)
    return where / FRET[0]


def test_an_edited_import_is_another_config_though_its_file_is_the_same(tmp_path):
    cfg = _fret_config(tmp_path / "a")
    before, file_before = config_identity(cfg), read_config(cfg).sha256
    export = cfg.with_name(FRET[1])
    export.write_text(
        export.read_text().replace("distance_to_target > 3", "distance_to_target > 4")
    )
    assert read_config(cfg).sha256 == file_before  # the config's own bytes: unchanged
    assert config_identity(cfg) != before


def test_the_same_files_elsewhere_are_the_same_config(tmp_path):
    """Keyed by the names as the config gives them, not where the tree lies: a dataset
    made from a copy of the configs resumes."""
    a, b = _fret_config(tmp_path / "a"), _fret_config(tmp_path / "b")
    assert config_identity(a) == config_identity(b)
    assert config_identity(a) != read_config(a).sha256


def test_a_config_that_imports_nothing_is_its_files_hash():
    """As the violation log's config_sha256: a dataset made before imports counted
    keeps its keys."""
    cfg = ROOT / "config" / "srobot.yaml"
    assert config_identity(cfg) == read_config(cfg).sha256
