"""The daemon's ROS names and defaults, defined once.

The daemon serves and publishes under these names; the tools (``reset``, ``bench``,
``inject``, ``demo``) and the tests reach the daemon through them.  The reference
is docs/reference/ros-interfaces.md (the daemon's topics and services).
"""

from __future__ import annotations

NODE_NAME = "safety_supervisor"
VIOLATIONS_TOPIC = "/safety_supervisor/violations"  # std_msgs/String, one JSON record each
HEARTBEAT_TOPIC = "/safety_supervisor/heartbeat"  # std_msgs/UInt64, from the loop
RESET_SERVICE = "/safety_supervisor/reset"  # std_srvs/Trigger: operator reset
DIAGNOSTICS_TOPIC = "/diagnostics"  # diagnostic_msgs/DiagnosticArray (REP 107)
