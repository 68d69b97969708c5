"""``safety-supervisor inject CONFIG REQ``: a computed violation-injection device.

The thesis injected violations with hand-written buttons, one per requirement
(its Lst. 7).  Here z3 computes them, with the analyses' encoder
(:mod:`monitors.verify.bmc`, the same semantics as the monitor): a short trace over
the topic variables whose last tick violates REQ while every other requirement,
assumptions and variable ranges included, holds at every tick.  When that is
impossible, a MaxSAT objective keeps as many of the others as possible and the
ones that must break are named.  The trace is re-checked with the reference
interpreter (:mod:`monitors.verify.interpret`) before anything is published: a
disagreement is a bug and nothing is sent.

Published, the trace is what the supervisor steps on, so the z3 problem is
posed over the *observed* sequence of states, not just the trace: the first
tick repeated by the warm-up (as many times as the supervisor may see it), each
tick as the step policy turns messages into steps (for ``on_message``, the
half-updated states between two ticks too), and the nominal state published
afterwards.  ``--all`` injects every requirement in turn into a running
supervisor and compares what its violation log says with what was expected:
a self-test of a deployed system (stop the robot's own controller first, or it
publishes on the same topics).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import struct
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

# z3 and rclpy are imported where they are used: the CLI imports this module for
# its parser at every start, and must stay quick for the other commands.
from monitors.errors import UserError
from monitors.ir.formula import Const, Formula, Past, Since, Var, max_bound, subterms, variables
from monitors.verify.interpret import Value, verdicts

EXIT_OK, EXIT_FAIL = 0, 1
WARMUP = 5  # copies of the first tick before the injection (10 Hz)
WARMUP_PERIOD_S = 0.1
NOMINAL_PERIOD_S = 0.1  # the nominal state after an injection, well under stale_after_ms
PLAUSIBLE = 1000  # unranged ints prefer |v| <= this (a readable value, not 2^63 - 1)
# ROS integer field types -> the values a message can carry (uint64 above
# int64's maximum is rejected by the supervisor, so it is left out)
INT_FIELD_RANGE = {
    "int8": (-(1 << 7), (1 << 7) - 1),
    "int16": (-(1 << 15), (1 << 15) - 1),
    "int32": (-(1 << 31), (1 << 31) - 1),
    "int64": (-(1 << 63), (1 << 63) - 1),
    "uint8": (0, (1 << 8) - 1),
    "uint16": (0, (1 << 16) - 1),
    "uint32": (0, (1 << 32) - 1),
    "uint64": (0, (1 << 63) - 1),
    "byte": (0, 255),
    "octet": (0, 255),
    "char": (0, 255),
}

Trace = list[dict[str, Value]]
STOPPED = (
    "note: publishing stopped: unless the robot publishes again, the supervisor reports "
    "its inputs stale (and runs on_stale) after stale_after_ms"
)


class InjectError(Exception):
    """A one-line failure of ``inject`` (printed without a traceback, exit 1)."""


class Unviolable(InjectError):
    """No publishable trace violates the requirement (``--all`` skips it, says why)."""


# ------------------------------------------------------------------ small formula helpers


def lookback(f: Formula) -> int:
    """Ticks of history ``f`` can see: its verdicts on a state repeated more than
    this many times no longer change (bounded windows are full of it, unbounded
    operators have reached their fixed point)."""
    depth: dict[Formula, int] = {}
    for g in subterms(f):  # children first
        kids = [depth[c] for c in g.children()]
        own = 0
        if isinstance(g, Past):
            own = 1 if g.op in ("Y", "Z") else (g.hi if g.hi is not None else (g.lo or 0) + 1)
        elif isinstance(g, Since):
            own = g.hi if g.hi is not None else (g.lo or 0) + 1
        depth[g] = max(kids, default=0) + own
    return depth[f]


def range_formula(name: str, vtype: str, rng: tuple[float, float]) -> Formula:
    """``lo <= name <= hi`` (integer bounds rounded inward, as the analyses do)."""
    from monitors.ir.formula import BinOp

    lo, hi = rng
    if vtype == "int64":
        c_lo, c_hi = Const(math.ceil(lo)), Const(math.floor(hi))
    else:
        c_lo, c_hi = Const(float(lo)), Const(float(hi))
    return BinOp("&", BinOp(">=", Var(name), c_lo), BinOp("<=", Var(name), c_hi))


def _fmt(v: Value) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else repr(v)
    return str(v)


def _names(items: Sequence[str]) -> str:
    if len(items) <= 1:
        return "".join(items)
    return ", ".join(items[:-1]) + " and " + items[-1]


# ------------------------------------------------------------------ the plan


@dataclass
class Topic:
    """One published topic: its message type and the variables it carries."""

    name: str
    msg: str
    fields: list[tuple[str, str]]  # (variable, field path)


@dataclass
class Injection:
    req: str
    text: str
    k: int
    trace: Trace  # the k ticks, topic variables only
    broken: list[str]  # other monitored requirements that must break too
    broken_ranges: list[str]  # variables whose declared range must break
    early: bool  # REQ holds before its last tick (else it is already violated earlier)
    tick_violations: list[list[str]]  # per tick: requirements false there (interpreter)
    expected: list[str]  # what the supervisor should log: REQ and the broken ones
    notes: list[str] = field(default_factory=list)


@dataclass
class _Schedule:
    """How the step policy turns published ticks into the states it steps on."""

    policy: str
    topic_of: dict[str, int]  # variable -> index of its topic in publishing order
    repeat: int = 1  # periodic: each tick is sampled about this many times


class Planner:
    """Computes injections for one loaded project (z3 through ``monitors.verify.bmc``)."""

    def __init__(self, project: Any, *, warmup: int = WARMUP) -> None:
        from supervisor.analysis_report import project_requirements

        cfg = project.config
        self.cfg = cfg
        self.warmup = warmup
        reqs, infos = project_requirements(project)
        self.reqs = {r.id: r for r in reqs}
        self.inputs = [v.name for v in cfg.inputs]
        self.types = {v.name: v.type for v in cfg.inputs}
        self.ranges = {
            v.name: range_formula(v.name, v.type, v.range)
            for v in infos
            if v.range is not None and v.type != "bool" and v.name in self.types
        }
        self.topics = topics_of(cfg)
        self.schedule = _schedule(cfg, self.topics)
        self.domains = _field_domains(cfg)
        self.unsupported: dict[str, str] = {}
        self._check_encodable()
        # constant-state saturation: a state repeated this often looks the same to
        # every requirement as one repeated forever
        self.saturation = max([2] + [lookback(r.formula) + 1 for r in self.reqs.values()])
        self._nominal: dict[str, Value] | None = None
        self._nominal_done = False

    # -------------------------------------------------------------- z3 building blocks

    def _check_encodable(self) -> None:
        from monitors.verify.bmc import Encoder, Unsupported, fresh_rows

        rows = fresh_rows(self.types, self.inputs, 1, "chk")
        enc = Encoder(self.types, rows)
        for rid, r in list(self.reqs.items()):
            try:
                enc.holds(r.formula)
            except Unsupported as e:
                self.unsupported[rid] = str(e)
                del self.reqs[rid]

    def _quiet(self, name: str) -> Value:
        """A readable default: the configured initial value, else 0 (false) moved into
        the range."""
        v = self.cfg.variables[name]
        t = self.types[name]
        if v.initial is not None:
            return bool(v.initial) if t == "bool" else v.initial
        if t == "bool":
            return False
        lo, hi = v.range if v.range is not None else (0, 0)
        x = min(max(0, lo), hi) if v.range is not None else 0
        return int(math.ceil(x)) if t == "int64" else float(x)

    def _domain(self, row: Mapping[str, Any]) -> list:
        """What the message fields can carry (hard: anything else cannot be published)."""
        import z3

        from monitors.verify.bmc import fp_const

        out = []
        for n, leaf in self.domains.items():
            x, t = row[n], self.types[n]
            if leaf in INT_FIELD_RANGE:
                lo, hi = INT_FIELD_RANGE[leaf]
                if t == "int64":
                    out += [x >= lo, x <= hi]
                elif t == "double":  # an integer field feeding a double variable
                    out += [
                        z3.fpEQ(z3.fpRoundToIntegral(z3.RTZ(), x), x),
                        z3.fpGEQ(x, fp_const(float(lo))),
                        z3.fpLEQ(x, fp_const(float(hi))),
                    ]
            elif leaf in ("float", "float32") and t == "double":
                narrow = z3.fpToFP(z3.RNE(), x, z3.Float32())
                out.append(z3.Or(z3.fpIsNaN(x), z3.fpToFP(z3.RNE(), narrow, z3.Float64()) == x))
        return out

    def _plausible(self, row: Mapping[str, Any]) -> list:
        """Soft: values near their range (or small): an out-of-range value that must be
        injected reads as 3, not 4611686018427387904."""
        import z3

        from monitors.verify.bmc import fp_const

        out = []
        for n in self.inputs:
            t, x = self.types[n], row[n]
            if t == "bool":
                continue
            v = self.cfg.variables[n]
            lo, hi = (v.range[0] - 1, v.range[1] + 1) if v.range else (-PLAUSIBLE, PLAUSIBLE)
            if t == "int64":
                out.append(z3.And(x >= math.ceil(lo), x <= math.floor(hi)))
            else:
                out.append(
                    z3.And(z3.fpGEQ(x, fp_const(float(lo))), z3.fpLEQ(x, fp_const(float(hi))))
                )
        return out

    # -------------------------------------------------------------- what the supervisor sees

    def observed(
        self, rows: Sequence[Mapping[str, Any]], warm: int, tail: int, repeat: int | None = None
    ) -> tuple[list, list[int]]:
        """The states the supervisor steps on when ``rows`` is published: ``warm``
        copies of tick 0, the ticks 1..k-1 as the step policy makes them (each
        ``repeat`` times: periodic sampling), then ``tail`` steps back on tick 0 (the
        nominal state, labelled -1).  Works on z3 rows and on concrete ones alike.
        Returns (states, the tick of each state)."""
        sch = self.schedule
        repeat = sch.repeat if repeat is None else repeat
        states: list = [rows[0]] * warm
        labels = [0] * warm

        def tick(prev: Mapping[str, Any], cur: Mapping[str, Any]) -> list:
            if sch.policy == "on_message":
                # every topic is published each tick, in a fixed order, and each
                # message is a step: after message j the topics up to j are new
                m = max(sch.topic_of.values()) + 1
                return [
                    {n: (cur[n] if sch.topic_of[n] <= j else prev[n]) for n in self.inputs}
                    for j in range(m)
                ]
            return [cur] * repeat

        for t in range(1, len(rows)):
            step = tick(rows[t - 1], rows[t])
            states += step
            labels += [t] * len(step)
        back = tick(rows[-1], rows[0])
        back += [rows[0]] * max(0, tail - len(back))
        return states + back, labels + [-1] * len(back)

    @staticmethod
    def span(labels: list[int], t: int) -> tuple[int, int]:
        """First and last index of tick ``t``'s states."""
        return labels.index(t), len(labels) - 1 - labels[::-1].index(t)

    def _variants(self) -> list[int]:
        """Warm-up copies the supervisor may see: 1..warmup (a freshly matched topic's
        first samples can be late), or saturated (it has seen the nominal state for
        long, as in ``--all``)."""
        s = self.saturation  # more copies than this look like exactly this many
        return sorted({min(r, s) for r in range(1, self.warmup + 1)} | {s})

    # -------------------------------------------------------------- nominal state

    def nominal(self) -> dict[str, Value] | None:
        """A quiet state that satisfies every requirement and range however long it is
        held (None when the requirements cannot all hold)."""
        if self._nominal_done:
            return self._nominal
        import z3

        from monitors.verify.bmc import Encoder, fresh_rows, model_trace, z3_value

        self._nominal_done = True
        row = fresh_rows(self.types, self.inputs, 1, "nominal")[0]
        enc = Encoder(self.types, [row] * self.saturation)
        opt = z3.Optimize()
        opt.set(timeout=20_000)
        opt.add(self._domain(row))
        for r in self.reqs.values():
            opt.add(z3.And(enc.holds(r.formula)))
        for f in self.ranges.values():
            opt.add(enc.holds(f)[0])
        for n in self.inputs:
            opt.add_soft(row[n] == z3_value(self.types[n], self._quiet(n)), id="quiet")
        if opt.check() != z3.sat:
            return None
        self._nominal = model_trace(opt.model(), [row], self.types)[0]
        return self._nominal

    # -------------------------------------------------------------- one injection

    def plan(self, rid: str) -> Injection:
        if rid in self.unsupported:
            raise InjectError(f"{rid} cannot be injected: {self.unsupported[rid]}")
        if rid not in self.reqs:
            known = ", ".join(r.id for r in self.cfg.requirements)
            raise InjectError(f"no requirement '{rid}' (requirements: {known})")
        req = self.reqs[rid]
        k = max(2, max_bound(req.formula) + 2)
        inj = self._solve(rid, k)
        if inj is None and lookback(req.formula) + 2 > k:
            k = lookback(req.formula) + 2  # nested bounds can need a longer lead-in
            inj = self._solve(rid, k)
        if inj is None:
            raise Unviolable(
                f"{rid} cannot be violated: no trace of {k} ticks with values the message "
                f"fields can carry makes `{req.formula}` false (see `check` for redundancy)"
            )
        return inj

    def _solve(self, rid: str, k: int) -> Injection | None:
        import z3

        from monitors.verify.bmc import Encoder, fresh_rows, model_trace, z3_value

        rows = fresh_rows(self.types, self.inputs, k, f"{rid}.")
        tail = self.saturation
        others = [o for o in self.reqs if o != rid]
        opt = z3.Optimize()
        opt.set(timeout=30_000)
        for row in rows:
            opt.add(self._domain(row))
        early: list = []
        keep: dict[str, list] = {o: [] for o in others}
        for warm in self._variants():
            states, labels = self.observed(rows, warm, tail)
            first, last = self.span(labels, k - 1)
            enc = Encoder(self.types, states)
            mine = enc.holds(self.reqs[rid].formula)
            opt.add(z3.Not(mine[last]))  # hard: the injected tick violates REQ
            early += mine[:first]  # REQ holds until its last tick
            for o in others:
                keep[o] += enc.holds(self.reqs[o].formula)
        # after a reset (reset: after_mitigation) REQ is judged afresh on the nominal state
        fresh = Encoder(self.types, [rows[0]] * tail).holds(self.reqs[rid].formula)
        # soft goals, most important first (z3 optimises them lexicographically)
        opt.add_soft(z3.And(early + fresh), id="1-early")
        for o in others:
            opt.add_soft(z3.And(keep[o]), id="2-others")
        ranges = {n: Encoder(self.types, rows).holds(f) for n, f in self.ranges.items()}
        for xs in ranges.values():
            opt.add_soft(z3.And(xs), id="3-ranges")
        nominal = self.nominal()
        if nominal is not None:
            for n in self.inputs:
                opt.add_soft(rows[0][n] == z3_value(self.types[n], nominal[n]), id="4-nominal")
        for t in range(1, k):
            for n in self.inputs:
                opt.add_soft(rows[t][n] == rows[t - 1][n], id="5-steady")
        for row in rows:
            for c in self._plausible(row):
                opt.add_soft(c, id="6-plausible")
        result = opt.check()
        if result == z3.unsat:
            return None
        if result != z3.sat:
            raise InjectError(f"z3 gave up computing a trace for {rid} ({opt.reason_unknown()})")
        model = opt.model()
        trace = model_trace(model, rows, self.types)

        def true(x: Any) -> bool:
            return z3.is_true(model.eval(x, model_completion=True))

        inj = Injection(
            req=rid,
            text=self.reqs[rid].text,
            k=k,
            trace=trace,
            broken=[o for o in others if not true(z3.And(keep[o]))],
            broken_ranges=[n for n, xs in ranges.items() if not true(z3.And(xs))],
            early=true(z3.And(early + fresh)),
            tick_violations=[],
            expected=[],
        )
        inj.expected = [rid, *inj.broken]
        self._recheck(inj)
        self._explain(inj)
        return inj

    # -------------------------------------------------------------- judge and explain

    def _recheck(self, inj: Injection) -> None:
        """The reference interpreter must confirm everything z3 claimed, on every
        observed sequence; otherwise nothing may be published."""
        from monitors.verify.bmc import evaluate_z3

        problem = self._judge(inj, inj.trace)
        if problem is not None:
            raise InjectError(
                f"internal error: z3 and the reference interpreter disagree on the trace "
                f"for {inj.req}: {problem}; nothing was published (please report) {inj.trace}"
            )
        self._tidy(inj)
        # the encoder must agree with the judge on the final trace too
        states, _ = self.observed(inj.trace, self.saturation, self.saturation)
        for r, q in self.reqs.items():
            if evaluate_z3(q.formula, states, self.types) != verdicts(q.formula, states):
                raise InjectError(
                    f"internal error: z3 and the reference interpreter disagree on {r} "
                    f"for the trace of {inj.req}; nothing was published (please report)"
                )
        inj.tick_violations = self._flagged(inj)

    def _judge(self, inj: Injection, trace: Trace) -> str | None:
        """What is wrong with ``trace`` as the injection ``inj`` describes it (REQ
        violated at the last tick, held before if ``early``, the others and ranges
        not listed as broken held throughout), according to the interpreter."""
        rid, tail = inj.req, self.saturation
        for warm in self._variants():
            states, labels = self.observed(trace, warm, tail)
            first, last = self.span(labels, inj.k - 1)
            mine = verdicts(self.reqs[rid].formula, states)
            if mine[last]:
                return f"{rid} holds at the injected tick (warm-up {warm})"
            if inj.early and not all(mine[:first]):
                return f"{rid} is violated before the injected tick (warm-up {warm})"
            for o, q in self.reqs.items():
                if o != rid and o not in inj.broken and not all(verdicts(q.formula, states)):
                    return f"{o} is violated (warm-up {warm})"
        if inj.early and not all(verdicts(self.reqs[rid].formula, [trace[0]] * tail)):
            return f"{rid} is violated on the nominal state"
        for n, f in self.ranges.items():
            if n not in inj.broken_ranges and not all(verdicts(f, trace)):
                return f"the range of {n} is broken"
        return None

    def _flagged(self, inj: Injection) -> list[list[str]]:
        """Per published tick, the requirements the supervisor may flag there (any
        warm-up variant; a monitor stays false after a violation: its first tick)."""
        flagged: list[set[str]] = [set() for _ in inj.trace]
        for warm in self._variants():
            states, labels = self.observed(inj.trace, warm, self.saturation)
            for r, q in self.reqs.items():
                vs = verdicts(q.formula, states)
                i = next((i for i, ok in enumerate(vs) if not ok), None)
                if i is not None and labels[i] >= 0:
                    flagged[labels[i]].add(r)
        return [[r for r in self.reqs if r in f] for f in flagged]

    def _tidy(self, inj: Injection) -> None:
        """Move each changed number to the nicest value that keeps every property
        (the interpreter judges): the closest to the previous tick, preferring the
        constants the requirements compare with and their neighbours, so a value
        reads as the threshold it crosses (8 for '> 7') instead of whatever z3 chose.
        Cheaper than asking z3 to minimise distances over 64-bit vectors."""
        consts: set[int | float] = {0}
        for q in self.reqs.values():
            for g in subterms(q.formula):
                if isinstance(g, Const) and not isinstance(g.value, bool):
                    v = g.value
                    if isinstance(v, float) and not math.isfinite(v):
                        continue
                    consts |= {v - 1, v, v + 1}
        trace = inj.trace
        for t in range(1, len(trace)):
            for n in self.inputs:
                cur, prev = trace[t][n], trace[t - 1][n]
                if self.types[n] == "bool" or cur == prev:
                    continue
                run = t  # the ticks from t that hold the same value move together
                while run + 1 < len(trace) and trace[run + 1][n] == cur:
                    run += 1
                rng = self.cfg.variables[n].range
                cands = set(consts) | ({rng[0], rng[1]} if rng else set())
                if self.types[n] == "int64":
                    cands = {int(c) for c in cands if float(c).is_integer()}
                else:
                    cands = {float(c) for c in cands}
                for c in sorted(cands, key=lambda c: (abs(c - prev), c)):
                    if abs(c - prev) >= abs(cur - prev):
                        break  # no nicer value left
                    if not self._fits(n, c):
                        continue
                    trial = [dict(row) for row in trace]
                    for i in range(t, run + 1):
                        trial[i][n] = c
                    if self._judge(inj, trial) is None:
                        trace = trial
                        break
        inj.trace = trace

    def _fits(self, name: str, value: Value) -> bool:
        """The value can be carried by the variable's message field."""
        leaf = self.domains.get(name)
        if leaf in INT_FIELD_RANGE:
            lo, hi = INT_FIELD_RANGE[leaf]
            return float(value).is_integer() and lo <= value <= hi
        if leaf in ("float", "float32") and isinstance(value, float):
            return struct.unpack("<f", struct.pack("<f", value))[0] == value
        return True

    def _explain(self, inj: Injection) -> None:
        mine = set(variables(self.reqs[inj.req].formula))
        for o in inj.broken:
            shared = sorted(mine & set(variables(self.reqs[o].formula)))
            why = f" (they share {', '.join(shared)})" if shared else ""
            inj.notes.append(f"violating {inj.req} also violates {o}{why}")
        for n in inj.broken_ranges:
            rng = self.cfg.variables[n].range
            assert rng is not None
            inj.notes.append(
                f"violating {inj.req} needs {n} outside its range [{rng[0]:g}, {rng[1]:g}]: "
                "ranges are not monitored, so the supervisor should log "
                f"{_names(inj.expected)} only"
            )
        if not inj.early:
            inj.notes.append(
                f"{inj.req} cannot hold before the injected tick here: it may be logged earlier"
            )
        for o, why in self.unsupported.items():
            inj.notes.append(f"{o} is not checked (z3 cannot encode it: {why})")
        if self.nominal() is None:
            inj.notes.append(
                "no state satisfies every requirement (see check): this trace starts "
                "from a state of its own, so --all cannot start each injection alike"
            )
        # periodic ticks are sampled a variable number of times: say when that matters
        if self.schedule.policy == "periodic":
            for rep in (1, 3):
                states, labels = self.observed(inj.trace, 1, self.saturation, rep)
                last = self.span(labels, inj.k - 1)[1]
                bad = [
                    o
                    for o in self.reqs
                    if o not in inj.expected and not all(verdicts(self.reqs[o].formula, states))
                ]
                if verdicts(self.reqs[inj.req].formula, states)[last] or bad:
                    inj.notes.append(
                        f"timing-sensitive: if the supervisor samples each tick {rep} time(s) "
                        "instead of 2 the outcome differs (time bounds in periods)"
                    )
                    break


# ------------------------------------------------------------------ config -> topics


def topics_of(cfg: Any) -> list[Topic]:
    """The topics to publish, in config order with the trigger's topic last."""
    out: dict[str, Topic] = {}
    for v in cfg.inputs:
        t = out.get(v.topic)
        if t is None:
            t = out[v.topic] = Topic(v.topic, v.msg, [])
        elif t.msg != v.msg:
            raise InjectError(
                f"{cfg.path}: topic {v.topic} is declared with two message types "
                f"({t.msg}, {v.msg}): one message cannot be published for both"
            )
        t.fields.append((v.name, v.field))
    topics = list(out.values())
    trig = cfg.step.trigger
    if cfg.step.policy == "on_trigger" and trig:
        topics.sort(key=lambda t: any(n == trig for n, _ in t.fields))
    return topics


def _schedule(cfg: Any, topics: list[Topic]) -> _Schedule:
    topic_of = {n: i for i, t in enumerate(topics) for n, _ in t.fields}
    repeat = 2 if cfg.step.policy == "periodic" else 1
    return _Schedule(cfg.step.policy, topic_of, repeat)


def _field_domains(cfg: Any) -> dict[str, str]:
    """Variable -> the ROS leaf type of its field (empty when ROS is not importable)."""
    from mitigations.rosmsg import field_type, message_class

    out = {}
    for v in cfg.inputs:
        try:
            out[v.name] = field_type(message_class(v.msg), v.field)
        except (UserError, ImportError):
            pass  # check reports it; the value is then not narrowed
    return out


def set_field(msg: Any, path: str, value: Any) -> None:
    """Set a dotted field path ('twist.twist.linear.x') in a message."""
    *parents, leaf = path.split(".")
    for part in parents:
        msg = getattr(msg, part)
    current = getattr(msg, leaf)
    if isinstance(current, bool):
        value = bool(value)
    elif isinstance(current, int):
        value = int(value)
    elif isinstance(current, float):
        value = float(value)
    setattr(msg, leaf, value)


# ------------------------------------------------------------------ printing


def trace_table(
    inj: Injection, names: Sequence[str], extra: Sequence[Sequence[str]] | None = None
) -> list[str]:
    """One row per tick, one column per variable (changed values marked '*'), then the
    requirements the interpreter finds violated at that tick."""
    head = ["tick", *names, "violated"]
    rows = []
    for t, state in enumerate(inj.trace):
        cells = [str(t)]
        for n in names:
            mark = "*" if t and state[n] != inj.trace[t - 1][n] else ""
            cells.append(_fmt(state[n]) + mark)
        cells.append(", ".join(inj.tick_violations[t]) or "-")
        rows.append(cells)
    if extra:
        head = [head[0], "at_ms", *head[1:]]
        rows = [[r[0], *e, *r[1:]] for r, e in zip(rows, extra, strict=True)]
    return columns(head, rows)


def columns(head: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """Left-aligned columns, two spaces apart (no cell contains two spaces)."""
    widths = [max([len(h), *(len(r[i]) for r in rows)]) for i, h in enumerate(head)]
    out = ["  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True)).rstrip()]
    for r in rows:
        out.append("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip())
    return out


def describe(inj: Injection, planner: Planner) -> list[str]:
    sch = planner.schedule
    how = {
        "on_trigger": f"each tick: the other topics, then {planner.cfg.step.trigger} "
        "(on_trigger: the trigger ends the tick)",
        "synchronized": "each tick: every topic once (synchronized)",
        "periodic": "each tick held for 2 periods, every topic at the period (periodic)",
        "on_message": "each tick: every topic in turn, one step per message (on_message)",
    }[sch.policy]
    clean = not inj.broken and not inj.broken_ranges
    what = (
        f"tick {inj.k - 1} violates {inj.req} and nothing else"
        if clean
        else f"tick {inj.k - 1} violates {inj.req}; the supervisor should log {_names(inj.expected)}"
    )
    return [f"{inj.req}: {inj.text}", f"{inj.k} ticks; {what}; {how}"]


# ------------------------------------------------------------------ ROS side


class RosOut:
    """Publishers for the configured topics, from a node of our own."""

    def __init__(self, cfg: Any, topics: list[Topic]) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions

        from mitigations.rosmsg import message_class

        self.cfg = cfg
        self.ctx = Context()
        rclpy.init(context=self.ctx, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("safety_supervisor_inject", context=self.ctx)
        # reliable + volatile: matches reliable and best-effort readers alike
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.topics = topics
        self.classes = {t.name: message_class(t.msg) for t in topics}
        self.pubs = {
            t.name: self.node.create_publisher(self.classes[t.name], t.name, qos) for t in topics
        }

    def close(self) -> None:
        import rclpy

        try:
            self.node.destroy_node()
        finally:
            rclpy.shutdown(context=self.ctx)

    def wait_for_supervisor(self, timeout: float) -> None:
        """Until the supervisor's node subscribes to every topic and each publisher is
        matched (DDS discovery takes ~3 s on localhost)."""
        name = self.cfg.ros.node_name.strip("/").split("/")[-1]
        deadline = time.monotonic() + timeout
        missing: list[str] = []
        while True:
            missing = []
            for t in self.topics:
                subs = self.node.get_subscriptions_info_by_topic(t.name)
                mine = any(s.node_name == name for s in subs)
                if not mine or self.pubs[t.name].get_subscription_count() < 1:
                    missing.append(t.name)
            if not missing:
                return
            if time.monotonic() > deadline:
                break
            time.sleep(0.05)
        domain = os.environ.get("ROS_DOMAIN_ID", "0")
        raise InjectError(
            f"no supervisor is listening: node '{name}' has no subscription to "
            f"{', '.join(missing)} after {timeout:g} s (is it running, on ROS_DOMAIN_ID={domain}?)"
        )

    def message(self, topic: Topic, state: Mapping[str, Value]) -> Any:
        msg = self.classes[topic.name]()
        for var, path in topic.fields:
            try:
                set_field(msg, path, state[var])
            except (AssertionError, TypeError, ValueError) as e:
                raise InjectError(
                    f"{var} = {_fmt(state[var])} cannot be set in {topic.msg}.{path}: {e}"
                ) from None
        return msg

    def publish(self, topic: Topic, state: Mapping[str, Value]) -> None:
        self.pubs[topic.name].publish(self.message(topic, state))


@dataclass
class Timing:
    gap_s: float = 0.02  # before the trigger (on_trigger) / between messages (on_message)
    tick_s: float = 0.05  # between two injected ticks
    hold_s: float = 0.5  # the nominal state after an injection


class Player:
    """Publishes injections with the timing the step policy needs."""

    def __init__(self, out: RosOut, planner: Planner, timing: Timing) -> None:
        self.out = out
        self.planner = planner
        self.timing = timing
        self.policy = planner.cfg.step.policy
        self.period_s = (planner.cfg.step.period_ms or 100.0) / 1000

    def state(self, s: Mapping[str, Value]) -> None:
        """One tick's worth of messages."""
        topics = self.out.topics
        if self.policy == "on_trigger":
            *rest, trig = topics
            for t in rest:
                self.out.publish(t, s)
            time.sleep(self.timing.gap_s)  # DDS does not order topics: the trigger last
            self.out.publish(trig, s)
        elif self.policy == "on_message":
            for i, t in enumerate(topics):
                if i:
                    time.sleep(self.timing.gap_s)  # one step per message, in this order
                self.out.publish(t, s)
        elif self.policy == "periodic":
            # hold the values for 2 periods, every topic at the period
            for _ in range(2):
                for t in topics:
                    self.out.publish(t, s)
                time.sleep(self.period_s)
        else:
            for t in topics:
                self.out.publish(t, s)

    def hold(
        self, s: Mapping[str, Value], seconds: float, until: Callable[[], bool] | None = None
    ) -> None:
        """Publish ``s`` at 10 Hz for ``seconds`` (or until ``until()``)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.state(s)
            if until is not None and until():
                return
            time.sleep(NOMINAL_PERIOD_S)

    def play(self, inj: Injection, warmup: int) -> list[list[str]]:
        """Warm-up, the ticks, then the nominal state; returns the at_ms column."""
        t0 = time.monotonic()
        ms = [[f"{0:.0f} (x{warmup})"]]
        for i in range(warmup):
            if i:
                time.sleep(WARMUP_PERIOD_S)
            self.state(inj.trace[0])
        time.sleep(WARMUP_PERIOD_S)
        for t in range(1, inj.k):
            if t > 1:
                time.sleep(self.timing.tick_s)
            ms.append([f"{(time.monotonic() - t0) * 1000:.0f}"])
            self.state(inj.trace[t])
        time.sleep(self.timing.tick_s)
        return ms


# ------------------------------------------------------------------ the violation log


def log_size(path: Path) -> int:
    try:
        return path.stat().st_size
    except FileNotFoundError:
        return 0


def violations_since(path: Path, offset: int) -> list[str]:
    """Requirement ids of the ``violation`` records written after byte ``offset``."""
    try:
        with path.open("rb") as f:
            if path.stat().st_size < offset:
                offset = 0  # rotated (copytruncate): read the new file from its start
            f.seek(offset)
            data = f.read()
    except FileNotFoundError:
        return []
    out = []
    for line in data.split(b"\n"):
        if not line.endswith(b"}"):
            continue  # a line still being written
        try:
            rec = json.loads(line)
        except ValueError:
            continue
        if rec.get("event") == "violation" and isinstance(rec.get("requirement"), str):
            out.append(rec["requirement"])
    return out


def _logged(ids: list[str]) -> str:
    counts: dict[str, int] = {}
    for i in ids:
        counts[i] = counts.get(i, 0) + 1
    return ", ".join(f"{i} x{c}" if c > 1 else i for i, c in counts.items()) or "none"


# ------------------------------------------------------------------ command


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "inject",
        help="publish a computed state that violates one requirement and only it",
        description="Compute (z3) a short trace that violates REQ while every other "
        "requirement holds, and publish it on the configured topics for a running "
        "supervisor. Stop the robot's own controller first: it publishes on the same topics.",
    )
    p.add_argument("config")
    p.add_argument("requirement", nargs="?", metavar="REQ")
    p.add_argument("--dry-run", action="store_true", help="compute and print only (no ROS)")
    p.add_argument(
        "--all",
        action="store_true",
        help="inject every requirement in turn and compare with the supervisor's log",
    )
    p.add_argument(
        "--log", default=None, metavar="FILE", help="--all: the supervisor's violation log"
    )
    p.add_argument(
        "--wait-s",
        type=float,
        default=15.0,
        metavar="S",
        help="how long to wait for the supervisor's subscriptions (default 15)",
    )
    p.add_argument(
        "--gap-ms", type=float, default=20.0, help="before the trigger / between messages (20)"
    )
    p.add_argument("--tick-ms", type=float, default=50.0, help="between injected ticks (50)")
    p.add_argument(
        "--hold-s",
        type=float,
        default=0.5,
        help="nominal state after each injection, for reset policies (0.5)",
    )
    p.set_defaults(inject_parser=p)


def _out(line: str = "") -> None:
    print(line, flush=True)


def cmd_inject(args: argparse.Namespace) -> int:
    parser = getattr(args, "inject_parser", None)
    if args.all == bool(args.requirement):
        msg = "give either REQ or --all" if not args.all else "give REQ or --all, not both"
        if parser is not None:
            parser.error(msg)  # exits 2 (usage)
        raise UserError(msg)
    try:
        return _inject(args)
    except InjectError as e:
        print(f"safety-supervisor inject: {e}", file=sys.stderr, flush=True)
        return EXIT_FAIL


def _load(path: str) -> Any:
    from supervisor.pipeline import project_for

    project = project_for(path)
    err = project.first_error()
    if err is not None:
        raise err
    return project


def _inject(args: argparse.Namespace) -> int:
    project = _load(args.config)
    cfg = project.config
    planner = Planner(project)
    if args.all:
        ids = _all_order(cfg, planner)
    else:
        cfg.requirement(args.requirement)  # unknown id: one line with the list
        ids = [args.requirement]
    t = time.perf_counter()
    plans: list[Injection] = []  # all computed before anything is sent
    skipped: dict[str, str] = {}
    for rid in ids:
        try:
            plans.append(planner.plan(rid))
        except Unviolable as e:
            if not args.all:
                raise
            skipped[rid] = str(e)
    solve_s = time.perf_counter() - t
    names = planner.inputs
    if args.dry_run:
        for inj in plans:
            for line in describe(inj, planner) + trace_table(inj, names):
                _out(line)
            for n in inj.notes:
                _out(f"note: {n}")
            _out()
        for line in _skipped(cfg, planner, plans, skipped) if args.all else []:
            _out(line)
        _out(f"dry run: nothing published ({len(plans)} trace(s) computed in {solve_s:.2f} s)")
        return EXIT_OK
    if not plans:
        raise InjectError("nothing to inject: " + "; ".join(_skipped(cfg, planner, [], skipped)))
    log = None
    if args.all or args.log:  # REQ with --log: check the log for that one injection too
        if not (args.log or cfg.log_path):
            raise InjectError("--all needs the supervisor's log: give --log FILE")
        log = Path(args.log or cfg.log_path)
        if not log.exists():
            raise InjectError(f"{log}: no such violation log (is it the running supervisor's?)")
    timing = Timing(args.gap_ms / 1000, args.tick_ms / 1000, args.hold_s)
    out = RosOut(cfg, planner.topics)
    try:
        out.wait_for_supervisor(args.wait_s)
        player = Player(out, planner, timing)
        if log is None:
            inj = plans[0]
            ms = player.play(inj, WARMUP)
            player.hold(inj.trace[0], timing.hold_s)
            for line in describe(inj, planner) + trace_table(inj, names, ms):
                _out(line)
            for n in inj.notes:
                _out(f"note: {n}")
            _out(
                f"published: tick 0 x{WARMUP} at 10 Hz (warm-up), ticks 1..{inj.k - 1}, then "
                f"tick 0 for {timing.hold_s:g} s (nominal)"
            )
            _out(STOPPED)
            return EXIT_OK
        return _run_all(plans, skipped, player, log, cfg, planner, timing)
    finally:
        out.close()


def _all_order(cfg: Any, planner: Planner) -> list[str]:
    """Guarantees whose monitor is reset after the violation first, then those that
    stay violated, then assumptions: a requirement left violated is reported once
    and never again, so it cannot disturb the later injections' expectations."""
    entries = [e for e in cfg.requirements if e.id in planner.reqs]

    def rank(e: Any) -> int:
        sticky = e.policy_config.reset == "never" or e.policy_config.latch
        return 2 if e.assumption else (1 if sticky else 0)

    return [e.id for e in sorted(entries, key=rank)]


def _skipped(
    cfg: Any, planner: Planner, plans: Iterable[Injection], why: dict[str, str]
) -> list[str]:
    """A line per requirement ``--all`` did not inject, with the reason."""
    done = {p.req for p in plans}
    out = []
    for e in cfg.requirements:
        if e.id in done:
            continue
        reason = why.get(e.id) or (
            f"{e.id}: z3 cannot encode it ({planner.unsupported[e.id]})"
            if e.id in planner.unsupported
            else f"{e.id} did not formalize (see check)"
        )
        out.append(f"skipped {reason}")
    return out


def _run_all(
    plans: list[Injection],
    skipped: dict[str, str],
    player: Player,
    log: Path,
    cfg: Any,
    planner: Planner,
    timing: Timing,
) -> int:
    names = planner.inputs
    rows: list[tuple[str, str, str, str]] = []
    failures = 0
    sticky = []
    t_all = time.monotonic()
    for i, inj in enumerate(plans):
        entry = cfg.requirement(inj.req)
        if entry.policy_config.reset == "never" or entry.policy_config.latch:
            sticky.append(inj.req)
        offset = log_size(log)
        # later injections start from the nominal state the previous one held
        ms = player.play(inj, WARMUP if i == 0 else 2)
        expected = set(inj.expected)
        # the nominal state: reset policies re-arm; stop early once the log has it all
        wait = max(timing.hold_s, _reset_wait(entry))
        player.hold(inj.trace[0], wait)
        player.hold(
            inj.trace[0], 2.0, lambda e=expected, o=offset: e <= set(violations_since(log, o))
        )
        got = violations_since(log, offset)
        once = planner.schedule.policy in ("on_trigger", "synchronized")
        if set(got) == expected and (not once or len(got) == len(expected)):
            result = "ok"
        elif not got:
            result = "MISMATCH: nothing logged"
        elif set(got) - expected:
            result = f"MISMATCH: also {_names(sorted(set(got) - expected))}"
        elif expected - set(got):
            result = f"MISMATCH: missing {_names(sorted(expected - set(got)))}"
        else:
            result = "MISMATCH: logged more than once"
        failures += result != "ok"
        for line in describe(inj, planner) + trace_table(inj, names, ms):
            _out(line)
        for n in inj.notes:
            _out(f"note: {n}")
        _out(f"logged: {_logged(got)} -> {result}")
        _out()
        rows.append((inj.req, ", ".join(inj.expected), _logged(got), result))
    if sticky:
        _out(f"operator reset (left violated by design: {', '.join(sticky)}): {_reset(player.out)}")
    for line in columns(("requirement", "expected", "logged", "result"), rows):
        _out(line)
    for line in _skipped(cfg, planner, plans, skipped):
        _out(line)
    ok = len(rows) - failures
    _out(
        f"{len(rows)} injected in {time.monotonic() - t_all:.1f} s: {ok} as expected"
        + (f", {failures} MISMATCH" if failures else "")
    )
    _out(STOPPED)
    return EXIT_FAIL if failures else EXIT_OK


def _reset_wait(entry: Any) -> float:
    pc = entry.policy_config
    if pc.reset == "after_ms" and pc.reset_after_ms is not None:
        return pc.reset_after_ms / 1000 + 0.2
    return 0.0


def _reset(out: RosOut) -> str:
    """Ask the supervisor for an operator reset (judge every requirement afresh)."""
    from rclpy.executors import SingleThreadedExecutor
    from std_srvs.srv import Trigger

    from supervisor.tools.reset import RESET_SERVICE

    client = out.node.create_client(Trigger, RESET_SERVICE)
    if not client.wait_for_service(timeout_sec=5.0):
        return f"not done: no {RESET_SERVICE} service within 5 s"
    future = client.call_async(Trigger.Request())
    ex = SingleThreadedExecutor(context=out.ctx)
    ex.add_node(out.node)
    deadline = time.monotonic() + 5.0
    while not future.done() and time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.1)
    ex.shutdown()
    if not future.done():
        return "not done: no answer within 5 s"
    res = future.result()
    return f"{'ok' if res.success else 'refused'}: {res.message}"


def main(argv: list[str] | None = None) -> int:
    """``python -m supervisor.tools.inject.run``: the same as ``safety-supervisor inject`` (one error
    handling for every command: the CLI's)."""
    from supervisor.cli import main as cli_main

    return cli_main(["inject", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
