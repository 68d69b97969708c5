"""Pages in a real headless browser: Debian's chromium driven by playwright (no
downloaded browser), for the tests of ``report`` and ``ui``."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import pytest

CHROMIUM = "/usr/bin/chromium"


def open_page(url: str) -> tuple[Any, Any, list[str], list[str]]:
    """The page in headless Chromium: (playwright, page, console messages, requests)."""
    sync_api = pytest.importorskip("playwright.sync_api")
    if not Path(CHROMIUM).exists():
        # CI (.ci/run) installs it and sets this: there the page must be opened
        if os.environ.get("SAFETY_SUPERVISOR_REQUIRE_BROWSER") == "1":
            pytest.fail(f"SAFETY_SUPERVISOR_REQUIRE_BROWSER=1 but {CHROMIUM} is missing")
        pytest.skip("Debian's chromium is not installed")
    pw = sync_api.sync_playwright().start()
    browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
    page = browser.new_page(viewport={"width": 1300, "height": 900})
    console: list[str] = []
    requests: list[str] = []
    page.on("console", lambda m: console.append(f"{m.type}: {m.text}"))
    page.on("pageerror", lambda e: console.append(f"pageerror: {e}"))
    page.on("request", lambda r: requests.append(r.url))
    page.goto(url)
    return pw, page, console, requests


def eval_all(page: Any, selector: str, fn: str) -> Any:
    """``fn`` (JavaScript, a function of an array of elements) applied to the page's
    matches of ``selector``, queried and read in one task of the page.

    A live page redraws as events arrive; playwright's ``eval_on_selector_all`` queries
    and then evaluates in a second round trip, so it can be handed an element a redraw
    has already detached (``closest('tr')`` is then null).
    """
    query = f"Array.from(document.querySelectorAll({json.dumps(selector)}))"
    return page.evaluate(f"() => ({fn})({query})")
