"""ROS message types from wherever they are: a recording's own definitions, the
installed interface packages (``share/<pkg>/msg|srv|action``) and rosbags' Jazzy
types, in that order of trust unless the recording's differ from the installed ones
(docs/reference/commands.md, "replay": "Types").

One implementation for the daemon's recorder (the types it describes in a bag) and
for replay (the types it decodes a bag with); type names are written as
``mitigations/rosmsg.py``, the one type lookup, writes them."""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Container, Iterable, Sequence
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype

from mitigations.rosmsg import normalise_type

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

Fielddefs = dict[str, Any]  # rosbags' name -> (constants, fields)

# What rosidl generates around a .srv and an .action file (rosidl_adapter and
# rosidl_parser's action definitions): the names and the text of each part.
_SRV_EVENT = (
    "service_msgs/ServiceEventInfo info\n{b}_Request[<=1] request\n{b}_Response[<=1] response\n"
)
_ACTION_PARTS = {
    "_SendGoal_Request": "unique_identifier_msgs/UUID goal_id\n{b}_Goal goal\n",
    "_SendGoal_Response": "bool accepted\nbuiltin_interfaces/Time stamp\n",
    "_GetResult_Request": "unique_identifier_msgs/UUID goal_id\n",
    "_GetResult_Response": "int8 status\n{b}_Result result\n",
    "_FeedbackMessage": "unique_identifier_msgs/UUID goal_id\n{b}_Feedback feedback\n",
}
_SEPARATOR = re.compile(r"^---[ \t]*$", re.MULTILINE)


def msg_search_prefixes() -> list[Path]:
    """Where installed ROS packages keep ``share/<pkg>/msg/*.msg``: the ament
    prefixes, and this Python's prefix (the ros-jazzy-* wheels install there)."""
    prefixes = [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(":") if p]
    return [*prefixes, Path(sys.prefix)]


def _names(node: tuple[Any, Any]) -> Iterable[str]:
    kind, payload = node
    if kind == Nodetype.NAME:
        yield payload
    elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        yield from _names(payload[0])


def _renamed(node: tuple[Any, Any], names: dict[str, str]) -> tuple[Any, Any]:
    kind, payload = node
    if kind == Nodetype.NAME:
        return kind, _unmangled(names.get(payload, payload))
    if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        return kind, (_renamed(payload[0], names), payload[1])
    return node


def _unmangled(name: str) -> str:
    """rosbags reads a reference 'pkg/srv/X' as 'pkg/srv/msg/X': back to ROS's name."""
    return name.replace("/srv/msg/", "/srv/").replace("/action/msg/", "/action/")


def _parse(text: str, pkg: str, kind: str, short: str, siblings: Sequence[str]) -> Fielddefs:
    """One part of an interface file as ``pkg/kind/short``.  rosbags parses a
    message of ``pkg/msg`` only; the parts of one .srv or .action refer to each other
    by short name, which rosbags resolves into ``pkg/msg``: those are renamed."""
    found = get_types_from_msg(text, f"{pkg}/msg/{short}")
    names = {f"{pkg}/msg/{s}": f"{pkg}/{kind}/{s}" for s in (short, *siblings)}
    return {
        _unmangled(names.get(k, k)): (consts, [(f, _renamed(t, names)) for f, t in fields])
        for k, (consts, fields) in found.items()
    }


def _base(kind: str, short: str) -> str:
    """The interface file's name of a type: 'Fibonacci_SendGoal_Request' ->
    'Fibonacci' for an action, 'BasicTypes_Event' -> 'BasicTypes' for a service."""
    if kind == "srv":
        return re.sub(r"_(Request|Response|Event)$", "", short)
    if kind == "action":
        parts = (
            r"Goal|Result|Feedback|FeedbackMessage|(SendGoal|GetResult)_(Request|Response|Event)"
        )
        return re.sub(rf"_({parts})$", "", short)
    return short


def _siblings(kind: str, base: str) -> list[str]:
    """The types one .srv or .action file makes, which refer to each other."""
    if kind == "srv":
        return [f"{base}_Request", f"{base}_Response", f"{base}_Event"]
    if kind == "action":
        calls = [
            f"{base}_{c}_{p}"
            for c in ("SendGoal", "GetResult")
            for p in ("Request", "Response", "Event")
        ]
        return [
            f"{base}_Goal",
            f"{base}_Result",
            f"{base}_Feedback",
            f"{base}_FeedbackMessage",
            *calls,
        ]
    return []


def _interface_file(pkg: str, kind: str, short: str, prefixes: Sequence[Path]) -> Fielddefs:
    """Every type one installed .msg, .srv or .action file defines that is named
    ``short`` or of which ``short`` is a part; empty if no file is installed."""
    if kind not in ("msg", "srv", "action"):
        return {}
    base = _base(kind, short)
    for prefix in prefixes:
        path = prefix / "share" / pkg / kind / f"{base}.{kind}"
        if path.is_file():
            return _file_types(str(path), pkg, kind, base)
    return {}


@cache
def _file_types(path: str, pkg: str, kind: str, base: str) -> Fielddefs:
    text = Path(path).read_text(encoding="utf-8")
    if kind == "msg":
        return _parse(text, pkg, kind, base, ())
    parts = _SEPARATOR.split(text)
    out: Fielddefs = {}
    if kind == "srv" and len(parts) == 2:
        names = [f"{base}_Request", f"{base}_Response", f"{base}_Event"]
        for short, part in zip(names, [*parts, _SRV_EVENT.format(b=base)], strict=True):
            out.update(_parse(part, pkg, kind, short, names))
    elif kind == "action" and len(parts) == 3:
        own = {f"{base}{s}": t.format(b=base) for s, t in _ACTION_PARTS.items()}
        texts = {
            f"{base}_Goal": parts[0],
            f"{base}_Result": parts[1],
            f"{base}_Feedback": parts[2],
            **own,
        }
        for call in ("SendGoal", "GetResult"):
            texts[f"{base}_{call}_Event"] = _SRV_EVENT.format(b=f"{base}_{call}")
        for short, part in texts.items():
            out.update(_parse(part, pkg, kind, short, list(texts)))
    return out


def installed_types(
    name: str, prefixes: Sequence[Path] | None = None, have: Container[str] = ()
) -> Fielddefs:
    """``name`` and every type it uses that is not in ``have``, from the installed
    interface files.  Raises LookupError naming the first type without one."""
    prefixes = msg_search_prefixes() if prefixes is None else prefixes
    found: Fielddefs = {}
    pending = [name]
    while pending:
        typ = pending.pop()
        if typ in found or typ in have:
            continue
        pkg, kind, short = ([*typ.split("/"), "", ""])[:3]
        got = _interface_file(pkg, kind, short, prefixes) if pkg and short else {}
        if typ not in got:
            dirs = ", ".join(str(p / "share" / pkg / kind) for p in prefixes)
            raise LookupError(f"no installed interface file for {typ} (searched {dirs})")
        found[typ] = got[typ]
        pending.extend(n for _f, t in got[typ][1] for n in _names(t))
    return found


def load_msg_types(
    typestore: Typestore, msgtype: str, prefixes: Sequence[Path] | None = None
) -> None:
    """Registers ``msgtype`` and every type it uses that ``typestore`` lacks, from
    the installed interface files.  Raises LookupError naming a type without one."""
    found = installed_types(msgtype, prefixes, typestore.fielddefs)
    typestore.register({k: v for k, v in found.items() if k not in typestore.fielddefs})


def _bag_types(defs: Iterable[tuple[str, str, str]]) -> tuple[Fielddefs, set[str]]:
    """The types a recording defines (name, encoding, text), and the names of those
    whose definition parsed."""
    types: Fielddefs = {}
    parsed: set[str] = set()
    for name, encoding, text in defs:
        if not text:
            continue
        typ = normalise_type(name)
        try:
            if encoding in ("ros2idl", "idl"):
                sep = "=" * 80 + "\n"
                parts = text.split(sep)[1:] if text.startswith(f"{sep}IDL: ") else [text]
                for part in parts:
                    types.update(
                        get_types_from_idl(
                            part.split("\n", 1)[1] if part.startswith("IDL: ") else part
                        )
                    )
            else:
                pkg, kind, short = ([*typ.split("/"), "", ""])[:3]
                if kind == "srv" and _SEPARATOR.search(text):
                    # rosbag2 stores a service's .srv text as its event's definition
                    parts = _SEPARATOR.split(text)
                    base = short.removesuffix("_Event")
                    names = [f"{base}_Request", f"{base}_Response", f"{base}_Event"]
                    for s, part in zip(names, [*parts, _SRV_EVENT.format(b=base)], strict=True):
                        types.update(_parse(part, pkg, kind, s, names))
                    parsed.update(f"{pkg}/srv/{n}" for n in names)
                else:
                    # a service's or action's part written out as a message (the
                    # daemon's recorder does): its siblings keep their srv/action names
                    siblings = _siblings(kind, _base(kind, short))
                    types.update(_parse(text, pkg, kind or "msg", short, siblings))
        except Exception:  # noqa: BLE001 - a definition rosbags cannot parse: not the bag's
            continue
        if typ in types:
            parsed.add(typ)
    return types, parsed


def _closure(name: str, *sources: Fielddefs, partial: bool = False) -> Fielddefs | None:
    """``name`` and what it uses, each from the first source that has it; None if
    one is in no source, unless ``partial`` (then what was found)."""
    out: Fielddefs = {}
    pending = [name]
    while pending:
        typ = pending.pop()
        if typ in out:
            continue
        fd = next((s[typ] for s in sources if typ in s), None)
        if fd is None:
            if partial:
                continue
            return None
        out[typ] = fd
        pending.extend(n for _f, t in fd[1] for n in _names(t))
    return out


def _fields(types: Fielddefs) -> dict[str, Any]:
    """What REP-2011's hash covers: field names and types, not constants."""
    return {k: v[1] for k, v in types.items()}


def _hash(name: str, types: Fielddefs) -> str | None:
    store = get_typestore(Stores.EMPTY)
    try:
        store.register(types)
        return str(store.hash_rihs01(name))
    except Exception:  # noqa: BLE001 - a type rosbags cannot hash is compared as unknown
        return None


def typestore_of(
    defs: Iterable[tuple[str, str, str]],
    used: Iterable[str] = (),
    said: list[str] | None = None,
    label: str = "",
    prefixes: Sequence[Path] | None = None,
) -> Typestore:
    """Types to decode a recording with (docs/reference/commands.md, "replay").

    For each ``used`` type: the installed interface package's when the recording
    does not define it, defines it as something that does not parse, or defines it
    otherwise (a different REP-2011 hash, as rosbag2's stub definitions); else the
    recording's own.  rosbags' Jazzy types stand in for a package not installed,
    but never over a definition of the recording that parses.  Each type used
    instead of the recording's definition is said in ``said``, one line each.

    The same definitions give the same store, kept (a few, the last used): bags of
    one robot define the same types, and making the store and its classes took a
    fifth of a small bag's replay (docs/BENCHMARKS.md, "Fleet").  Readers only read
    a store, and rosbags' generated deserializers come with it."""
    key = (
        tuple(defs),
        tuple(used),
        tuple(prefixes) if prefixes is not None else os.environ.get("AMENT_PREFIX_PATH"),
    )
    kept = _stores.pop(key, None)
    if kept is None:
        kept = _typestore(list(key[0]), key[1], prefixes)
    _stores[key] = kept  # the last used, last out
    while len(_stores) > STORES_KEPT:
        del _stores[next(iter(_stores))]
    store, replaced = kept
    if said is not None:
        for typ, theirs, where, inst_hash in replaced:
            said.append(
                f"warning: {label}: type {typ}: the recording's definition ({theirs}) "
                f"is not {where} (hash {inst_hash}): decoded with that one"
            )
    return store


STORES_KEPT = 8
# (definitions, types used, where installed types are) -> the store, and the types
# it decodes otherwise than the recording defines them (said by typestore_of)
_stores: dict[tuple[Any, ...], tuple[Typestore, list[tuple[str, str, str, str]]]] = {}


def _typestore(
    defs: list[tuple[str, str, str]], used: Iterable[str], prefixes: Sequence[Path] | None
) -> tuple[Typestore, list[tuple[str, str, str, str]]]:
    replaced: list[tuple[str, str, str, str]] = []
    bag, parsed = _bag_types(defs)
    defined = {normalise_type(name) for name, _enc, text in defs if text}
    defined |= {f"{n}_Event" for n in defined if "/srv/" in n}
    jazzy = get_typestore(Stores.ROS2_JAZZY).fielddefs
    chosen: Fielddefs = dict(bag)
    for typ in dict.fromkeys(normalise_type(u) for u in used):
        try:
            inst: Fielddefs | None = installed_types(typ, prefixes)
            where = f"the one installed in {typ.split('/', 1)[0]}"
        except Exception:  # noqa: BLE001 - none installed, or a file rosbags cannot parse
            if typ in parsed:
                continue
            inst = _closure(typ, jazzy)
            where = "rosbags' Jazzy one"
        if inst is None:
            continue
        if typ in defined:
            # both sides hashed by rosbags, so that its reading of byte and char (as
            # uint8) does not make equal types differ
            own = _closure(typ, bag, inst, jazzy) if typ in parsed else None
            if own is not None and _fields(own) == _fields(inst):
                continue  # the same fields, so the same hash: no need to compute it
            inst_hash = _hash(typ, inst)
            bag_hash = _hash(typ, own) if own else None
            if bag_hash is not None and bag_hash == inst_hash:
                continue
            theirs = f"hash {bag_hash}" if bag_hash else "does not parse"
            replaced.append((typ, theirs, where, str(inst_hash)))
        chosen.update(inst)
    # Only what the recording's types use (and the daemon's records, std_msgs/String):
    # making a class of each of rosbags' 170 Jazzy types costs 0.1 s per bag.
    needed: Fielddefs = {}
    for typ in [*chosen, "std_msgs/msg/String"]:
        needed.update(_closure(typ, chosen, jazzy, partial=True) or {})
    store = get_typestore(Stores.EMPTY)
    store.register(needed)
    return store, replaced
