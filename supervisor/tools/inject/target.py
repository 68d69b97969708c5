"""What an injection is aimed at: one loaded project's requirements (those z3 can
encode), its input variables and topics, and the states the supervisor steps on
when a trace is published there."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from monitors.ir.formula import Formula, Past, Pre, Since, subterms
from monitors.verify.analysis import range_formula
from monitors.verify.bmc import Encoder, Unsupported, fresh_rows
from supervisor.pipeline import Project
from supervisor.tools.inject.fields import field_domains
from supervisor.tools.inject.schedule import observed, schedule_of, span, topics_of
from supervisor.validation import project_requirements

WARMUP = 5  # copies of the first tick before the injection (10 Hz)


def lookback(f: Formula) -> int:
    """Ticks of history ``f`` can see: its verdicts on a state repeated more than
    this many times no longer change (bounded windows are full of it, unbounded
    operators have reached their fixed point)."""
    depth: dict[Formula, int] = {}
    for g in subterms(f):  # children first
        kids = [depth[c] for c in g.children()]
        own = 0
        if isinstance(g, Pre):
            own = 1  # the previous tick's value (init only at tick 0)
        elif isinstance(g, Past):
            own = 1 if g.op in ("Y", "Z") else (g.hi if g.hi is not None else (g.lo or 0) + 1)
        elif isinstance(g, Since):
            own = g.hi if g.hi is not None else (g.lo or 0) + 1
        depth[g] = max(kids, default=0) + own
    return depth[f]


class Target:
    """One loaded project as inject sees it."""

    def __init__(self, project: Project, *, warmup: int = WARMUP) -> None:
        cfg = project.config
        self.cfg = cfg
        self.warmup = warmup
        reqs, infos = project_requirements(project)
        self.reqs = {r.id: r for r in reqs}
        self.inputs = [v.name for v in cfg.inputs]
        self.types = {v.name: v.type for v in cfg.inputs}
        # declared ranges, rounded as the analyses do
        self.ranges: dict[str, Formula] = {}
        for v in infos:
            rf = range_formula(v)
            if rf is not None and v.name in self.types:
                self.ranges[v.name] = rf
        self.topics = topics_of(cfg)
        self.schedule = schedule_of(cfg, self.topics)
        self.domains = field_domains(cfg)
        self.unsupported: dict[str, str] = {}
        self._check_encodable()
        # constant-state saturation: a state repeated this often looks the same to
        # every requirement as one repeated forever
        self.saturation = max([2] + [lookback(r.formula) + 1 for r in self.reqs.values()])

    def _check_encodable(self) -> None:
        rows = fresh_rows(self.types, self.inputs, 1, "chk")
        enc = Encoder(self.types, rows)
        for rid, r in list(self.reqs.items()):
            try:
                enc.holds(r.formula)
            except Unsupported as e:
                self.unsupported[rid] = str(e)
                del self.reqs[rid]

    # -------------------------------------------------------------- what the supervisor sees

    def observed(
        self, rows: Sequence[Mapping[str, Any]], warm: int, tail: int, repeat: int | None = None
    ) -> tuple[list, list[int]]:
        """The states the supervisor steps on when ``rows`` is published (see
        :func:`schedule.observed`), and the tick of each state."""
        return observed(self.schedule, self.inputs, rows, warm, tail, repeat)

    @staticmethod
    def span(labels: list[int], t: int) -> tuple[int, int]:
        """First and last index of tick ``t``'s states."""
        return span(labels, t)

    def variants(self) -> list[int]:
        """Warm-up copies the supervisor may see: 1..warmup (a freshly matched topic's
        first samples can be late), or saturated (it has seen the nominal state for
        long, as in ``--all``)."""
        s = self.saturation  # more copies than this look like exactly this many
        return sorted({min(r, s) for r in range(1, self.warmup + 1)} | {s})
