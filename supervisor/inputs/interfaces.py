"""Services and actions as topics: ROS 2 publishes a service's calls on
``<service>/_service_event`` (service introspection, when the server or client
enables it) and an action's goal states on ``<action>/_action/status``
(docs/reference/config.md, "Services and actions")."""

from __future__ import annotations

from monitors.errors import UserError

# service_msgs/msg/ServiceEventInfo.event_type: both sides of a call publish
# events when both enable introspection; a variable takes either side's.
SERVICE_CALLS: dict[str, frozenset[int]] = {
    "request": frozenset({0, 1}),  # REQUEST_SENT (client), REQUEST_RECEIVED (server)
    "response": frozenset({2, 3}),  # RESPONSE_SENT (server), RESPONSE_RECEIVED (client)
}
# action_msgs/msg/GoalStatus.status
GOAL_STATUS: dict[str, int] = {
    "accepted": 1,
    "executing": 2,
    "canceling": 3,
    "succeeded": 4,
    "canceled": 5,
    "aborted": 6,
}
ACTION_STATUS_MSG = "action_msgs/msg/GoalStatusArray"


def service_topic(service: str) -> str:
    return service.rstrip("/") + "/_service_event"


def service_event_type(srv: str) -> str:
    """'std_srvs/srv/Trigger' -> 'std_srvs/srv/Trigger_Event', the events' message type."""
    parts = [p for p in srv.replace("::", "/").split("/") if p]
    if len(parts) == 2:
        parts = [parts[0], "srv", parts[1]]
    if len(parts) != 3 or parts[1] != "srv":
        raise UserError(f"'{srv}' is not a ROS 2 service type", hint="write it as package/srv/Name")
    return f"{parts[0]}/srv/{parts[2]}_Event"


def action_status_topic(action: str) -> str:
    return action.rstrip("/") + "/_action/status"


def goal_statuses(value: object) -> tuple[str, ...]:
    """``status:`` as a tuple of state names (one name or a list of them)."""
    names = [value] if isinstance(value, str) else value
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise UserError("status must be a goal state or a list of them")
    for n in names:
        if n not in GOAL_STATUS:
            raise UserError(f"unknown goal state '{n}'", hint="one of: " + ", ".join(GOAL_STATUS))
    return tuple(dict.fromkeys(names))
