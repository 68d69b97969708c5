"""The monitoring core: messages and time in, records and actions out.

No rclpy here.  The receive loop (supervisor/daemon/receive.py) and ``replay``
(supervisor/tools/replay) drive the same Core, so what the daemon decides online
is what replay decides offline from the same messages and receive times
(docs/reference/commands.md, "replay").

Time is logical.  Every timer (the periodic step, the synchronized policy's skew,
an input turning stale, a policy's cooldown, escalation, repeat or confirmation)
runs at its own deadline, before any message received after that deadline,
whenever the loop actually gets to it.  So the order of events is a function of
the messages' receive times alone, not of how busy the loop was: a late loop
catches up tick by tick instead of merging ticks.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from typing import Any, Protocol

from mitigations.engine import Request
from mitigations.policy import Armed, Forecast, Note
from mitigations.supervision import Supervision
from mitigations.violationlog.format import encode_fragment
from supervisor.daemon.runtime import InputEvent, Rows, StepResult
from supervisor.daemon.session import Session

REJECT_REPORT_FIRST = 10  # then every REJECT_REPORT_EVERY-th rejected value per input
REJECT_REPORT_EVERY = 1000
# The input events that may come with every message: counted, reported sparsely.
_COUNTED = {"input_rejected": "rejected", "input_nan": "nan", "input_future_stamp": "future"}
_NEVER = 1 << 63  # later than any deadline


class Log(Protocol):
    """What the core writes (mitigations.violationlog.writer.ViolationLog)."""

    def violation(self, requirement: str, **fields: Any) -> bool: ...
    def mitigation(self, requirement: str, **fields: Any) -> bool: ...
    def reset(self, requirement: str, *, reason: str, **extra: Any) -> bool: ...
    def supervisor(self, what: str, **fields: Any) -> bool: ...
    def prediction(self, requirement: str, **fields: Any) -> bool: ...
    def prediction_expired(self, requirement: str, **fields: Any) -> bool: ...


def warn(text: str) -> None:
    try:
        print(f"safety-supervisor: WARNING: {text}", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


class Core:
    """One session's runtime and policies, driven by :meth:`message` and :meth:`advance`.

    ``submit`` receives the actions the policies decide (the daemon's engine runs
    them; replay records them); ``published`` each violation record once written
    (the daemon's violations topic); ``marker`` the external events replay needs
    to reproduce a run (the start, an operator reset), with their logical time."""

    def __init__(
        self,
        session: Session,
        log: Log,
        submit: Callable[[Request], None],
        *,
        published: Callable[[dict[str, Any]], None] | None = None,
        marker: Callable[[str, int, dict[str, Any]], None] | None = None,
        warn: Callable[[str], None] = warn,
    ) -> None:
        self.log = log
        self._submit = submit
        self._published = published
        self._marker = marker
        self.warn = warn
        self.violations = 0
        self.predictions = 0
        self.now: int | None = None  # the logical time reached
        self._due = 0  # a lower bound of the next deadline (0: not known)
        self.session = session
        self.supervision = Supervision(session.runtime, session.policies, self)
        self._stale_after_ns = _stale_after_ns(session)
        self._limits = _limits(session, self._stale_after_ns)
        self._templates = _templates(session, log)
        # The step's violation records for ``published``, handed over once its
        # actions are submitted (_after_step): the halt does not wait for them.
        self._unsent: list[dict[str, Any] | tuple[Any, ...]] = []
        # The halt path (_halt_first): per requirement, its armed policy's first
        # effects with their policy state encoded, made off the path; and the
        # requirements whose record and actions the step's halt path has done.
        self._encode = _encoder(session, log)
        self._armed: list[tuple[Armed, str] | None] = []
        self._early: dict[int, Armed] = {}
        self._arm()

    # ------------------------------------------------------------ driving

    def start(self, t: int) -> None:
        """Monitoring starts at ``t``: the periodic grid begins here."""
        self._mark("start", t)
        self.advance(t)

    def message(self, name: str, value: Any, t: int) -> None:
        """Input ``name``'s value, received at ``t`` (not before the time reached)."""
        self.fields(((name, value),), t)

    def fields(self, values: Sequence[tuple[str, Any]], t: int) -> None:
        """One message received at ``t`` carrying these inputs' values (the fields
        of one topic that variables read): set together, stepped at most once."""
        if t >= self._due:
            self.advance(t)
        self.now = t
        rt = self.session.runtime
        result, events = rt.on_values(values, t)
        limits = self._limits
        for name, _ in values:
            after = limits[name]
            if after is not None and t + after < self._due:
                self._due = t + after + 1  # this input's silence limit starts again at t
        due = rt.due(t)
        if due is not None:  # the synchronized policy's skew may have started
            self._due = min(self._due, due)
        if events:
            self.input_events(events)
        if result is not None:
            self._after_step(result)

    def quiet(self) -> bool:
        """:meth:`rows` may take messages now: the runtime can step a batch and no
        policy is active (so no policy deadline can fall inside it)."""
        sup = self.supervision
        # a requirement that predicts reads its margin after every step
        return self.session.runtime.bulk_ready and not sup.active and not sup.predicting

    def rows(self, rows: Rows, *, min_rows: int = 1) -> int:
        """Messages of one input row each (``replay``'s recordings), received at
        ``rows.t_ns``: as many as are quiet stepped in bulk (Runtime.step_rows),
        with the same decisions as :meth:`fields` one by one.  Returns how many
        were taken; the caller hands the next one to :meth:`fields`."""
        t0 = int(rows.t_ns[0]) if len(rows.t_ns) else None
        if t0 is None:
            return 0
        if t0 >= self._due:
            self.advance(t0)
        if not self.quiet():
            return 0
        rt = self.session.runtime
        done = rt.step_rows(rows, self._stale_after_ns, min_rows=min_rows)
        if not done.rows:
            return 0
        self.now = int(rows.t_ns[done.rows - 1])
        self._due = 0  # the next deadline is computed afresh
        if done.result is not None:
            self._after_step(done.result)
        return done.rows

    def reject(self, name: str, t: int, why: str) -> None:
        """A message of input ``name`` whose field could not be read."""
        if t >= self._due:
            self.advance(t)
        self.input_events([InputEvent("input_rejected", name, t, why)])

    def advance(self, t: int) -> None:
        """Run every timer due at or before ``t``, each at its own deadline."""
        if t < self._due:  # nothing is due yet (the loop asks every turn)
            self.now = t if self.now is None else max(self.now, t)
            return
        while True:
            d = self.next_deadline(t)
            if d is None or d > t:
                self._due = _NEVER if d is None else d
                self.now = t if self.now is None else max(self.now, t)
                return
            self.now = d
            self._run_due(d)

    def next_due(self, t: int) -> int | None:
        """:meth:`next_deadline`, or a time before it: the lower bound the core keeps
        when it is known (woken at it, the loop's :meth:`advance` finds the rest)."""
        if not self._due:
            d = self.next_deadline(t)
            self._due = _NEVER if d is None else d
        return None if self._due == _NEVER else self._due

    def next_deadline(self, t: int) -> int | None:
        """The earliest timer, looking from ``t``: a step (a periodic monitor's first
        one is due at once), an input turning stale, a policy deadline."""
        rt = self.session.runtime
        times = [
            d
            for d in (
                rt.due(t),
                rt.stale_due(self._stale_after_ns),
                self.supervision.next_deadline(),
            )
            if d is not None
        ]
        return min(times) if times else None

    def _run_due(self, d: int) -> None:
        rt = self.session.runtime
        due = rt.due(d)
        if due is not None and due <= d:
            result = rt.on_timer(d)
            if result is not None:
                self._after_step(result)
        stale = rt.stale_due(self._stale_after_ns)
        if stale is not None and stale <= d:
            self.input_events(rt.check_stale(d, self._stale_after_ns))
        deadline = self.supervision.next_deadline()
        if deadline is not None and deadline <= d:
            self.supervision.on_time(d)
            self._arm()  # a policy that ended its incident is armed again

    def _after_step(self, result: StepResult) -> None:
        busy = bool(result.violated or self.supervision.active)
        if result.violated and self._encode:
            self._halt_first(result)
        self.supervision.after_step(result)
        if busy or self.supervision.active:
            self._due = 0  # a policy deadline may have moved earlier
            self._early.clear()
            self._arm()
        if self._unsent:
            self._send()

    def _halt_first(self, result: StepResult) -> None:
        """The halt path (docs/reference/log.md#the-halt-path): when every violation
        of the step is armed (Supervision.halt_plan), write their records and submit
        their actions now, before the policies run; the policies' own Report and Act
        then find them done (report, act)."""
        plan = self.supervision.halt_plan(result.violated, result.t_ns)
        if plan is None:
            return
        rt = self.session.runtime
        recent = rt.recent
        stale = rt.stale_inputs()
        for i, armed in plan:
            template, encoded = self._templates[i], self._armed[i]
            if template is None or encoded is None or encoded[0] is not armed:
                return
            written = self.log.violation_row(  # type: ignore[attr-defined]
                template, row=recent[-1], recent=recent, stale=stale, policy_state=encoded[1]
            )
            if written is None:  # no plain JSON form: the policies' way
                return
            self._early[i] = armed
            self._submit(Request(self.session.requirements[i].id, armed.actions, result.t_ns))

    def _arm(self) -> None:
        """Each armed requirement's policy state encoded for the halt path, when it
        changed (made after a step's actions, not on the next halt's path)."""
        if not self._encode:
            return
        armed = self.supervision.armed
        if len(self._armed) != len(armed):
            self._armed = [None] * len(armed)
        for i, a in enumerate(armed):
            have = self._armed[i]
            if a is None:
                self._armed[i] = None
            elif have is None or have[0] is not a:
                self._armed[i] = (a, self._encode(a.policy_state))

    def _send(self) -> None:
        """The records report() wrote, to ``published``, in the order written."""
        unsent, self._unsent = self._unsent, []
        if self._published is None:
            return
        for item in unsent:
            if isinstance(item, dict):
                self._published(item)
                continue
            template, result, recent, stale, policy_state = item
            self._published(
                {
                    "requirement": template.requirement,
                    "text": template.text,
                    "formula": template.formula,
                    **template.extra,
                    "tick": result.tick,
                    "inputs": dict(result.inputs),
                    "recent": recent,
                    "stale": stale,
                    "policy_state": policy_state,
                }
            )

    def operator_reset(self, t: int, requirement: str | None = None, **extra: Any) -> list[str]:
        """Reset every requirement's monitor (or ``requirement``'s), lift the latches of
        those that hold; returns the refused ones as ``id (why)``.  An unknown id is a
        KeyError (the caller checks it first: nothing is reset)."""
        ids = [r.id for r in self.session.requirements]
        only = None if requirement is None else ids.index(requirement) if requirement in ids else -1
        if only == -1:
            raise KeyError(requirement)
        self.advance(t)
        target = {} if requirement is None else {"requirement": requirement}
        self._mark("operator_reset", t, **target, **extra)
        refused = [f"{ids[i]} ({why})" for i, why in self.supervision.operator_reset(only)]
        self._arm()
        tick = self.session.runtime.tick  # the next tick is judged afresh
        self.log.reset(
            "*" if requirement is None else requirement,
            reason="operator reset",
            refused=refused,
            tick=tick,
            **extra,
        )
        self._due = 0
        return refused

    def swap(self, new: Session) -> None:
        """Go on with ``new`` (a reloaded config); kept policies stay active.  Its
        runtime takes over the latest values, counts and tick (Runtime.adopt)."""
        new.runtime.adopt(self.session.runtime)
        self.session = new
        self.supervision = Supervision(new.runtime, new.policies, self)
        self.supervision.active = {i for i, p in enumerate(new.policies) if p.active}
        self._stale_after_ns = _stale_after_ns(new)
        self._limits = _limits(new, self._stale_after_ns)
        self._templates = _templates(new, self.log)
        self._encode = _encoder(new, self.log)
        self._early.clear()
        self._arm()
        self._due = 0
        if self.now is not None:
            self._mark("reload", self.now, config=new.config.path)

    # ------------------------------------------------------------ for the node
    # The daemon's ROS side (node.py and its parts) talks to the core only: what
    # it shows or counts of the runtime goes through these.

    @property
    def tick(self) -> int:
        """Steps taken so far (kept across a reload)."""
        return self.session.runtime.tick

    def step_due(self, t: int) -> int | None:
        """When the next timer-driven step is due (periodic timer, synchronized skew)."""
        return self.session.runtime.due(t)

    def input_stats(self) -> dict[str, dict[str, Any]]:
        """Per input: messages, rejected, nan, future, lost, own, stale, last_ns."""
        return self.session.runtime.input_stats()

    def stale_inputs(self) -> list[str]:
        return self.session.runtime.stale_inputs()

    def snapshot(self) -> dict[str, Any]:
        """Each input's latest value."""
        return self.session.runtime.snapshot()

    def missing_inputs(self) -> list[str]:
        """Inputs without a value yet: nothing is stepped until each has one."""
        return self.session.runtime.missing_inputs()

    def latest_margins(self) -> list[float | None]:
        """Each requirement's margin after the last step (status.py): the predictions'
        monitor's for a requirement with ``predict:``, else the monitor's with
        ``step.margins``; None where margins are off or before the first step."""
        rt = self.session.runtime
        n = len(self.session.requirements)
        if rt.tick == 0:
            return [None] * n
        predicted = rt.margins() if rt.margin_monitor is not None else None
        mon = rt.monitor
        every = mon.margins() if getattr(getattr(mon, "spec", None), "margins", False) else None
        out: list[float | None] = []
        for i, pol in enumerate(self.session.policies):
            source = predicted if pol.trend is not None else every
            out.append(None if source is None else float(source[i]))
        return out

    def count_own(self, name: str) -> None:
        """The daemon's own message came back on input ``name``'s topic (loss.py)."""
        self.session.runtime.count_own(name)

    def count_lost(self, name: str, n: int) -> None:
        """``n`` messages of input ``name`` never arrived (a sequence gap; loss.py)."""
        self.session.runtime.count_lost(name, n)

    def _mark(self, what: str, t: int, **fields: Any) -> None:
        if self._marker is not None:
            self._marker(what, t, fields)

    # ------------------------------------------------------------ Supervision's sink

    def report(
        self, index: int, result: StepResult, policy_state: dict[str, Any], **predicted: float
    ) -> None:
        s = self.session
        rt = s.runtime
        template = self._templates[index]
        early = self._early.get(index)
        if early is not None and not predicted and policy_state == early.policy_state:
            # written by the halt path (_halt_first), before the policies ran
            self.violations += 1
            if self._published is not None:
                stale = rt.stale_inputs()
                self._unsent.append((template, result, list(rt.recent), stale, policy_state))
            return
        if early is not None:  # not what the policy armed: a bug; the record stays whole
            # (its actions were submitted already: act() still finds them done)
            self.log.supervisor(
                "internal_error",
                where="halt path",
                error=f"{s.requirements[index].id}: the policy state differs from the armed one",
            )
        # a violation that followed a prediction carries its lead (predicted_ms), a
        # field the template does not have: it takes violation()'s whole way
        if template is not None and not predicted:
            # The record from its template (writer.ViolationTemplate): the same bytes
            # as violation() writes, with less work before the halt.  Written before
            # any action of this step is submitted, as below.
            stale = rt.stale_inputs()
            self.log.violation_from(  # type: ignore[attr-defined]
                template,
                tick=result.tick,
                inputs=result.inputs,
                recent=rt.recent,
                stale=stale,
                policy_state=policy_state,
            )
            self.violations += 1
            if self._published is not None:  # the dict made after the halt (_send)
                self._unsent.append((template, result, list(rt.recent), stale, policy_state))
            return
        req = s.requirements[index]
        record = {
            "requirement": req.id,
            "text": req.entry.text,
            "formula": s.formulas[index],
            **(
                {"formula_inputs": s.formulas_inputs[index]}
                if index < len(s.formulas_inputs) and s.formulas_inputs[index]
                else {}
            ),
            "tick": result.tick,
            "inputs": dict(result.inputs),
            "recent": list(rt.recent),
            "stale": rt.stale_inputs(),
            "policy_state": policy_state,
            **predicted,  # predicted_ms: the lead time of the prediction it followed
        }
        # Written before any action of this step is submitted: a record of every
        # violation exists even if an action hangs the machine.  The log's
        # durability decides whether it is also fsynced first (before_action) or
        # once the inline actions are out (after_publish; docs/reference/log.md).
        self.log.violation(**record)
        self.violations += 1
        if self._published is not None:
            self._unsent.append(record)

    def forecast(
        self, index: int, forecast: Forecast, result: StepResult | None, t_ns: int
    ) -> None:
        """A prediction's record, written before its early actions are submitted
        (docs/reference/prediction.md, "Records")."""
        req = self.session.requirements[index]
        if forecast.what == "prediction":
            inputs = dict(result.inputs) if result is not None else self.snapshot()
            self.predictions += 1
            self.log.prediction(req.id, **forecast.detail, inputs=inputs)
        else:
            self.log.prediction_expired(req.id, tick=self.session.runtime.tick, **forecast.detail)

    def act(self, index: int, actions: tuple[str, ...], stage: str, t_ns: int) -> None:
        early = self._early.pop(index, None)
        if early is not None and stage == "violation" and actions == early.actions:
            return  # submitted by the halt path (_halt_first)
        req = self.session.requirements[index]
        self._submit(Request(req.id, actions, t_ns, stage))

    def reset(self, index: int, reason: str) -> None:
        req = self.session.requirements[index]
        self.log.reset(req.id, reason=reason, tick=self.session.runtime.tick)

    def note(self, index: int, note: Note, t_ns: int) -> None:
        req = self.session.requirements[index]
        pol = self.session.policies[index]
        ok = note.what == "confirmed"
        since = pol.incident_ns
        self.log.mitigation(
            req.id,
            action=f"confirm:{note.detail.get('variable')}",
            kind="confirm",
            ok=ok,
            error=None
            if ok
            else (
                f"{note.detail.get('variable')} = {note.detail.get('actual')!r}, "
                f"expected {note.detail.get('expected')!r} within {note.detail.get('within_ms')} ms"
            ),
            latency_ms=0.0 if since is None else round((t_ns - since) / 1e6, 3),
        )
        if not ok:
            self.warn(f"mitigation of {req.id} did not take effect: {note.detail}")

    # ------------------------------------------------------------ inputs

    def input_events(self, events: list[InputEvent]) -> None:
        rt = self.session.runtime
        for ev in events:
            key = _COUNTED.get(ev.what)
            if key is not None:
                n = rt.input_stats()[ev.name][key]
                if n > REJECT_REPORT_FIRST and n % REJECT_REPORT_EVERY:
                    continue  # a flood is counted, and reported every 1000th
                verb = "rejected" if key == "rejected" else "accepted"
                self.warn(f"input '{ev.name}': {verb} {ev.detail} ({n} so far)")
                self.log.supervisor(ev.what, input=ev.name, detail=ev.detail, count=n)
                continue
            self.log.supervisor(ev.what, input=ev.name, detail=ev.detail)
            if ev.what == "input_stale":
                self.warn(f"input '{ev.name}' is stale: {ev.detail}")
                on_stale = self.session.config.on_stale
                if on_stale:
                    self._submit(Request(f"on_stale:{ev.name}", tuple(on_stale), ev.t_ns, "stale"))


def _templates(session: Session, log: Log) -> list[Any]:
    """Each requirement's violation template, made once per session (None: the
    log has no templates, or the record no plain JSON form; report() then builds
    the whole record)."""
    make = getattr(log, "violation_template", None)
    out: list[Any] = []
    for i, req in enumerate(session.requirements):
        if make is None:
            out.append(None)
            continue
        extra = (
            {"formula_inputs": session.formulas_inputs[i]}
            if i < len(session.formulas_inputs) and session.formulas_inputs[i]
            else {}
        )
        out.append(make(req.id, text=req.entry.text, formula=session.formulas[i], **extra))
    return out


def _encoder(session: Session, log: Log) -> Callable[[Any], str] | None:
    """How an armed policy state is encoded for the log's halt path; None when the
    log has none, or an input is named ``tick`` (a row of ``recent`` then has no
    tick of its own to take the record's from)."""
    names = {s.name for s in session.runtime.inputs}
    return encode_fragment if hasattr(log, "violation_row") and "tick" not in names else None


def _stale_after_ns(session: Session) -> int | None:
    ms = session.config.step.stale_after_ms
    return int(ms * 1e6) if ms else None


def _limits(session: Session, default_after_ns: int | None) -> dict[str, int | None]:
    """Each input's silence limit, looked up once per session (Core.fields runs per
    message)."""
    rt = session.runtime
    return {s.name: rt.stale_after(s.name, default_after_ns) for s in rt.inputs}
