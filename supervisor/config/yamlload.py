"""YAML loading that remembers where every value came from.

Safety engineers edit the config by hand; every error must point at a line.
Mappings load as LineDict (with ``.line`` and ``.key_line(k)``) and sequences
as LineList (with ``.line`` and ``.item_line(i)``); duplicate keys are errors
(PyYAML silently keeps the last one, which would hide a typo'd requirement).
Numbers are finite (``.nan`` and ``.inf`` are errors, at their line) and
nesting is at most MAX_NESTING deep (docs/reference/config.md, "Limits").
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import yaml

from monitors.errors import UserError
from supervisor.config.imported import MAX_CONFIG_BYTES, decode, read_bytes

# PyYAML composes and constructs nested collections recursively; a config nests
# a few levels, so anything deeper is refused before composing.
MAX_NESTING = 50
# Values of the whole document with every alias expanded; a config has hundreds.
MAX_VALUES = 1_000_000


class LineDict(dict):
    line: int = 0
    file: str = ""
    _key_lines: dict[str, int]

    def key_line(self, key: str) -> int:
        return self._key_lines.get(key, self.line)


class LineList(list):
    line: int = 0
    file: str = ""
    _item_lines: list[int]

    def item_line(self, i: int) -> int:
        return self._item_lines[i] if i < len(self._item_lines) else self.line


class LineStr(str):
    line: int = 0
    col: int = 0
    file: str = ""


def _make_loader(file: str) -> type[yaml.SafeLoader]:
    class Loader(yaml.SafeLoader):
        pass

    def construct_mapping(loader: yaml.SafeLoader, node: yaml.MappingNode) -> LineDict:
        out = LineDict()
        out.line = node.start_mark.line + 1
        out.file = file
        out._key_lines = {}
        loader.flatten_mapping(node)
        for key_node, value_node in node.value:
            key = loader.construct_object(key_node, deep=True)
            if not isinstance(key, str | int | float | bool) or key is None:
                raise UserError(
                    "mapping keys must be plain names", file=file, line=key_node.start_mark.line + 1
                )
            key = str(key)
            if key in out:
                raise UserError(
                    f"duplicate key '{key}' (first at line {out._key_lines[key]})",
                    file=file,
                    line=key_node.start_mark.line + 1,
                )
            out[key] = loader.construct_object(value_node, deep=True)
            out._key_lines[key] = key_node.start_mark.line + 1
        return out

    def construct_sequence(loader: yaml.SafeLoader, node: yaml.SequenceNode) -> LineList:
        out = LineList(loader.construct_object(n, deep=True) for n in node.value)
        out.line = node.start_mark.line + 1
        out.file = file
        out._item_lines = [n.start_mark.line + 1 for n in node.value]
        return out

    def construct_str(loader: yaml.SafeLoader, node: yaml.ScalarNode) -> LineStr:
        s = LineStr(loader.construct_scalar(node))
        s.line = node.start_mark.line + 1
        # Plain scalars start where the text starts; quoted ones one column later.
        s.col = node.start_mark.column + 1 + (1 if node.style in ("'", '"') else 0)
        s.file = file
        return s

    def construct_float(loader: yaml.SafeLoader, node: yaml.ScalarNode) -> float:
        x = yaml.SafeLoader.construct_yaml_float(loader, node)
        if not math.isfinite(x):
            raise UserError(
                f"'{node.value}' is not a finite number",
                file=file,
                line=node.start_mark.line + 1,
                col=node.start_mark.column + 1,
                hint="every number in the config must be finite",
            )
        return x

    def construct_int(loader: yaml.SafeLoader, node: yaml.ScalarNode) -> int:
        try:
            return yaml.SafeLoader.construct_yaml_int(loader, node)
        except ValueError:  # more digits than Python converts (sys.get_int_max_str_digits)
            raise UserError(
                f"number '{node.value[:20]}...' is too long",
                file=file,
                line=node.start_mark.line + 1,
                col=node.start_mark.column + 1,
            ) from None

    Loader.add_constructor("tag:yaml.org,2002:float", construct_float)
    # A date-like scalar stays text: no key takes a date, and a bad one
    # (2001-13-45) would otherwise fail inside PyYAML with no line.
    Loader.add_constructor("tag:yaml.org,2002:timestamp", construct_str)
    Loader.add_constructor("tag:yaml.org,2002:int", construct_int)
    Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, construct_mapping)
    Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_SEQUENCE_TAG, construct_sequence)
    Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_SCALAR_TAG, construct_str)
    return Loader


def load_yaml(path: Path | str, text: str | None = None) -> Any:
    """Parse a YAML file; syntax errors become UserError at the offending line."""
    file = str(path)
    if text is None:
        text = decode(read_bytes(path, "config", MAX_CONFIG_BYTES), file)
    loader = _make_loader(file)
    try:
        _check_nesting(text, loader, file)
        return yaml.load(text, Loader=loader)  # noqa: S506 - SafeLoader subclass
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        line = mark.line + 1 if mark else None
        col = mark.column + 1 if mark else None
        raise UserError(
            f"invalid YAML: {e.problem or e.context}", file=file, line=line, col=col
        ) from None
    except yaml.YAMLError as e:
        raise UserError(f"invalid YAML: {e}", file=file) from None


def _check_nesting(text: str, loader: type[yaml.SafeLoader], file: str) -> None:
    """Refuse collections nested deeper than MAX_NESTING, and aliases that expand
    to more than MAX_VALUES values (a "billion laughs": a few lines whose value,
    once printed in an error, fills memory).  PyYAML's event parser keeps an
    explicit stack (no recursion), so this pass sees any depth."""
    level = 0
    sizes: dict[str, int] = {}  # anchor -> values it expands to
    # values in each open collection (and the whole document), with its anchor
    counts: list[list[Any]] = [[None, 0]]
    for event in yaml.parse(text, Loader=loader):
        if isinstance(event, yaml.CollectionStartEvent):
            level += 1
            if level > MAX_NESTING:
                raise UserError(
                    f"nested more than {MAX_NESTING} levels deep",
                    file=file,
                    line=event.start_mark.line + 1,
                    col=event.start_mark.column + 1,
                )
            counts.append([event.anchor, 1])
            continue
        if isinstance(event, yaml.CollectionEndEvent):
            level -= 1
            anchor, n = counts.pop()
        elif isinstance(event, yaml.AliasEvent):
            n, anchor = sizes.get(str(event.anchor), 1), None
        elif isinstance(event, yaml.ScalarEvent):
            n, anchor = 1, event.anchor
        else:
            continue
        counts[-1][1] += n
        if counts[-1][1] > MAX_VALUES:
            raise UserError(
                f"expands to more than {MAX_VALUES} values (YAML aliases)",
                file=file,
                line=event.start_mark.line + 1,
                col=event.start_mark.column + 1,
            )
        if anchor is not None:
            sizes[str(anchor)] = n


def line_of(value: object, default: int | None = None) -> int | None:
    return getattr(value, "line", None) or default
