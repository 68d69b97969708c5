"""Benches running at once on one host (the suite's xdist workers, two engineers)
never share a ROS domain: each one's publishers would count in the other's."""

from __future__ import annotations

import subprocess
import sys

import pytest

from supervisor.tools.bench import session
from supervisor.tools.bench.errors import BenchError
from supervisor.tools.bench.session import Session, claim_domain

# Ids of this test's own: the suite's benches hold the real range meanwhile.
IDS = (201, 206)
ALL = range(IDS[0], IDS[1] + 1)

HOLD = f"""
import sys
from supervisor.tools.bench import session
session.DOMAIN_IDS = {IDS}
held = [session.claim_domain() for _ in range(int(sys.argv[1]))]
print(" ".join(str(d) for d, _ in held), flush=True)
sys.stdin.read()  # hold the claims until the test closes stdin
"""


def test_a_session_takes_the_one_domain_another_process_leaves_free(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(session, "DOMAIN_IDS", IDS)
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(len(ALL) - 1)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None
        held = {int(d) for d in holder.stdout.readline().split()}
        assert len(held) == len(ALL) - 1
        (free,) = set(ALL) - held
        s = Session(None)
        try:
            assert s.domain_id == free
            with pytest.raises(BenchError, match=r"every ROS_DOMAIN_ID of 201\.\.206 is held"):
                claim_domain()
        finally:
            s.close()
        d, claim = claim_domain()  # closed: free again
        claim.close()
        assert d == free
    finally:
        holder.kill()
        holder.wait()


def test_a_given_domain_is_used_as_given() -> None:
    s = Session(7)
    try:
        assert s.domain_id == 7 and s.env["ROS_DOMAIN_ID"] == "7"
    finally:
        s.close()
