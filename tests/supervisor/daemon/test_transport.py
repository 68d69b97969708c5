"""The daemon's DDS transport is UDP only unless the operator chose one: no Fast DDS
shared-memory ports to crash on at stop (docs/reference/faults.md, "Stop";
supervisor/daemon/transport.py).  Robot nodes with the default transports (shared
memory and UDP, as this test process's) still reach it."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

from supervisor.daemon.transport import DEFAULT_PROFILES, udp_only, udp_settings

LOCALHOST = {"ROS_DOMAIN_ID": "7", "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}


def test_default_range_gets_builtin_udp(tmp_path: Path) -> None:
    assert udp_settings({"ROS_DOMAIN_ID": "7"}, tmp_path) == {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}
    subnet = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}
    assert udp_settings(subnet, tmp_path) == {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}


def test_localhost_gets_a_udp_profile_in_place_of_rmws_shared_memory(tmp_path: Path) -> None:
    # rmw_fastrtps configures LOCALHOST's transports itself, whatever the variables say
    assert udp_settings(LOCALHOST, tmp_path) == {
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT",
        "FASTRTPS_DEFAULT_PROFILES_FILE": "PROFILE",
    }


def test_the_units_udp_choice_is_honoured_under_localhost(tmp_path: Path) -> None:
    # the unit's FASTDDS_BUILTIN_TRANSPORTS=UDPv4, which rmw ignores under LOCALHOST
    unit = {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}
    assert udp_settings(unit, tmp_path) is None  # Fast DDS applies it itself
    assert udp_settings({**LOCALHOST, **unit}, tmp_path) == {
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT",
        "FASTRTPS_DEFAULT_PROFILES_FILE": "PROFILE",
    }


@pytest.mark.parametrize(
    "choice",
    [
        {"FASTDDS_BUILTIN_TRANSPORTS": "DEFAULT"},
        {"FASTDDS_BUILTIN_TRANSPORTS": "SHM"},
        {"FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/fastdds.xml"},
        {"FASTDDS_DEFAULT_PROFILES_FILE": "/etc/fastdds.xml"},
        {"ROS_DISCOVERY_SERVER": "127.0.0.1:11811"},
        {"ROS_STATIC_PEERS": "192.168.0.2"},
        {"ROS_LOCALHOST_ONLY": "1"},
        {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"},
    ],
)
def test_the_operators_choice_wins(tmp_path: Path, choice: dict[str, str]) -> None:
    assert udp_settings({**LOCALHOST, **choice}, tmp_path) is None
    assert udp_settings(choice, tmp_path) is None


def test_a_profile_in_the_working_directory_wins(tmp_path: Path) -> None:
    (tmp_path / DEFAULT_PROFILES).write_text("<profiles/>")
    assert udp_settings(LOCALHOST, tmp_path) is None


def test_udp_only_restores_the_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    env = dict(LOCALHOST)
    with udp_only(env) as settings:
        assert settings is not None
        profile = Path(env["FASTRTPS_DEFAULT_PROFILES_FILE"])
        assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT"
        assert "<useBuiltinTransports>false</useBuiltinTransports>" in profile.read_text()
    assert env == LOCALHOST  # the daemon's children get the operator's environment
    assert not profile.exists()


def test_no_temporary_directory_leaves_rmw_its_choice(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "missing"))
    env = dict(LOCALHOST)
    with udp_only(env) as settings:
        assert settings is None
        assert env == LOCALHOST
    warning = capsys.readouterr().err
    assert warning.startswith("safety-supervisor: WARNING: DDS transports left to rmw"), warning
    assert warning.count("\n") == 1, warning  # one line, no traceback


def _shm_ports(pid: int) -> set[str]:
    """Fast DDS's shared-memory ports the process has mapped."""
    maps = Path(f"/proc/{pid}/maps").read_text().splitlines()
    return {line.split()[-1] for line in maps if "/dev/shm/fastrtps_port" in line}


@pytest.mark.ros
@pytest.mark.parametrize(
    "operator",
    [{}, {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}, {"FASTDDS_BUILTIN_TRANSPORTS": "DEFAULT"}],
)
def test_daemon_under_localhost_is_udp_only_and_hears_a_shared_memory_robot(
    tmp_path: Path, operator: dict[str, str]
) -> None:
    """The tests' LOCALHOST range: the daemon maps no shared-memory port, unless the
    operator asked for Fast DDS's defaults, and monitors a robot node that has both."""
    pytest.importorskip("rclpy")
    from rosutil import S0, Daemon, Robot, ros_node

    d = Daemon(tmp_path, env=operator)
    try:
        with ros_node() as node:
            d.wait_notify("READY=1", timeout=60)
            assert _shm_ports(os.getpid()), "this robot node should have shared memory"
            Robot(node).warm_up(d, S0)  # the daemon steps on what the robot published
            ports = _shm_ports(d.proc.pid)
            if operator.get("FASTDDS_BUILTIN_TRANSPORTS") == "DEFAULT":
                assert ports, "the operator's FASTDDS_BUILTIN_TRANSPORTS=DEFAULT was overridden"
            else:  # none, or the unit's UDPv4
                assert not ports, f"the daemon has shared-memory ports: {sorted(ports)}"
            d.terminate()
    finally:
        d.close()
