"""What the bench publishes, read from the config, and the configs the daemon runs."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from mitigations.settings import PublishSettings
from supervisor.tools.bench.errors import BenchError

DEPTH = 1000  # every bench subscription and publisher: reliable, volatile, depth 1000

# The thesis's sRobot: a nominal state satisfying every requirement, and the
# violating state of the latency experiment (state_req103: a trained worker in
# the red zone, OpState not 3) with the step trigger turnoffUVC false.
SROBOT_NOMINAL = {"classifier": 0, "distance_to_target": 50, "OpState": 0}
SROBOT_VIOLATING = {
    "classifier": 1,
    "distance_to_target": 2,
    "OpState": 2,
    "alert": True,
    "slowdown": True,
    "halt": False,
    "turnoffUVC": False,
}
SROBOT_NOMINAL_CHECK = {"classifier": 0, "halt": False}
LATENCY_REQUIREMENT = "state_req103"
HALT_MITIGATION = "stop_robot"


class Plan:
    """What the config says the bench publishes, and the configs the daemon runs."""

    def __init__(self, config: Path) -> None:
        from monitors.errors import UserError
        from supervisor.config import load_config

        try:
            self.cfg = load_config(config)
        except UserError as e:
            raise BenchError(str(e)) from None
        self.path = config
        cfg = self.cfg
        inputs = list(cfg.inputs)
        if not inputs:
            raise BenchError(f"{config}: no input variables with topics")
        trigger = cfg.step.trigger if cfg.step.policy == "on_trigger" else None
        # The trigger is published last in each round: it ends a tick.
        inputs.sort(key=lambda v: v.name == trigger)
        self.trigger = trigger or inputs[-1].name
        self.topics = [
            {"name": v.name, "topic": v.topic, "msg": v.msg, "field": v.field} for v in inputs
        ]
        self.nominal = {v.name: _nominal(v) for v in inputs}
        self.daemon_node = cfg.ros.node_name
        self.scan: dict[str, Any] | None = None  # a LaserScan stream beside (ScanPlan)

    def latency_problem(self) -> str | None:
        """Why this config cannot run the latency experiment, or None."""
        names = {t["name"] for t in self.topics}
        missing = sorted(set(SROBOT_VIOLATING) - names)
        if missing:
            return f"the latency experiment needs the sRobot inputs (missing: {', '.join(missing)})"
        if self.trigger != "turnoffUVC":
            return "the latency experiment needs step.policy on_trigger with trigger turnoffUVC"
        if not any(r.id == LATENCY_REQUIREMENT for r in self.cfg.requirements):
            return f"the latency experiment needs requirement {LATENCY_REQUIREMENT}"
        m = self.cfg.mitigations.get(HALT_MITIGATION)
        if m is None or m.kind != "publish":
            return f"the latency experiment needs a publish mitigation '{HALT_MITIGATION}'"
        return None

    @property
    def halt(self) -> tuple[str, str]:
        s = self.cfg.mitigations[HALT_MITIGATION].settings
        assert isinstance(s, PublishSettings)  # checked by latency_problem()
        return s.topic, s.msg

    def write_config(
        self, out: Path, log: Path, *, latency: bool, durability: str | None = None
    ) -> Path:
        """A copy of the config for the daemon: inputs reliable with depth 1000 (the
        baselines' QoS), no on_stale (a stale halt would add messages nobody sent),
        the log in our temp dir, the ROS reset service on for the driver's handshake;
        for latency, state_req103 acts at every violation; ``durability``:
        logging.durability (None: the config's own)."""
        import yaml

        doc = yaml.safe_load(self.path.read_text())
        base = self.path.resolve().parent
        for key in ("requirements_from", "variables_from"):
            if isinstance(doc.get(key), str) and not os.path.isabs(doc[key]):
                doc[key] = str(base / doc[key])
        for spec in (doc.get("variables") or {}).values():
            if isinstance(spec, dict) and "topic" in spec:
                spec["qos"], spec["depth"] = "reliable", DEPTH
        doc.pop("on_stale", None)
        doc.setdefault("logging", {})["violations"] = str(log)
        if durability is not None:
            doc["logging"]["durability"] = durability
        # The driver's handshake is a call of the ROS reset service, several per
        # trial: turn the service on and lift the operator-reset rate limit
        # (docs/reference/ros-interfaces.md); the socket stays in our temp dir.
        doc["ros"] = {**(doc.get("ros") or {}), "reset_service": True}
        doc["control"] = {
            **(doc.get("control") or {}),
            "socket": str(out.parent / "control.sock"),
            "max_resets": 1_000_000_000,
        }
        if latency:
            reqs = doc.setdefault("requirements", [])
            entry = next((r for r in reqs if r.get("id") == LATENCY_REQUIREMENT), None)
            if entry is None:  # imported (requirements_from): refine it by id
                entry = {"id": LATENCY_REQUIREMENT}
                reqs.append(entry)
            entry["on_violation"] = [HALT_MITIGATION]
            entry["policy"] = {"debounce_steps": 1, "reset": "after_mitigation"}
        self._extend(doc)
        out.write_text(yaml.safe_dump(doc, sort_keys=False))
        return out

    def _extend(self, doc: dict[str, Any]) -> None:
        """What a derived plan adds to the daemon's config (ScanPlan: the scan)."""


# The LaserScan beside the sRobot stream (``bench --scan``): a 1,440-reading scan
# (a 0.25 degree lidar) at 40 Hz, some readings NaN or infinite, header.stamp set
# at each publication; the daemon reduces its ranges (REP 117) and ages its stamp.
SCAN_TOPIC = "/bench/scan"
SCAN_MSG = "sensor_msgs/msg/LaserScan"
SCAN_HZ = 40.0
SCAN_READINGS = 1440
SCAN_RANGE = (0.05, 30.0)  # range_min, range_max
SCAN_CLOSEST = 1.25  # the smallest reading within range: the obstacle the daemon sees
SCAN_REQUIREMENT = "bench_scan_clear"


def scan_ranges(n: int = SCAN_READINGS) -> list[float]:
    """``n`` readings: every 17th NaN, every 29th +inf, every 53rd below range_min,
    every 61st above range_max (none of these a reading), the rest between
    SCAN_CLOSEST and 10 m (the smallest exactly SCAN_CLOSEST)."""
    out = []
    for i in range(n):
        if i % 17 == 5:
            out.append(float("nan"))
        elif i % 29 == 7:
            out.append(float("inf"))
        elif i % 53 == 11:
            out.append(SCAN_RANGE[0] / 2)
        elif i % 61 == 13:
            out.append(SCAN_RANGE[1] * 2)
        else:
            out.append(SCAN_CLOSEST + (i * 37 % 1000) / 1000 * (10.0 - SCAN_CLOSEST))
    return out


class ScanPlan(Plan):
    """The plan, with a LaserScan topic published beside its stream and two more
    variables and one requirement in the daemon's config: ``obstacle`` (``reduce:
    min`` over ``ranges``), ``scan_age_ms`` (``age_of: obstacle``), and
    ``SCAN_REQUIREMENT``: always obstacle > 0.5 & scan_age_ms < 1000, an assumption
    (inputs only) that the nominal scan satisfies, logged when violated."""

    def __init__(self, config: Path, hz: float = SCAN_HZ, readings: int = SCAN_READINGS) -> None:
        super().__init__(config)
        for name in ("obstacle", "scan_age_ms"):
            if name in self.cfg.variables:
                raise BenchError(f"{config}: has a variable '{name}' already (the scan's)")
        self.scan = {
            "name": "obstacle",
            "topic": SCAN_TOPIC,
            "msg": SCAN_MSG,
            "field": "ranges",
            "hz": hz,
            "readings": readings,
            "range_min": SCAN_RANGE[0],
            "range_max": SCAN_RANGE[1],
        }

    def _extend(self, doc: dict[str, Any]) -> None:
        variables = doc.setdefault("variables", {})
        variables["obstacle"] = {
            "type": "double",
            "topic": SCAN_TOPIC,
            "msg": SCAN_MSG,
            "field": "ranges",
            "reduce": "min",
            "qos": "reliable",
            "depth": DEPTH,
        }
        variables["scan_age_ms"] = {"type": "double", "age_of": "obstacle"}
        doc.setdefault("requirements", []).append(
            {
                "id": SCAN_REQUIREMENT,
                "text": f"{self.cfg.component} shall always satisfy "
                "obstacle > 0.5 & scan_age_ms < 1000",
                "assumption": True,  # on inputs alone: no output can make it true
                "on_violation": [SCAN_REQUIREMENT],
            }
        )
        mitigations = doc.setdefault("mitigations", {})
        mitigations[SCAN_REQUIREMENT] = {"log": {"message": "obstacle near or scan old"}}


def _nominal(v: Any) -> Any:
    if v.name in SROBOT_NOMINAL:
        return SROBOT_NOMINAL[v.name]
    if v.type == "bool":
        return False
    zero: Any = 0.0 if v.type == "double" else 0
    if v.range is not None and not (v.range[0] <= zero <= v.range[1]):
        return v.range[0]
    return zero
