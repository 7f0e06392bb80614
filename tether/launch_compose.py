"""Launch files for real projects: ``args`` and ``$(arg NAME)``, ``include`` under a namespace,
``remap`` and ``params_file``, flattened into one list of nodes for :mod:`tether.launch` to validate.

::

    name: two-sonars
    args:
      range_m: 20                       # a default; `tether launch f.yaml --arg range_m=30` overrides
      scene: {default: tripod, description: the simulated scene}
      address: null                     # required: no default
    include:
      - file: sonar_sim_imager.yaml     # relative to this file
        namespace: port                 # its nodes become port.sim, port.imager; topics port.imager/image
        args: {range_m: $(arg range_m)}
        remap: {nav/pose: ins/pose}     # its nodes' input from nav/pose take ins/pose (of this file)
    nodes:
      - id: imager
        node: nodes.sonar.polar_imager:PolarImager
        params_file: params/imager.yaml # merged under `params` (params win)
        params: {width_px: $(arg width)}
        inputs: {ping: port.sonar/ping}
        remap: {port.sonar/ping: starboard.sonar/ping}   # an input's source ...
                                                          # ... or an output: `image: fan` names it fan

Scoping is lexical: a source names a node of its own file (or ``ns.node`` of a file that file
includes); a name the file does not define is looked up in the file that includes it, and so
on up. ``$(arg NAME)`` alone keeps the argument's type (``20`` stays a number); inside text it
is formatted. ``$(dirname)`` is the absolute folder of the file it is written in (of the included
file, in an include), as in ROS launch files: ``scene: $(dirname)/../sim/scenes/x.yaml`` finds the
scene wherever ``tether launch`` is run from (a plain relative path is relative to that folder).
Command-line args set the top file's args only; a file passes values down with ``include: args:``.
An output remap renames the output in the launch graph (what other nodes and ``tether graph``
call it); on the wire the topic stays ``<id>/<output>``, as the runtime has no topic map. Every
error is one :class:`ConfigError` line naming the file and line.
"""
from __future__ import annotations

import difflib
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from tether.errors import ConfigError
from tether.yamlsafe import Located, load_yaml_file

ARG_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_\-]*$")
NAMESPACE_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_\-]*(\.[A-Za-z][A-Za-z0-9_\-]*)*$")
SUBST_RE = re.compile(r"\$\(([^()]*)\)")
TIMER_RE = re.compile(r"^timer/")
TOP_KEYS = {"name", "nodes", "machines", "description", "links", "args", "include"}
INCLUDE_KEYS = {"file", "namespace", "args", "remap"}
ARG_SPEC_KEYS = {"default", "description"}
MAX_INCLUDE_DEPTH = 8
MAX_NODES = 2000
MAX_INCLUDES = 500                                      # files read in all, counting repeats
_REQUIRED = object()
_DIRNAME = "$dirname"                                  # where $(dirname) waits among the args (not an arg name)


def at(mapping: Any, key: Any = None, fallback: str = "") -> str:
    """``FILE:LINE`` of ``key`` in a mapping read by :func:`load_yaml`."""
    if isinstance(mapping, Located):
        return f"{mapping.where_of(key) or fallback}:{mapping.line_of(key) if key is not None else mapping.line}"
    return fallback


def _hint(name: str, known: Any) -> str:
    close = difflib.get_close_matches(name, sorted(known), n=1)
    return f"did you mean {close[0]!r}?" if close else f"declared: {', '.join(sorted(known)) or 'none'}"


@dataclass
class Draft:
    """One node on its way up the include tree: ids and sources relative to the file being composed."""

    raw: Any                                            # the node mapping, arguments substituted
    where: str
    index: int = 0                                      # its place in its file's 'nodes'
    rel_id: str = ""
    resolved: dict[str, str] = field(default_factory=dict)   # input -> topic, relative to the current file
    pending: dict[str, str] = field(default_factory=dict)    # input -> a name the files so far do not define
    remapped: dict[str, str] = field(default_factory=dict)   # input -> "FILE:LINE: remap A -> B" (for errors)
    aliases: dict[str, str] = field(default_factory=dict)    # output alias -> the class's output name
    alias_at: dict[str, str] = field(default_factory=dict)   # output alias -> "FILE:LINE" of its remap


@dataclass
class Composed:
    """A launch file with its includes flattened: node mappings ready for validation."""

    doc: Located                                        # the top file, args substituted
    nodes: list[Draft]
    machines: Located                                   # name -> spec, each remembering its file
    links: list[tuple[str, Any]]                        # ("FILE:LINE: links[k]", raw link)


def compose(path: Path, args: Mapping[str, Any] | None = None) -> Composed:
    """Read ``path`` and everything it includes; ``args`` are the command line's (``--arg``)."""
    composed = _compose(path, dict(args or {}), None, (), [0, 0])
    for draft in composed.nodes:                       # what no file defines stays as written
        draft.resolved.update(draft.pending)
        draft.pending.clear()
    return composed


def _compose(path: Path, given: dict[str, Any], given_at: Located | None, stack: tuple[Path, ...],
             count: list[int]) -> Composed:
    where = str(path)
    doc = load_yaml_file(path)
    if not isinstance(doc, dict):
        raise ConfigError(f"{where}: a launch file is a mapping with 'name' and 'nodes'")
    for key in doc:
        if key not in TOP_KEYS:
            raise ConfigError(f"{at(doc, key, where)}: unknown key {key!r} ({_hint(str(key), TOP_KEYS)})")
    here = {_DIRNAME: str(path.resolve().parent)}         # $(dirname), beside the args
    values = _arguments(where, doc, given, given_at, here)
    body = _substitute(doc.derive({k: v for k, v in doc.items() if k != "args"}), {**values, **here}, where)
    raw_nodes = body.get("nodes")
    if raw_nodes is not None and not isinstance(raw_nodes, list) or raw_nodes == [] and not body.get("include"):
        raise ConfigError(f"{at(body, 'nodes', where)}: 'nodes' must be a non-empty list")
    drafts = [_draft(where, i, raw) for i, raw in enumerate(raw_nodes or [])]
    count[0] += len(drafts)
    machines = body.get("machines")
    if machines is not None and not isinstance(machines, Located):
        raise ConfigError(f"{at(body, 'machines', where)}: 'machines' must map a name to {{host, port_base}}")
    machines = machines if machines is not None else Located()
    links = [(f"{at(body.get('links'), fallback=where)}: links[{k}]", raw)
             for k, raw in enumerate(_list(body, "links", where))]
    for k, inc in enumerate(_list(body, "include", where)):
        sub = _include(where, k, inc, stack + (path.resolve(),), count)
        ns, used = inc.get("namespace") or "", set()
        for draft in sub.nodes:
            _adopt(draft, ns, inc, used)
        _check_include_remaps(where, inc, used)
        drafts += sub.nodes
        for name in sub.machines:
            if name in machines and machines[name] != sub.machines[name]:
                raise ConfigError(f"{at(sub.machines, name, where)}: machine {name!r} is declared differently "
                                  f"in {at(machines, name, where)}")
        machines = machines.merged_over(sub.machines) if sub.machines else machines
        names = {d.rel_id for d in sub.nodes}
        links += [(link_at, _prefix_link(raw, ns, names)) for link_at, raw in sub.links]
        if count[0] > MAX_NODES:
            raise ConfigError(f"{at(inc, 'file', where)}: the includes expand to more than {MAX_NODES} nodes")
    if not drafts:
        raise ConfigError(f"{at(body, 'nodes', where)}: 'nodes' must be a non-empty list")
    scope = {d.rel_id for d in drafts}
    for draft in drafts:
        for name, text in list(draft.pending.items()):
            if TIMER_RE.match(text) or text.partition("/")[0] in scope:
                draft.resolved[name] = draft.pending.pop(name)
    return Composed(doc=body, nodes=drafts, machines=machines, links=links)


def _list(body: Located, key: str, where: str) -> list:
    value = body.get(key)
    if value is None:
        return []
    if not isinstance(value, list):
        raise ConfigError(f"{at(body, key, where)}: '{key}' must be a list")
    return value


# -- args ------------------------------------------------------------------------------------
def _arguments(where: str, doc: Located, given: dict[str, Any], given_at: Located | None,
               here: dict[str, str]) -> dict[str, Any]:
    """Declared args with their values: defaults (which may use ``here``'s $(dirname)), overridden by
    ``given`` (the command line's when ``given_at`` is None, else an include's ``args``); errors for
    unknown or missing ones."""
    raw = doc.get("args")
    if raw is None:
        raw = Located()
    if not isinstance(raw, dict):
        raise ConfigError(f"{at(doc, 'args', where)}: 'args' must map NAME: default (null: required)")
    declared: dict[str, Any] = {}
    for name, spec in raw.items():
        line = at(raw, name, where)
        if isinstance(name, bool):
            raise ConfigError(f"{line}: arg {name!r}: YAML reads on/off/yes/no as true/false; quote the name")
        if not isinstance(name, str) or not ARG_RE.match(name):
            raise ConfigError(f"{line}: arg {name!r}: a name is letters, digits and '_', not starting with a digit")
        if isinstance(spec, dict) and spec and set(spec) <= ARG_SPEC_KEYS:
            if not isinstance(spec.get("description", ""), str):
                raise ConfigError(f"{line}: arg {name!r}: description must be text")
            spec = spec.get("default")
        declared[name] = _REQUIRED if spec is None else spec
    for name in given:
        if name not in declared:
            src = "--arg" if given_at is None else at(given_at, name)
            raise ConfigError(f"{src}: {where} declares no arg {name!r} ({_hint(str(name), declared)})")
    values: dict[str, Any] = {}
    for name, default in declared.items():            # a default may use the args declared before it
        if name in given:
            values[name] = given[name]
        elif default is _REQUIRED:
            how = f"--arg {name}=VALUE" if given_at is None else f"nor by the include at {at(given_at)}"
            raise ConfigError(f"{at(raw, name, where)}: arg {name!r} has no default and is not given ({how})")
        else:
            for m in SUBST_RE.finditer(default) if isinstance(default, str) else ():
                later = m.group(1).strip().partition(" ")[2].strip()
                if later in declared and later not in values:
                    raise ConfigError(f"{at(raw, name, where)}: arg {name!r}: its default uses {later!r}, declared "
                                      "after it (a default uses the args above it)")
            values[name] = _substitute(default, {**values, **here}, at(raw, name, where))
    return values


def _substitute(value: Any, args: dict[str, Any], line: str) -> Any:
    """``$(arg NAME)`` in every string of ``value``; a string that is only that keeps the arg's type."""
    if isinstance(value, Located):
        out = value.derive({})
        for k, v in value.items():
            here = at(value, k, line)
            key = _substitute(k, args, here) if isinstance(k, str) else k     # a remap's topic may be an arg
            if isinstance(key, (dict, list)):
                raise ConfigError(f"{here}: the key {k!r} becomes a {type(key).__name__}: a key is a name")
            out[key] = _substitute(v, args, here)
            out.key_lines[key] = value.line_of(k)
        return out
    if isinstance(value, dict):
        return {k: _substitute(v, args, line) for k, v in value.items()}
    if isinstance(value, list):
        return [_substitute(v, args, line) for v in value]
    if not isinstance(value, str) or "$(" not in value:
        return value
    if "$(" in SUBST_RE.sub("", value):
        raise ConfigError(f"{line}: an unclosed or nested '$(' in {value[:80]!r} (expected $(arg NAME) or $(dirname))")
    whole = SUBST_RE.fullmatch(value.strip())
    if whole:
        return _arg(whole.group(1), args, line)

    def text(m: re.Match) -> str:
        v = _arg(m.group(1), args, line)
        if isinstance(v, (dict, list)):
            raise ConfigError(f"{line}: $({m.group(1)}) is a {type(v).__name__}: it cannot be part of a text")
        return ("true" if v else "false") if isinstance(v, bool) else str(v)

    return SUBST_RE.sub(text, value)


def _arg(content: str, args: dict[str, Any], line: str) -> Any:
    kind, _, name = content.strip().partition(" ")
    name = name.strip()
    if kind == "dirname" and not name and _DIRNAME in args:
        return args[_DIRNAME]
    if kind != "arg" or not name:
        raise ConfigError(f"{line}: unknown substitution $({content}) (the ones there are: $(arg NAME), $(dirname))")
    if name not in args:
        declared = set(args) - {_DIRNAME}              # $(dirname) waits among the args, but is not one
        raise ConfigError(f"{line}: $(arg {name}): the file declares no arg {name!r} ({_hint(name, declared)})")
    return args[name]


# -- nodes: ids, inputs, remap, params_file -----------------------------------------------------
def _draft(where: str, index: int, raw: Any) -> Draft:
    draft = Draft(raw=raw, where=where, index=index)
    if not isinstance(raw, dict) or not isinstance(raw.get("id"), str):
        return draft                                     # the validator says what is wrong
    draft.rel_id = raw["id"]
    if "." in draft.rel_id:
        raise ConfigError(f"{at(raw, 'id', where)}: nodes[{index}]: id {draft.rel_id!r}: '.' separates "
                          "namespaces (set by include); an id in a file has none")
    inputs = raw.get("inputs") or {}
    if isinstance(inputs, dict) and all(isinstance(k, str) and isinstance(v, str) for k, v in inputs.items()):
        draft.pending = dict(inputs)
        _node_remap(draft, where)
    for name, text in list(draft.pending.items()):
        if TIMER_RE.match(text):
            draft.resolved[name] = draft.pending.pop(name)
    if "params_file" in raw:
        draft.raw = _with_params_file(raw, where, draft.rel_id)
    return draft


def _node_remap(draft: Draft, where: str) -> None:
    raw = draft.raw
    remap = raw.get("remap")
    if remap is None:
        return
    what = f"node {draft.rel_id!r}"
    if not isinstance(remap, dict):
        raise ConfigError(f"{at(raw, 'remap', where)}: {what}: 'remap' maps a source topic or an output name "
                          "to a new one")
    for src, dst in remap.items():
        line = at(remap, src, where)
        if not isinstance(src, str) or not isinstance(dst, str) or not src or not dst:
            raise ConfigError(f"{line}: {what}: remap {src!r}: {dst!r}: both sides are names")
        if "/" in src:
            hits = [name for name, text in draft.pending.items() if text == src]
            if not hits:
                raise ConfigError(f"{line}: {what}: remap {src!r} matches none of its inputs' sources "
                                  f"({', '.join(sorted(set(draft.pending.values()))) or 'no inputs'})")
            if "/" not in dst:
                raise ConfigError(f"{line}: {what}: remap {src!r} -> {dst!r}: a source is 'node/output'")
            for name in hits:
                draft.pending[name] = dst
                draft.remapped[name] = f"{line}: remap {src} -> {dst}"
        else:
            if "/" in dst or not NAME_RE.match(dst):
                raise ConfigError(f"{line}: {what}: remap of output {src!r}: the new name {dst!r} is letters, "
                                  "digits, '-' or '_'")
            if dst in draft.aliases:
                raise ConfigError(f"{line}: {what}: two outputs are remapped to {dst!r}")
            draft.aliases[dst] = src
            draft.alias_at[dst] = line


def _with_params_file(raw: Located, where: str, node_id: str) -> Located:
    files = raw["params_file"]
    files = [files] if isinstance(files, str) else files
    what = f"{at(raw, 'params_file', where)}: node {node_id!r}: params_file"
    if not isinstance(files, list) or not files or not all(isinstance(f, str) and f for f in files):
        raise ConfigError(f"{what} is a file name or a list of them")
    explicit = raw.get("params")
    if explicit is not None and not isinstance(explicit, Located):
        return raw                                        # the validator refuses the 'params' itself
    merged = Located()
    merged.where, merged.line, merged.key_lines = where, raw.line_of("params_file"), {}
    for name in files:
        path = Path(where).parent / name
        if not path.is_file():
            raise ConfigError(f"{what} {name!r}: no such file ({path})")
        loaded = load_yaml_file(path)
        if not isinstance(loaded, Located):
            raise ConfigError(f"{path}: a params file is a mapping of name: value (node {node_id!r})")
        merged = loaded.merged_over(merged)
    if explicit is not None:
        merged = explicit.merged_over(merged)
    out = raw.derive({k: v for k, v in raw.items() if k != "params_file"})
    out["params"] = merged
    return out


# -- include -----------------------------------------------------------------------------------
def _include(where: str, k: int, inc: Any, stack: tuple[Path, ...], count: list[int]) -> Composed:
    if not isinstance(inc, dict):
        raise ConfigError(f"{where}: include[{k}]: an include is a mapping with 'file' (and namespace, args, remap)")
    for key in inc:
        if key not in INCLUDE_KEYS:
            raise ConfigError(f"{at(inc, key, where)}: include[{k}]: unknown key {key!r} ({_hint(str(key), INCLUDE_KEYS)})")
    name = inc.get("file")
    if not isinstance(name, str) or not name:
        raise ConfigError(f"{at(inc, 'file', where)}: include[{k}]: 'file' names a launch file")
    ns = inc.get("namespace")
    if ns is not None and (not isinstance(ns, str) or not NAMESPACE_RE.match(ns)):
        raise ConfigError(f"{at(inc, 'namespace', where)}: include[{k}]: namespace {ns!r} must be names of "
                          "letters, digits, '-' or '_' joined by '.'")
    given = inc.get("args")
    if given is not None and not isinstance(given, Located):
        raise ConfigError(f"{at(inc, 'args', where)}: include[{k}]: 'args' must map NAME: value")
    if inc.get("remap") is not None and not isinstance(inc["remap"], dict):
        raise ConfigError(f"{at(inc, 'remap', where)}: include[{k}]: 'remap' maps a source topic to another")
    path = Path(where).parent / name
    line = at(inc, "file", where)
    if not path.is_file():
        raise ConfigError(f"{line}: include {name!r}: no such launch file ({path})")
    if path.resolve() in stack:
        cycle = " -> ".join(p.name for p in stack[stack.index(path.resolve()):]) + f" -> {path.name}"
        raise ConfigError(f"{line}: include cycle: {cycle}")
    if len(stack) >= MAX_INCLUDE_DEPTH:
        raise ConfigError(f"{line}: includes nested deeper than {MAX_INCLUDE_DEPTH} files")
    count[1] += 1
    if count[1] > MAX_INCLUDES:
        raise ConfigError(f"{line}: more than {MAX_INCLUDES} files included in all")
    if given is None:
        given = inc.derive({})
    return _compose(path, dict(given), given, stack, count)


def _adopt(draft: Draft, ns: str, inc: Located, used: set[str]) -> None:
    """A node of an included file seen from the including file: the include's remaps applied
    (they name sources in the included file's terms, targets in the includer's), then namespaced."""
    remap = inc.get("remap") or {}
    for name, text in [*draft.resolved.items(), *draft.pending.items()]:
        if text in remap:
            dst = remap[text]
            line = at(remap, text)
            if not isinstance(dst, str) or "/" not in dst:
                raise ConfigError(f"{line}: include remap {text!r} -> {dst!r}: a source is 'node/output'")
            draft.resolved.pop(name, None)
            draft.pending[name] = dst
            draft.remapped[name] = f"{line}: include remap {text} -> {dst}"
            used.add(text)
    pre = f"{ns}." if ns else ""
    draft.rel_id = pre + draft.rel_id if draft.rel_id else draft.rel_id
    draft.resolved = {k: v if TIMER_RE.match(v) else pre + v for k, v in draft.resolved.items()}


def _check_include_remaps(where: str, inc: Located, used: set[str]) -> None:
    remap = inc.get("remap") or {}
    for src in remap:
        if not isinstance(src, str) or "/" not in src:
            raise ConfigError(f"{at(remap, src, where)}: include remap {src!r}: an include remaps sources "
                              "('node/output'); an output is renamed on its node")
        if src not in used:
            raise ConfigError(f"{at(remap, src, where)}: include remap {src!r} matches no input source in "
                              "the included file")


def _prefix_link(raw: Any, ns: str, names: set[str]) -> Any:
    if not ns or not isinstance(raw, dict) or not isinstance(raw.get("between"), list):
        return raw
    out = raw.derive() if isinstance(raw, Located) else dict(raw)
    out["between"] = [f"{ns}.{e}" if isinstance(e, str) and f"{ns}.{e}" in names else e for e in raw["between"]]
    return out
