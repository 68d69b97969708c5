"""The operator's page (supervisor/tools/ui/page.py) in headless Chromium: what an
operator sees during an incident.

The real server and hub in this process, fed status documents and violation records
as the daemon publishes them (tests/system/test_ui.py has the same over real DDS);
each behaviour is checked in the rendered DOM, with no console error and no request
leaving the page's origin.
"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
from browser import open_page

from supervisor.tools.ui.hub import Hub
from supervisor.tools.ui.server import UiServer, reset_availability
from tests.system.test_ui import TOKEN, FakeControl, status_doc, wait_js

RED_BADGE = "rgb(255, 205, 210)"  # .state-violated's background
GREEN_BADGE = "rgb(200, 230, 201)"  # .state-holding's


def iso(t: datetime) -> str:
    return t.strftime("%Y-%m-%dT%H:%M:%S.%fZ")


@contextmanager
def page_of(
    tmp_path: Path, doc: dict[str, Any], **server: Any
) -> Iterator[tuple[Hub, Any, list[str], list[str], str]]:
    """The UI's server with ``doc`` shown, and its page in Chromium: (hub, page,
    console, requests, socket path)."""
    control = FakeControl(tmp_path / "ctl.sock")
    hub = Hub(lambda _doc: reset_availability(str(control.path), TOKEN))
    ui = UiServer(("127.0.0.1", 0), hub, TOKEN, lambda: str(control.path), **server)
    threading.Thread(target=ui.serve_forever, daemon=True).start()
    hub.on_status(doc)
    pw = None
    try:
        pw, page, console, requests = open_page(ui.url())
        page.wait_for_selector("tr.req, tr.input")
        yield hub, page, console, requests, str(control.path)
        assert console == [], console
        assert all(u.startswith(ui.url()) for u in requests), requests
    finally:
        if pw is not None:
            pw.stop()
        ui.stop()
        control.close()


@contextmanager
def feeding(hub: Hub, sock: str, reqs: list[dict[str, Any]]) -> Iterator[None]:
    """A status document every 0.3 s, as the daemon publishes them, so the page stays
    live; ``reqs`` is read at each (the test changes it)."""
    stop = threading.Event()

    def run() -> None:
        while not stop.wait(0.3):
            hub.on_status(status_doc(sock, now=iso(datetime.now(UTC)), requirements=list(reqs)))

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


def rows(page: Any) -> list[tuple[str, str, str]]:
    """The requirements as listed: (id, state shown, state's background colour)."""
    found = page.eval_on_selector_all(
        "tr.req",
        "rs => rs.map(r => [r.dataset.requirement, r.dataset.state, "
        "getComputedStyle(r.querySelector('.state')).backgroundColor])",
    )
    return [tuple(r) for r in found]


def badge(page: Any, rid: str) -> str:
    return page.inner_text(f"tr.req[data-requirement='{rid}'] .state").strip()


def requirement(rid: str, **over: Any) -> dict[str, Any]:
    r = {"id": rid, "text": f"R shall always satisfy {rid}", "formula": f"(H {rid})",
         "state": "holding", "violations": 0, "last_violation": None, "last_tick": None,
         "actions": []}  # fmt: skip
    r.update(over)
    return r


# ---------------------------------------------------------------- violations held


@pytest.mark.slow
def test_a_violation_reset_at_once_stays_shown_and_comes_first(tmp_path: Path) -> None:
    """A policy resets a requirement within milliseconds: the page still shows it
    violated, in red, "violated N s ago" counting up, for ``--violated-for`` after
    each violation, and lists the most recently violated first."""
    hold = 3.0
    t0 = datetime.now(UTC)
    reqs = [requirement("a"), requirement("b"), requirement("c")]
    sock = str(tmp_path / "ctl.sock")
    doc = status_doc(sock, now=iso(t0), requirements=reqs, events=[])
    with page_of(tmp_path, doc, violated_for_s=hold) as (hub, page, _console, _req, sock):
        assert rows(page) == [(r, "holding", GREEN_BADGE) for r in "abc"]

        # c is violated and reset before the next document: the topic's record, then
        # a document that says holding again
        hub.on_violation({"event": "violation", "requirement": "c", "tick": 7,
                          "ts": iso(datetime.now(UTC)), "inputs": {"x": 1}})  # fmt: skip
        seen_c = time.monotonic()
        reqs[2] = requirement("c", violations=1, last_violation=iso(datetime.now(UTC)))
        with feeding(hub, sock, reqs):
            wait_js(page, "document.querySelector('tr.req').dataset.requirement === 'c'")
            held(page, hub, sock, reqs, seen_c, hold)


def held(
    page: Any, hub: Hub, sock: str, reqs: list[dict[str, Any]], seen_c: float, hold: float
) -> None:
    """c violated and reset at ``seen_c``; then b."""
    # the next document says c holds (before it, the topic's record said violated)
    wait_js(page, "document.querySelector(\"tr.req[data-requirement='c']\")"
            ".dataset.daemonState === 'holding'")  # fmt: skip
    assert rows(page) == [
        ("c", "violated", RED_BADGE),
        ("a", "holding", GREEN_BADGE),
        ("b", "holding", GREEN_BADGE),
    ]
    assert re.fullmatch(r"violated [0-2] s ago", badge(page, "c")), badge(page, "c")

    # b is violated later, seen in a document only (no violations topic): first
    t_b = datetime.now(UTC)
    reqs[1] = requirement("b", violations=1, last_violation=iso(t_b))
    hub.on_status(status_doc(sock, now=iso(datetime.now(UTC)), requirements=reqs))
    wait_js(page, "document.querySelector('tr.req').dataset.requirement === 'b'")
    assert [r[:2] for r in rows(page)] == [
        ("b", "violated"),
        ("c", "violated"),
        ("a", "holding"),
    ]
    # "N s ago" counts up
    wait_js(page, "document.querySelector(\"tr.req[data-requirement='c'] .state\")"
            ".textContent.includes('violated 2 s ago')", 5)  # fmt: skip

    # past the hold, c shows the state the documents give (holding) again; the
    # order stays by recency
    wait_js(page, "document.querySelector(\"tr.req[data-requirement='c']\")"
            ".dataset.state === 'holding'", 5)  # fmt: skip
    assert time.monotonic() - seen_c >= hold - 0.3
    assert rows(page)[1] == ("c", "holding", GREEN_BADGE)
    assert [r[0] for r in rows(page)] == ["b", "c", "a"]


@pytest.mark.slow
def test_a_latched_requirement_keeps_its_state_and_says_when_it_was_violated(
    tmp_path: Path,
) -> None:
    now = datetime.now(UTC)
    reqs = [requirement("a"),
            requirement("l", state="latched", violations=1, last_violation=iso(now))]  # fmt: skip
    doc = status_doc(str(tmp_path / "ctl.sock"), now=iso(now), requirements=reqs, events=[])
    with page_of(tmp_path, doc) as (_hub, page, _console, _requests, _sock):
        assert rows(page)[0][:2] == ("l", "latched")
        text = page.inner_text("tr.req[data-requirement='l'] td:nth-child(2)")
        assert re.search(r"violated [0-2] s ago", text), text


def test_the_hold_is_an_option_of_ui_and_bad_values_are_one_line() -> None:
    from inproc import cli_main

    for bad in ("-1", "nan", "inf", "soon", "1e9"):
        r = cli_main("ui", "--violated-for", bad, "--bind", "127.0.0.1:0")
        code, out, err = r.returncode, r.stdout, r.stderr
        assert code == 2 and out == "", (bad, code, out, err)
        assert err.strip().splitlines()[-1].startswith("safety-supervisor ui: error: "), err
        assert "Traceback" not in err and f"'{bad}'" in err, err
