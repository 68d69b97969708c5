"""The installed dependencies are the ones the code is written for.

ROS's ``ros-rosidl-parser`` wheel requires ``lark-parser`` 0.12, the old name of
the project whose ``lark`` 1.x the grammars need.  Both unpack into the same
``lark/`` folder, so what imports depends on which pip unpacked last.
"""

from __future__ import annotations

import base64
import hashlib
from importlib import metadata

import lark
import pytest

from monitors.errors import UserError
from monitors.ir import formula


def _version(text: str) -> tuple[int, ...]:
    return tuple(int(p) for p in text.split(".")[:2])


def test_the_importable_lark_is_lark_1() -> None:
    assert _version(lark.__version__) >= formula.LARK_NEEDED, lark.__version__
    assert metadata.version("lark") == lark.__version__


def test_no_file_of_lark_was_overwritten_by_lark_parser() -> None:
    """Every file lark's RECORD lists is on disk as lark wrote it."""
    changed = []
    for f in metadata.distribution("lark").files or []:
        if f.hash is None or f.suffix != ".py":
            continue
        data = f.locate().read_bytes()
        digest = base64.urlsafe_b64encode(hashlib.new(f.hash.mode, data).digest()).rstrip(b"=")
        if digest.decode() != f.hash.value:
            changed.append(str(f))
    assert changed == [], f"written over by another package: {changed}"


def test_an_old_lark_is_refused_with_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(lark, "__version__", "0.12.0")
    formula._parser.cache_clear()
    try:
        with pytest.raises(UserError) as err:
            formula.parse_formula("H (x > 1)")
    finally:
        formula._parser.cache_clear()
    text = str(err.value)
    assert "\n" not in text
    assert "lark 0.12.0 is installed" in text and "lark-parser" in text
    assert "pip install --force-reinstall --no-deps 'lark>=1.1'" in text
