"""The test run's own user cache (tests/conftest.py, ``user_cache``): replay's
monitors are built once per run, in the run's temporary directory, never in or
from the ~/.cache of whoever runs the tests."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from supervisor.cache import Cache


def test_the_run_has_one_user_cache_of_its_own(
    user_cache: Path, tmp_path_factory: pytest.TempPathFactory
) -> None:
    assert os.environ["XDG_CACHE_HOME"] == str(user_cache)
    assert user_cache.is_relative_to(tmp_path_factory.getbasetemp())
    cache = Cache.open_user()
    assert cache is not None and cache.root == user_cache / "safety-supervisor"
