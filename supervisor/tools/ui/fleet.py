"""The fleet view: several supervisors (ROS namespaces, DDS domains) in one UI.

The fleet file (``ui --fleet FILE``) lists robots; supervisors found on the
watched domains' graphs join them.  Each supervisor has a :class:`Hub` of its own
(its page and stream carry only its data) and one row on the fleet page; a robot
whose status stops is shown as lost, never removed.  No rclpy here (the ROS side
is :class:`.node.FleetNode`).  docs/reference/commands.md, ``ui``.
"""

from __future__ import annotations

import os
import queue
import re
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from monitors.errors import UserError
from supervisor.config.fields import check_keys, error_at
from supervisor.config.yamlload import LineDict, LineList, load_yaml
from supervisor.names import STATUS_TOPIC, VIOLATIONS_TOPIC, client_control_socket
from supervisor.tools.ui.hub import Hub, utc_now
from supervisor.tools.ui.streams import Streams

NAME_RE = re.compile(r"[A-Za-z0-9_.-]{1,64}")  # also the robot's path: /robot/<name>
NS_RE = re.compile(r"/|(/[A-Za-z_][A-Za-z0-9_]*)+")
MAX_DOMAIN = 232  # the largest ROS_DOMAIN_ID (docs.ros.org, "The ROS_DOMAIN_ID")
LOST_PERIODS = 3  # status periods without a document: lost
LOST_DEFAULT_S = 3.0  # until a document announced the period, or two gave it
LOST_MIN_S = 1.0  # a short ros.status_ms must not make a busy machine flap
STATUS_SUFFIX = STATUS_TOPIC  # "/safety_supervisor/status" ends every daemon's status topic


@dataclass(frozen=True)
class RobotSpec:
    """One robot of the fleet file."""

    name: str
    namespace: str
    domain: int
    line: int = 0
    socket: str | None = None  # its control socket, if on this machine (``socket:``)


def default_domain(env: dict[str, str] | None = None) -> int:
    """The environment's ROS_DOMAIN_ID, as the daemon takes it (0 if unset)."""
    text = (env if env is not None else os.environ).get("ROS_DOMAIN_ID", "").strip()
    try:
        return int(text) if text else 0
    except ValueError:
        return 0


def _namespace(value: Any, where: LineDict) -> str:
    # as the daemon's ros.namespace: relative means under /
    ns = "/" + value.strip("/") if isinstance(value, str) else None
    if ns is None or not NS_RE.fullmatch(ns):
        raise error_at(
            f"'namespace' must be a ROS namespace (e.g. /robot1), not {value!r}",
            where,
            "namespace",
        )
    return ns


def load_fleet(path: Path, env: dict[str, str] | None = None) -> list[RobotSpec]:
    """The robots of a fleet file: a YAML list of ``{name, namespace, domain,
    socket}``; every mistake a one-line UserError at its FILE:LINE.  ``socket``
    (relative: to the file's folder) is where that robot's resets go; without it,
    where ``reset`` looks for a supervisor of the robot's domain on this machine."""
    doc = load_yaml(path)
    if not isinstance(doc, LineList) or not doc:
        raise UserError(
            "the fleet file must be a non-empty list of robots",
            file=str(path),
            line=getattr(doc, "line", None) or 1,
            hint="- {name: robot1, namespace: /robot1, domain: 0}",
        )
    robots: list[RobotSpec] = []
    seen_names: dict[str, int] = {}
    seen_topics: dict[tuple[int, str], str] = {}
    for i, item in enumerate(doc):
        if not isinstance(item, LineDict):
            raise UserError(
                "each robot must be a mapping {name, namespace, domain}",
                file=str(path),
                line=doc.item_line(i),
            )
        check_keys(item, {"name", "namespace", "domain", "socket"}, "a robot")
        name = item.get("name")
        if name is None:
            raise error_at("a robot needs a 'name'", item)
        if not isinstance(name, str) or not NAME_RE.fullmatch(name):
            raise error_at(
                f"'name' must be letters, digits, '_', '.' or '-' (at most 64), not {name!r}",
                item,
                "name",
            )
        if name in seen_names:
            raise error_at(
                f"robot '{name}' is listed twice (first at line {seen_names[name]})", item, "name"
            )
        seen_names[name] = item.key_line("name")
        namespace = _namespace(item.get("namespace", "/"), item)
        domain = item.get("domain", default_domain(env))
        if isinstance(domain, bool) or not isinstance(domain, int):
            raise error_at(f"'domain' must be a whole number, not {domain!r}", item, "domain")
        if not 0 <= domain <= MAX_DOMAIN:
            raise error_at(f"'domain' must be 0 to {MAX_DOMAIN}, not {domain}", item, "domain")
        key = (domain, namespace)
        if key in seen_topics:
            raise error_at(
                f"robot '{name}' has the namespace and domain of '{seen_topics[key]}'",
                item,
                "namespace" if "namespace" in item else None,
            )
        seen_topics[key] = name
        sock = item.get("socket")
        if sock is not None and (not isinstance(sock, str) or not sock or "\0" in sock):
            raise error_at(f"'socket' must be a path, not {sock!r}", item, "socket")
        if sock is None:
            sock = client_control_socket({**(env if env is not None else os.environ),
                                          "ROS_DOMAIN_ID": str(domain)})  # fmt: skip
        else:
            sock = str(path.parent / sock)
        robots.append(RobotSpec(name, namespace, domain, item.line, sock))
    return robots


def status_topic(namespace: str) -> str:
    return namespace.rstrip("/") + STATUS_TOPIC


def violations_topic(namespace: str) -> str:
    return namespace.rstrip("/") + VIOLATIONS_TOPIC


def namespace_of(topic: str) -> str | None:
    """The daemon's namespace from its status topic; None for another topic."""
    if topic != STATUS_SUFFIX and not topic.endswith(STATUS_SUFFIX):
        return None
    return topic[: -len(STATUS_SUFFIX)] or "/"


def _utc_seconds(ts: Any) -> float | None:
    try:
        return datetime.strptime(str(ts), "%Y-%m-%dT%H:%M:%S.%fZ").timestamp()
    except ValueError:
        return None


def local_reset_availability(
    doc: dict[str, Any] | None,
    socket_path: str | None,
    token: bytes | None,
    check: Callable[[str | None, bytes | None], dict[str, Any]],
) -> dict[str, Any]:
    """Resets for a supervisor of the fleet: through the socket the fleet file gives
    it (``socket_path``; None for a discovered one), and only while its status says
    it runs on this machine: a robot elsewhere can have a socket at the same path
    (the unit's /run/safety-supervisor/control.sock) that is not its own.  The
    document can only take resets away, never say where they go."""
    if socket_path is None:
        return {"available": False, "why": "not in the fleet file: no control socket of its own"}
    if not isinstance(doc, dict):
        return {"available": False, "why": "no status document yet"}
    host = str(doc.get("supervisor") or "").partition(":")[0]
    if host != socket.gethostname():
        return {"available": False, "why": f"the supervisor runs on {host or '?'}, not here"}
    return check(socket_path, token)


@dataclass
class Robot:
    """One supervisor of the fleet: where its status comes from, its hub, its row."""

    id: str
    name: str
    domain: int
    namespace: str
    configured: bool
    hub: Hub
    socket: str | None = None  # where its resets go: the fleet file's, never a document's
    status_at: float | None = None  # monotonic time of the last document
    seen_utc: str | None = None  # wall time of the last document
    period_s: float | None = None  # between the last two documents (the daemon's clock)
    last_now: float | None = None
    lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def topic(self) -> str:
        return status_topic(self.namespace)

    def lost_after_s(self) -> float:
        if self.period_s is None:
            return LOST_DEFAULT_S
        return max(LOST_PERIODS * self.period_s, LOST_MIN_S)


class Fleet:
    """The fleet's robots and the fleet page's browsers; thread-safe."""

    def __init__(
        self,
        robots: list[RobotSpec],
        reset_state: Callable[[dict[str, Any] | None, str | None], dict[str, Any]],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """``reset_state(doc, socket)``: whether a robot's resets can reach its socket."""
        self._lock = threading.Lock()
        self._clock = clock
        self._reset_state = reset_state
        self._robots: dict[str, Robot] = {}
        self._by_topic: dict[tuple[int, str], Robot] = {}
        self._streams = Streams()
        self.configured = len(robots)
        for spec in robots:
            self._add(spec.name, spec.name, spec.domain, spec.namespace, True, spec.socket)

    # ------------------------------------------------------------ robots

    def _add(
        self,
        rid: str,
        name: str,
        domain: int,
        namespace: str,
        configured: bool,
        socket_path: str | None = None,
    ) -> Robot:
        def reset_state(doc: dict[str, Any] | None) -> dict[str, Any]:
            return self._reset_state(doc, socket_path)

        robot = Robot(
            rid, name, domain, namespace, configured, Hub(reset_state, self._clock), socket_path
        )
        robot.hub.label = f"robot {name}: "
        self._robots[rid] = robot
        self._by_topic[(domain, namespace)] = robot
        return robot

    def domains(self) -> list[int]:
        with self._lock:
            return sorted({r.domain for r in self._robots.values()})

    def robots(self) -> list[Robot]:
        with self._lock:
            return list(self._robots.values())

    def robot(self, rid: str) -> Robot | None:
        with self._lock:
            return self._robots.get(rid)

    def first(self) -> Robot:
        with self._lock:
            return next(iter(self._robots.values()))

    def watch(self, domain: int, namespace: str) -> tuple[Robot, bool]:
        """The robot of a status topic found on ``domain``'s graph: a configured
        one, or a new row (True) named after its namespace."""
        with self._lock:
            robot = self._by_topic.get((domain, namespace))
            if robot is not None:
                return robot, False
            base = f"d{domain}-" + (namespace.strip("/").replace("/", "-") or "root")
            rid, n = base, 1
            while rid in self._robots:  # a configured name that looks like ours
                n += 1
                rid = f"{base}-{n}"
            robot = self._add(rid, namespace, domain, namespace, configured=False)
        self._broadcast({"type": "robot", "robot": self.row(robot)})
        return robot, True

    # ------------------------------------------------------------ inputs

    def on_status(self, robot: Robot, doc: dict[str, Any]) -> None:
        """A document already checked (``receive_status`` checks one off the topic)."""
        robot.hub.on_status(doc)
        self._seen(robot, doc)
        self._broadcast({"type": "robot", "robot": self.row(robot)})

    def _seen(self, robot: Robot, doc: dict[str, Any]) -> None:
        now = _utc_seconds(doc.get("now"))
        announced = doc.get("status_period_s")  # checked: a number or None (schema.py)
        with robot.lock:
            if announced:
                robot.period_s = announced
            elif now is not None and robot.last_now is not None and now > robot.last_now:
                robot.period_s = now - robot.last_now
            robot.last_now = now
            robot.status_at = self._clock()
            robot.seen_utc = utc_now()

    def on_violation(self, robot: Robot, record: dict[str, Any]) -> None:
        robot.hub.on_violation(record)

    def receive_status(self, robot: Robot, data: bytes | str, publisher: Callable[[], str]) -> None:
        """A status document off the topic: checked by the robot's hub (schema.py);
        a bad one is counted on its row, never shown."""
        if not robot.hub.receive_status(data, publisher):
            self._broadcast({"type": "robot", "robot": self.row(robot)})
            return
        self._seen(robot, robot.hub.status or {})
        self._broadcast({"type": "robot", "robot": self.row(robot)})

    def on_publishers(self, robot: Robot, names: list[str]) -> None:
        if names != robot.hub.publishers:
            robot.hub.on_publishers(names)
            self._broadcast({"type": "robot", "robot": self.row(robot)})

    # ------------------------------------------------------------ outputs

    def row(self, robot: Robot) -> dict[str, Any]:
        """The fleet page's row of one supervisor; ``lost`` as of now (the page
        keeps ageing it between updates)."""
        doc = robot.hub.status or {}
        with robot.lock:
            age = None if robot.status_at is None else self._clock() - robot.status_at
            lost_after = robot.lost_after_s()
            seen = robot.seen_utc
        reqs = doc.get("requirements") or []
        open_ids = [
            str(r.get("id")) for r in reqs if isinstance(r, dict) and r.get("state") != "holding"
        ]
        supervisor = str(doc.get("supervisor") or "")
        return {
            "id": robot.id,
            "name": robot.name,
            "domain": robot.domain,
            "namespace": robot.namespace,
            "topic": robot.topic,
            "configured": robot.configured,
            "supervisor": supervisor,
            "host": supervisor.partition(":")[0] if supervisor else "",
            "component": doc.get("component"),
            "config_sha256": doc.get("config_sha256"),
            "uptime_s": doc.get("uptime_s"),
            "tick_rate_hz": doc.get("tick_rate_hz"),
            "receive_rate_hz": doc.get("receive_rate_hz"),
            "lost": doc.get("lost"),
            "open": open_ids,
            "age_s": age,
            "last_seen": seen,
            "lost_after_s": lost_after,
            "state": "waiting" if age is None else ("lost" if age > lost_after else "live"),
            "invalid": robot.hub.invalid["count"],
            "publishers": len(robot.hub.publishers),
        }

    def snapshot(self) -> dict[str, Any]:
        return {"type": "snapshot", "robots": [self.row(r) for r in self.robots()]}

    def subscribe(self) -> queue.Queue[str | None]:
        return self._streams.subscribe(self.snapshot)

    def unsubscribe(self, q: queue.Queue[str | None]) -> None:
        self._streams.unsubscribe(q)

    def close(self) -> None:
        with self._lock:
            hubs = [r.hub for r in self._robots.values()]
        self._streams.close()
        for hub in hubs:
            hub.close()

    def _broadcast(self, message: dict[str, Any]) -> None:
        self._streams.broadcast(message)
