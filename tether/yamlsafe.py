"""YAML for files users (or attackers) hand us: bounded, strict, and able to say where.

``yaml.safe_load`` constructs no objects, but it still expands aliases without limit (a
"billion laughs" file of a few hundred bytes hangs the process), recurses once per
nesting level (5,000 levels end in a RecursionError), and keeps the last of two equal
keys without a word. :func:`load_yaml` composes the document first, refuses it when it
is nested deeper than ``max_depth``, when its aliases would expand past ``max_nodes`` or
refer to themselves, or when a mapping repeats a key, and only then builds Python
values. Mappings come back as :class:`Located` dicts that remember the line of every key,
so a validator can name the line of the value it rejects.

>>> doc = load_yaml("a: 1\\nb: {c: 2}\\n", where="x.yaml")
>>> doc.line_of("b")
2
"""
from __future__ import annotations

from typing import Any

import yaml
from yaml.nodes import MappingNode, Node, SequenceNode

from tether.errors import ConfigError
from tether.paths import not_regular

MAX_DEPTH = 64
MAX_NODES = 100_000                 # after alias expansion
MAX_BYTES = 4 << 20

MERGE_TAG = "tag:yaml.org,2002:merge"


class Located(dict):
    """A mapping read from YAML: ``line`` is where it starts, ``line_of(key)`` where a key is (1-based),
    ``where`` the file (``where_of(key)`` when a mapping was merged from several files)."""

    line: int = 0
    where: str = ""
    key_lines: dict
    key_where: dict | None = None

    def line_of(self, key: Any, default: int | None = None) -> int:
        lines = getattr(self, "key_lines", None) or {}
        return lines.get(key, self.line if default is None else default)

    def where_of(self, key: Any = None) -> str:
        return (self.key_where or {}).get(key, self.where) if key is not None else self.where

    def derive(self, items: Any = None) -> "Located":
        """A copy (or ``items`` in its place) that still says where this mapping and its keys are."""
        out = Located(self if items is None else items)
        out.line, out.where, out.key_lines = self.line, self.where, dict(getattr(self, "key_lines", None) or {})
        out.key_where = dict(self.key_where) if self.key_where else None
        return out

    def merged_over(self, base: "Located") -> "Located":
        """``base`` updated with this mapping, every key remembering the file and line it came from."""
        out = self.derive({**base, **self})
        out.key_where = {k: base.where_of(k) for k in base} | {k: self.where_of(k) for k in self}
        out.key_lines = {k: base.line_of(k) for k in base} | {k: self.line_of(k) for k in self}
        return out


class _Limit(yaml.YAMLError):
    def __init__(self, line: int, text: str) -> None:
        super().__init__(text)
        self.line, self.text = line, text


class _Loader(yaml.SafeLoader):
    """SafeLoader with a nesting bound while composing (the C loader cannot be hooked)."""

    def __init__(self, stream: str, max_depth: int, where: str = "") -> None:
        super().__init__(stream)
        self._depth = 0
        self._max_depth = max_depth
        self._where = where

    def compose_node(self, parent: Node | None, index: Any) -> Node:
        self._depth += 1
        try:
            if self._depth > self._max_depth:
                mark = self.peek_event().start_mark
                raise _Limit(mark.line + 1, f"nested deeper than {self._max_depth} levels")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_located_map(self, node: MappingNode):
        data = Located()
        data.line = node.start_mark.line + 1
        data.where = self._where
        data.key_lines = {}
        yield data
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:            # before merging: `<<: *base` may be overridden
            if key_node.tag == MERGE_TAG:
                continue
            key = self.construct_object(key_node, deep=True)
            line = key_node.start_mark.line + 1
            try:
                first = seen.get(key)
            except TypeError:
                raise _Limit(line, f"a mapping key must be a scalar, not {type(key).__name__}") from None
            if first is not None:
                raise _Limit(line, f"duplicate key {key!r} (first on line {first})")
            seen[key] = data.key_lines[key] = line
        self.flatten_mapping(node)
        for key_node, value_node in node.value:
            key = self.construct_object(key_node, deep=True)
            data[key] = self.construct_object(value_node, deep=True)
            data.key_lines.setdefault(key, key_node.start_mark.line + 1)


_Loader.add_constructor("tag:yaml.org,2002:map", _Loader.construct_located_map)


def _expanded_size(root: Node, max_nodes: int) -> int:
    """Node count with every alias expanded; raises past ``max_nodes`` or on a self-referring alias."""
    memo: dict[int, int] = {}
    active: set[int] = set()

    def size(node: Node) -> int:
        key = id(node)
        if key in memo:
            return memo[key]
        if key in active:
            raise _Limit(node.start_mark.line + 1, "an alias refers to the node that contains it")
        active.add(key)
        total = 1
        if isinstance(node, SequenceNode):
            for child in node.value:
                total += size(child)
                if total > max_nodes:
                    break
        elif isinstance(node, MappingNode):
            for k, v in node.value:
                total += size(k) + size(v)
                if total > max_nodes:
                    break
        active.discard(key)
        if total > max_nodes:
            raise _Limit(node.start_mark.line + 1,
                         f"expands to more than {max_nodes} values (aliases nested like a 'billion laughs' file)")
        memo[key] = total
        return total

    return size(root)


def load_yaml(text: str | bytes, *, where: str, max_depth: int = MAX_DEPTH, max_nodes: int = MAX_NODES) -> Any:
    """Parse one YAML document with the limits above; :class:`ConfigError` ``"WHERE:LINE: why"`` otherwise."""
    if len(text) > MAX_BYTES:
        raise ConfigError(f"{where}: {len(text)} bytes is larger than a configuration file can be ({MAX_BYTES})")
    try:
        loader = _Loader(text, max_depth, where)    # the reader refuses control characters here
    except yaml.reader.ReaderError as exc:
        line = text[:exc.position].count("\n" if isinstance(text, str) else b"\n") + 1
        raise ConfigError(f"{where}:{line}: character {exc.character:#04x} is not allowed in YAML text "
                          "(a control character or a byte that is not UTF-8): remove it") from None
    try:
        root = loader.get_single_node()
        if root is None:
            return None
        _expanded_size(root, max_nodes)
        return loader.construct_document(root)
    except _Limit as exc:
        raise ConfigError(f"{where}:{exc.line}: {exc.text}") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = f":{mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{where}{line}: not valid YAML: {exc.problem or exc.context}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{where}: not valid YAML: {str(exc).splitlines()[0] if str(exc) else exc}") from None
    except RecursionError:       # a deep flow collection inside one scalar event: belt and braces
        raise ConfigError(f"{where}: nested too deeply") from None
    finally:
        loader.dispose()


def load_yaml_file(path: Any) -> Any:
    """:func:`load_yaml` of a file, naming it in every error."""
    from pathlib import Path

    path = Path(path)
    what = not_regular(path)
    if what:                                    # a FIFO without a writer blocks open() for ever
        raise ConfigError(f"{path}: {what}, not a configuration file (give a .yaml file)")
    try:
        with path.open("rb") as f:              # bounded: /dev/zero or a huge file is refused, not read to the end
            text = f.read(MAX_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror}") from None
    if len(text) > MAX_BYTES:
        raise ConfigError(f"{path}: larger than a configuration file can be ({MAX_BYTES} bytes)")
    try:
        decoded = text.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    return load_yaml(decoded, where=str(path))
