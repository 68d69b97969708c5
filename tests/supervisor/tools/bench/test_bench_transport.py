"""bench's echo, the floor the halt is judged against, is reached over the daemon's
transport (UDP only under the tests' LOCALHOST range), not over shared memory the
daemon does not use (supervisor/daemon/transport.py)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.ros
pytest.importorskip("rclpy")

import rosutil  # noqa: E402

from supervisor.children import ros_env  # noqa: E402

PROBE = """
import sys
from supervisor.tools.bench.helper import ros_node
with ros_node("bench_probe", as_daemon=sys.argv[1] == "daemon"):
    maps = open("/proc/self/maps").read().splitlines()
    print(len({l.split()[-1] for l in maps if "/dev/shm/fastrtps_port" in l}))
"""


@pytest.mark.parametrize(("like", "shm"), [("daemon", False), ("robot", True)])
def test_bench_node_as_daemon_maps_no_shared_memory(like: str, shm: bool) -> None:
    env = ros_env(rosutil.DOMAIN_ID)
    env.pop("FASTDDS_BUILTIN_TRANSPORTS", None)
    env.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
    assert env.get("ROS_AUTOMATIC_DISCOVERY_RANGE") == "LOCALHOST"
    out = subprocess.run(
        [sys.executable, "-c", PROBE, like],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        cwd=os.getcwd(),
        check=True,
    )
    ports = int(out.stdout.split()[-1])
    assert (ports > 0) == shm, (like, ports, out.stderr[-2000:])
