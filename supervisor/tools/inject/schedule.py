"""What the supervisor steps on when a trace is published: the topics in the
order they are sent (the trigger's last), and the states the step policy makes
of the published ticks (for ``on_message`` the half-updated states between two
ticks too, for ``periodic`` each tick sampled more than once)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from supervisor.inputs.readers import kind_of, plain_field
from supervisor.tools.inject.errors import InjectError


@dataclass
class Topic:
    """One published topic: its message type and the variables it carries."""

    name: str
    msg: str
    fields: list[tuple[str, str]]  # (variable, field path)


@dataclass
class Schedule:
    """How the step policy turns published ticks into the states it steps on."""

    policy: str
    topic_of: dict[str, int]  # variable -> index of its topic in publishing order
    repeat: int = 1  # periodic: each tick is sampled about this many times


def topics_of(cfg: Any) -> list[Topic]:
    """The topics to publish, in config order with the trigger's topic last."""
    out: dict[str, Topic] = {}
    for v in cfg.inputs:
        if plain_field(v) is None:
            # a value made of a whole message (an array, a stamp, a call) has no one
            # field to set: inject writes traces of plain fields (docs/reference/commands.md)
            raise InjectError(
                f"{cfg.path}:{v.line}: variable '{v.name}' is a {kind_of(v)} read "
                f"{'through reduce: ' + str(v.reduce) if v.reduce else 'of a whole message'}"
                "; inject publishes one field per variable, so it cannot drive this config"
            )
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


def schedule_of(cfg: Any, topics: list[Topic]) -> Schedule:
    topic_of = {n: i for i, t in enumerate(topics) for n, _ in t.fields}
    repeat = 2 if cfg.step.policy == "periodic" else 1
    return Schedule(cfg.step.policy, topic_of, repeat)


def observed(
    sch: Schedule,
    inputs: Sequence[str],
    rows: Sequence[Mapping[str, Any]],
    warm: int,
    tail: int,
    repeat: int | None = None,
) -> tuple[list, list[int]]:
    """The states the supervisor steps on when ``rows`` is published: ``warm``
    copies of tick 0, the ticks 1..k-1 as the step policy makes them (each
    ``repeat`` times: periodic sampling), then ``tail`` steps back on tick 0 (the
    nominal state, labelled -1).  Works on z3 rows and on concrete ones alike.
    Returns (states, the tick of each state)."""
    repeat = sch.repeat if repeat is None else repeat
    states: list = [rows[0]] * warm
    labels = [0] * warm

    def tick(prev: Mapping[str, Any], cur: Mapping[str, Any]) -> list:
        if sch.policy == "on_message":
            # every topic is published each tick, in a fixed order, and each
            # message is a step: after message j the topics up to j are new
            m = max(sch.topic_of.values()) + 1
            return [
                {n: (cur[n] if sch.topic_of[n] <= j else prev[n]) for n in inputs} for j in range(m)
            ]
        return [cur] * repeat

    for t in range(1, len(rows)):
        step = tick(rows[t - 1], rows[t])
        states += step
        labels += [t] * len(step)
    back = tick(rows[-1], rows[0])
    back += [rows[0]] * max(0, tail - len(back))
    return states + back, labels + [-1] * len(back)


def span(labels: list[int], t: int) -> tuple[int, int]:
    """First and last index of tick ``t``'s states."""
    return labels.index(t), len(labels) - 1 - labels[::-1].index(t)
