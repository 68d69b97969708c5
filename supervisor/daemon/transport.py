"""The daemon's DDS transport: UDP only, unless the operator chose otherwise.

Fast DDS 2.14 (Jazzy's) can crash (SIGSEGV) while deleting a participant that has
shared-memory ports, when a peer that was sending to it died abruptly
(docs/reference/faults.md, "Stop").  A daemon without shared-memory ports has nothing
to crash on, and robot nodes with the default transports (shared memory and UDP)
reach it over UDP on the loopback.  The shipped unit already sets
``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``; the daemon chooses the same itself when the
environment says nothing, for its own process only (its children, the mitigation
commands, inherit the operator's environment unchanged).

``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` needs more: rmw_fastrtps 8.4 then
configures the participant's transports itself (shared memory and UDP, whatever
``FASTDDS_BUILTIN_TRANSPORTS`` says, the unit's ``UDPv4`` too), so the daemon asks rmw
for the system default range and gives Fast DDS what rmw would have given, less the
shared memory, in an XML profile: discovery over unicast only, with 127.0.0.1 as the
initial peer.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator, Mapping, MutableMapping
from pathlib import Path

from supervisor.daemon.core import warn

# Where the daemon leaves Fast DDS alone: another RMW, or the operator's own choice
# of transports, XML profiles, discovery server or static peers.
FASTDDS_RMWS = ("", "rmw_fastrtps_cpp", "rmw_fastrtps_dynamic_cpp")
OPERATOR_CHOICES = (
    "FASTRTPS_DEFAULT_PROFILES_FILE",
    "FASTDDS_DEFAULT_PROFILES_FILE",
    "ROS_DISCOVERY_SERVER",
    "ROS_STATIC_PEERS",
    "ROS_LOCALHOST_ONLY",
)
# Fast DDS also loads this file from the working directory when it exists.
DEFAULT_PROFILES = "DEFAULT_FASTRTPS_PROFILES.xml"

# rmw_fastrtps 8.4's LOCALHOST participant (rmw_fastrtps_shared_cpp/src/participant.cpp)
# without its shared-memory transport: no multicast discovery locator, 127.0.0.1 as
# the initial peer, UDPv4 with up to 32 participants per host.
LOCALHOST_UDP_PROFILE = """\
<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <transport_descriptors>
    <transport_descriptor>
      <transport_id>safety_supervisor_udp</transport_id>
      <type>UDPv4</type>
      <maxInitialPeersRange>32</maxInitialPeersRange>
    </transport_descriptor>
  </transport_descriptors>
  <participant profile_name="safety_supervisor" is_default_profile="true">
    <rtps>
      <builtin>
        <metatrafficUnicastLocatorList><locator><udpv4/></locator></metatrafficUnicastLocatorList>
        <initialPeersList>
          <locator><udpv4><address>127.0.0.1</address></udpv4></locator>
        </initialPeersList>
      </builtin>
      <userTransports><transport_id>safety_supervisor_udp</transport_id></userTransports>
      <useBuiltinTransports>false</useBuiltinTransports>
    </rtps>
  </participant>
</profiles>
"""


def udp_settings(environ: Mapping[str, str], cwd: Path) -> dict[str, str] | None:
    """The variables that make the daemon's participant UDP only ("PROFILE" stands
    for the XML profile's path), or None where the daemon leaves Fast DDS alone."""
    if environ.get("RMW_IMPLEMENTATION", "") not in FASTDDS_RMWS:
        return None
    transports = environ.get("FASTDDS_BUILTIN_TRANSPORTS", "")
    if transports not in ("", "UDPv4"):  # e.g. DEFAULT: shared memory wanted
        return None
    if any(environ.get(k) for k in OPERATOR_CHOICES) or (cwd / DEFAULT_PROFILES).exists():
        return None
    if environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE") == "LOCALHOST":
        return {
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT",
            "FASTRTPS_DEFAULT_PROFILES_FILE": "PROFILE",
        }
    if transports:  # UDPv4 already, as the unit sets
        return None
    return {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}


def _cwd() -> Path | None:
    try:
        return Path.cwd()
    except OSError:  # removed under the daemon: no profile file there either
        return None


@contextlib.contextmanager
def udp_only(environ: MutableMapping[str, str] | None = None) -> Iterator[dict[str, str] | None]:
    """Within: the settings of :func:`udp_settings` in ``environ`` (os.environ), for
    rclpy's init and the first node (the participant reads them then); restored on
    exit, so children get the operator's environment.  Yields what was set."""
    env = os.environ if environ is None else environ
    cwd = _cwd()
    settings = udp_settings(env, cwd) if cwd is not None else None
    if settings is None:
        yield None
        return
    saved = {k: env.get(k) for k in settings}
    with contextlib.ExitStack() as stack:
        if "FASTRTPS_DEFAULT_PROFILES_FILE" in settings:
            try:
                tmp = stack.enter_context(
                    tempfile.TemporaryDirectory(prefix="safety-supervisor-dds-")
                )
                profile = Path(tmp) / "localhost-udp.xml"
                profile.write_text(LOCALHOST_UDP_PROFILE)
            except OSError as e:  # no writable temporary directory: rmw's choice, as before
                warn(f"DDS transports left to rmw_fastrtps (shared memory included): {e}")
                yield None
                return
            settings["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(profile)
        try:
            env.update(settings)
            yield settings
        finally:
            for k, v in saved.items():
                if v is None:
                    env.pop(k, None)
                else:
                    env[k] = v
