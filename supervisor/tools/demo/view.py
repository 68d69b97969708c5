"""The demo on screen: the live view, the status line of ``--no-live``, the summary."""

from __future__ import annotations

from typing import Any

from supervisor.tools.demo.robot import zone_of
from supervisor.tools.demo.state import CLASS_WORDS, DemoState

STATE_WORDS = {0: "normal", 1: "alert", 2: "alert + slow down", 3: "stop + UV off"}
EVENTS_SHOWN = 8


def _pct(rate: float) -> str:
    return f"{rate * 100:g} %"


def person_line(c: dict[str, Any]) -> str:
    cls = c.get("c")
    if not c:
        return "waiting for the first perception cycle"
    if cls == 0:
        return "nobody in sight"
    d = c.get("d")
    return f"{CLASS_WORDS.get(cls, cls)} at {d} m, {zone_of(int(d or 0))} zone"


def robot_line(c: dict[str, Any]) -> str:
    if not c:
        return "-"
    s = c.get("state")
    flags = [
        f"alert {'ON' if c.get('alert') else 'off'}",
        f"slowdown {'ON' if c.get('slowdown') else 'off'}",
        f"halt {'ON' if c.get('halt') else 'off'}",
        f"UV light {'off' if c.get('turnoffUVC') else 'on'}",
    ]
    fault = "   << UV STUCK ON (fault)" if c.get("fault") else ""
    return f"OpState {s} ({STATE_WORDS.get(s, '?')})   {'  '.join(flags)}{fault}"


def _counts(st: DemoState) -> tuple[str, str]:
    v = ", ".join(f"{k} {n}" for k, n in sorted(st.violations.items())) or "none"
    m = (
        ", ".join(
            f"{a} {s.ok} ok" + (f" {s.failed} failed" if s.failed else "")
            for a, s in sorted(st.actions.items())
        )
        or "none"
    )
    return v, m


def supervisor_line(st: DemoState) -> str:
    """The daemon's STATUS= (``ticks=.. violations=.. stale=..``) in words."""
    if not st.status:
        return "starting" if not st.ready else f"{st.ticks} ticks"
    fields = dict(w.partition("=")[::2] for w in st.status.split() if "=" in w)
    if not fields:
        return st.status
    text = f"{st.ticks} ticks   stale inputs: {fields.get('stale', 'none')}"
    if fields.get("waiting_for"):
        text += f"   waiting for: {fields['waiting_for']}"
    if fields.get("latched"):
        text += f"   latched: {fields['latched']}"
    return text


def screen(st: DemoState, final: bool = False) -> str:
    v, m = _counts(st)
    c = st.cycle
    lines = [
        f"safety-supervisor demo   {min(st.elapsed(), st.duration):5.1f} s / {st.duration:g} s   "
        f"ROS domain {st.domain}   fault rate {_pct(st.fault_rate)}   seed {st.seed}",
        "power_off (escalation of operationalstate_3) is simulated here: "
        "a local marker program, no SSH",
        "",
        f"person       walk {st.walk}: {person_line(c)}",
        f"robot        {robot_line(c)}",
        f"supervisor   {supervisor_line(st)}",
        "",
        f"violations   {sum(st.violations.values())}: {v}",
        f"mitigations  {sum(s.ok + s.failed for s in st.actions.values())}: {m}",
        f"faults       {st.faults} injected, {st.faults_fixed} cut by the supervisor",
        "",
        "last events",
    ]
    return "\n".join(lines + _screen_tail(st, final))


def _screen_tail(st: DemoState, final: bool) -> list[str]:
    """Both live screens end alike: the last events, the log, how to stop."""
    recent = st.timeline()[-EVENTS_SHOWN:]
    lines = [f"  {e.render()}" for e in recent] or ["  (none yet)"]
    lines += ["", f"violation log: {st.log}"]
    if not final:
        lines.append("Ctrl-C stops the demo")
    return lines


def status_line(st: DemoState) -> str:
    c = st.cycle
    if not c:
        return ""  # nothing to say before the first perception cycle
    robot = f"OpState {c.get('state')}" if c else "-"
    if c:
        on = [n for n in ("alert", "slowdown", "halt") if c.get(n)]
        on.append("UV off" if c.get("turnoffUVC") else "UV STUCK ON" if c.get("fault") else "UV on")
        robot += f" ({', '.join(on)})"
    n_mit = sum(s.ok + s.failed for s in st.actions.values())
    return (
        f"{st.elapsed():6.1f} s  walk {st.walk}: {person_line(c)} | {robot} | "
        f"ticks {st.ticks}, violations {sum(st.violations.values())}, mitigations {n_mit}"
    )


def _percentile(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, max(0, round(q * (len(s) - 1))))]


def summary(st: DemoState, elapsed: float, interrupted: bool) -> str:
    classes = ", ".join(
        f"{n} {CLASS_WORDS[c].split()[0]}" for c, n in sorted(st.walk_classes.items())
    )
    ticks = st.stop_record.get("ticks") if st.stop_record else st.ticks
    n_v = sum(st.violations.values())
    n_m = sum(s.ok + s.failed for s in st.actions.values())
    head = "demo interrupted" if interrupted else "demo finished"
    lines = [
        f"{head} after {elapsed:.1f} s (ROS domain {st.domain}, seed {st.seed}, "
        f"fault rate {_pct(st.fault_rate)})",
        f"  walks             {st.walk}" + (f" ({classes})" if classes else ""),
        f"  state changes     {st.state_changes}",
        f"  faults injected   {st.faults} (UV light stuck on in state 3), "
        f"{st.faults_fixed} cut by the supervisor's uv_off",
        f"  supervisor ticks  {ticks}",
        f"  violations        {n_v}",
    ]
    width = max([len(k) for k in st.violations] + [len(k) for k in st.actions] + [16])
    for req, n in sorted(st.violations.items()):
        lines.append(f"    {req:<{width}}  {n}")
    lines += _mitigation_lines(st, n_m, width)
    return "\n".join(lines)


def _mitigation_lines(st: Any, n_m: int, width: int) -> list[str]:
    """The summary's mitigations and where the log is (both examples)."""
    lines = [f"  mitigations       {n_m}"]
    for action, s in sorted(st.actions.items()):
        lat = (
            f"latency p50 {_percentile(s.latencies, 0.5):.1f} ms, max {max(s.latencies):.1f} ms"
            if s.latencies
            else "no latency"
        )
        lines.append(f"    {action:<{width}}  {s.ok} ok, {s.failed} failed, {lat}")
    return [
        *lines,
        f"  violation log     {st.log}",
        f"                    (safety-supervisor logs {st.log} --summary)",
    ]


# ------------------------------------------------------------ the mobile base


def base_line(b: dict[str, Any]) -> str:
    """The base's last state line in words."""
    if not b:
        return "waiting for the scenario"
    scan = f"scan {b.get('scan_hz', 0):g} Hz" + (" (stamp FROZEN)" if b.get("frozen") else "")
    nav = b.get("nav") or "none"
    battery = b.get("battery")
    text = (
        f"obstacle {b.get('obstacle', 0):.2f} m   speed {b.get('speed', 0):.2f} m/s   "
        f"cmd {b.get('cmd', 0):.2f} m/s   {scan}   "
        f"battery {battery * 100 if isinstance(battery, int | float) else 0:.0f} %   nav {nav}"
    )
    return text + ("   HALTED" if b.get("halted") else "")


def phase_line(st: DemoState) -> str:
    p = st.phase
    if not p:
        return "-"
    breaks = p.get("breaks")
    return f"{p.get('name')}: {p.get('says')}" + (f"   (breaks {breaks})" if breaks else "")


def _requirement_rows(st: DemoState, with_last: bool) -> list[str]:
    names = list(st.requirements) + sorted(set(st.violations) - set(st.requirements))
    width = max([len(n) for n in names] + [16])
    rows = []
    for name in names:
        n = st.violations.get(name, 0)
        row = f"{name:<{width}}  " + (
            f"broken: {n} violation{'s' if n != 1 else ''}" if n else "not broken"
        )
        last = st.last_violation.get(name)
        if with_last and last is not None:
            row += f"   (last at {last.t:.1f} s: {last.text.split(': ', 1)[-1]})"
        rows.append(row)
    return rows


def base_screen(st: DemoState, final: bool = False) -> str:
    _, m = _counts(st)
    lines = [
        f"safety-supervisor demo --example mobile-base   "
        f"{min(st.elapsed(), st.duration):5.1f} s / {st.duration:g} s   "
        f"ROS domain {st.domain}   seed {st.seed}",
        "",
        f"phase        {phase_line(st)}",
        f"base         {base_line(st.base)}",
        f"supervisor   {supervisor_line(st)}",
        "",
        f"requirements {sum(1 for r in st.requirements if st.violations.get(r))} of "
        f"{len(st.requirements)} broken, {sum(st.violations.values())} violations",
    ]
    lines += [f"  {row}" for row in _requirement_rows(st, with_last=True)]
    lines += [
        f"mitigations  {sum(s.ok + s.failed for s in st.actions.values())}: {m}",
        "",
        "last events",
    ]
    return "\n".join(lines + _screen_tail(st, final))


def base_status_line(st: DemoState) -> str:
    if not st.base:
        return ""  # nothing to say before the scenario starts
    n_mit = sum(s.ok + s.failed for s in st.actions.values())
    return (
        f"{st.elapsed():6.1f} s  {st.phase.get('name', '-')} | {base_line(st.base)} | "
        f"ticks {st.ticks}, violations {sum(st.violations.values())}, mitigations {n_mit}"
    )


def base_summary(st: DemoState, elapsed: float, interrupted: bool) -> str:
    ticks = st.stop_record.get("ticks") if st.stop_record else st.ticks
    n_v = sum(st.violations.values())
    n_m = sum(s.ok + s.failed for s in st.actions.values())
    head = "demo interrupted" if interrupted else "demo finished"
    halts = ", ".join(f"{n} by {by}" for by, n in sorted(st.base_halts.items())) or "none"
    broken = sum(1 for r in st.requirements if st.violations.get(r))
    lines = [
        f"{head} after {elapsed:.1f} s (example mobile-base, ROS domain {st.domain}, "
        f"seed {st.seed})",
        f"  phases            {st.phases}",
        f"  estops pressed    {st.estops}",
        f"  base halted       {halts}",
        f"  supervisor ticks  {ticks}",
        f"  violations        {n_v}",
    ]
    width = max([len(k) for k in st.violations] + [len(k) for k in st.actions] + [16])
    for req, n in sorted(st.violations.items()):
        lines.append(f"    {req:<{width}}  {n}")
    lines.append(f"  requirements      {len(st.requirements)}")
    lines += [f"    {row}" for row in _requirement_rows(st, with_last=False)]
    lines.append(f"  broken            {broken} of {len(st.requirements)} requirements")
    lines += _mitigation_lines(st, n_m, width)
    return "\n".join(lines)
