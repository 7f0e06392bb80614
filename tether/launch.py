"""Launch files: parse, validate before anything starts, and plan each node's sockets.

::

    name: sonar-localize
    machines:                       # optional; without it everything is local (ipc)
      boat:  {host: 127.0.0.1, port_base: 47100}
    nodes:
      - id: sonar
        node: sim.fls:FlsSonar
        params: {range_m: 20}
        restart: on-failure         # or never (default)
        machine: boat
        rt_priority: 50             # optional: SCHED_FIFO for a cyclic node (see tether.runner)
      - id: imager
        node: nodes.sonar.polar_imager:PolarImager
        inputs: {ping: sonar/ping, tick: timer/hz/10}

Files compose (:mod:`tether.launch_compose`): ``args`` with defaults and ``$(arg NAME)``,
``include`` of other files under a namespace (``ns.node`` ids, ``ns.node/output`` topics),
``remap`` per node or include, and ``params_file`` merged under ``params``.

Validation raises :class:`ConfigError` with one line naming the file, line, node and key.
The file is read with :func:`tether.yamlsafe.load_yaml` (aliases bounded before they
expand, nesting bounded, duplicate keys refused); unknown keys are errors at every level,
and numbers have ranges (timers in (0, 10 kHz], ``max_restarts`` in [0, 1000], every
float parameter finite).
"""
from __future__ import annotations

import difflib
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from tether.errors import ConfigError
from tether.launch_compose import Draft, compose
from tether.link import LinkModel, parse_link
from tether.node import MAX_TIMER_HZ, Node, Ports, Tick
from tether.runner import load_node_class
from tether.runtime import RunSpec, Source
from tether.stats import NodeStats
from tether.transport import ipc_endpoint, runtime_dir
from tether.yamlsafe import Located, load_yaml

ID_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_\-]*$")
NODE_ID_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_\-]*(\.[A-Za-z][A-Za-z0-9_\-]*)*$")   # ns.ns.id
TOPIC_RE = re.compile(NODE_ID_RE.pattern[:-1] + r"/[A-Za-z_][A-Za-z0-9_\-]*$")             # ns.id/output
TIMER_RE = re.compile(r"^timer/(hz|ms)/([0-9]*\.?[0-9]+)$")
RESTART_POLICIES = ("never", "on-failure")
NODE_KEYS = {"id", "node", "params", "inputs", "restart", "max_restarts", "machine", "env", "remap", "params_file",
             "rt_priority"}
ENV_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
MAX_RESTARTS = 1000
MAX_RT_PRIORITY = 98     # SCHED_FIFO 1..99; 99 is left to the kernel's own threads (watchdog, migration)


@dataclass
class NodeEntry:
    """One node of a launch file, validated."""

    id: str
    node: str
    params: dict[str, Any]
    inputs: dict[str, str]
    restart: str = "never"
    max_restarts: int = 3
    machine: str = ""
    env: dict[str, str] = field(default_factory=dict)
    rt_priority: int = 0          # SCHED_FIFO priority of the node's process (0: normal scheduling)
    cls: type[Node] | None = None
    ports: Ports | None = None
    renamed: dict[str, str] = field(default_factory=dict)    # output -> the name its remap gives it


@dataclass
class Machine:
    name: str
    host: str = "127.0.0.1"
    port_base: int = 47000


@dataclass
class LaunchFile:
    """A validated pipeline."""

    path: Path
    name: str
    nodes: list[NodeEntry]
    machines: dict[str, Machine]
    links: list[tuple[frozenset[str], LinkModel]] = field(default_factory=list)
    #: what is allowed but likely a mistake, one line each naming the file and line (``tether check``
    #: prints them; ``--strict`` makes them errors)
    warnings: list[str] = field(default_factory=list)

    def link_between(self, a: NodeEntry, b: NodeEntry) -> LinkModel | None:
        """The link model a message from node ``a`` to node ``b`` crosses (by node id or machine), if any."""
        for ends, model in self.links:
            x, y = sorted(ends)
            if any(u in (a.id, a.machine) and v in (b.id, b.machine) for u, v in ((x, y), (y, x))):
                return model
        return None

    def node(self, node_id: str) -> NodeEntry:
        for entry in self.nodes:
            if entry.id == node_id:
                return entry
        raise KeyError(node_id)

    def topics(self) -> dict[str, str]:
        """Every output topic -> message type name."""
        return {f"{n.id}/{out}": tp.type_name() for n in self.nodes for out, tp in n.ports.outputs.items()}

    def edges(self) -> list[tuple[str, str, str]]:
        """(source topic or timer, destination node id, destination input)."""
        return [(src, n.id, name) for n in self.nodes for name, src in n.inputs.items()]


def parse_value(text: str) -> Any:
    """A ``--param`` value: YAML scalar/list/map syntax (``20``, ``true``, ``[1, 2]``, ``bilinear``)."""
    try:
        return load_yaml(text, where="--param")
    except ConfigError:
        return text


def parse_assignments(items: list[str] | None, flag: str = "--arg") -> dict[str, Any]:
    """``NAME=VALUE`` strings of a command-line ``flag`` -> {name: value} (values read by :func:`parse_value`)."""
    out: dict[str, Any] = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise ConfigError(f"{flag} {item!r}: expected NAME=VALUE")
        if name in out:
            raise ConfigError(f"{flag} {name} is given twice")
        out[name] = parse_value(value)
    return out


def parse_launch_args(items: list[str] | None) -> dict[str, Any]:
    """``--arg NAME=VALUE`` strings -> {name: value} (values read like ``--param``)."""
    return parse_assignments(items, "--arg")


def parse_overrides(items: list[str] | None) -> dict[str, dict[str, Any]]:
    """``NODE.KEY=VALUE`` strings -> {node: {key: value}} (a namespaced node: ``ns.node.KEY=VALUE``)."""
    out: dict[str, dict[str, Any]] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        node_id, dot, param = key.rpartition(".")
        if not sep or not dot or not node_id or not param:
            raise ConfigError(f"--param {item!r}: expected NODE.KEY=VALUE")
        if param in out.get(node_id, {}):
            raise ConfigError(f"--param {node_id}.{param} is given twice")
        out.setdefault(node_id, {})[param] = parse_value(value)
    return out


def _at(where: str, mapping: Any, key: Any = None) -> str:
    """``FILE:LINE`` of ``key`` in a mapping read by :func:`load_yaml` (of the mapping itself without a key);
    the file is the one the mapping (or that key, in a merged mapping) was read from."""
    if isinstance(mapping, Located):
        return f"{mapping.where_of(key) or where}:{mapping.line_of(key) if key is not None else mapping.line}"
    return where


def _unknown_keys(at: str, raw: Located, allowed: set[str], what: str) -> None:
    for key in raw:
        if key not in allowed:
            close = difflib.get_close_matches(str(key), sorted(allowed), n=1)
            hint = f"did you mean {close[0]!r}?" if close else f"allowed: {', '.join(sorted(allowed))}"
            raise ConfigError(f"{_at(at, raw, key)}: {what}unknown key {key!r} ({hint})")


def _int_in(at: str, raw: Any, key: str, default: int, lo: int, hi: int, what: str = "") -> int:
    value = raw.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ConfigError(f"{_at(at, raw, key)}: {what}{key} must be an integer in [{lo}, {hi}], got {value!r}")
    return value


def load_launch(path: str | Path, overrides: Mapping[str, Mapping[str, Any]] | None = None, *,
                args: Mapping[str, Any] | None = None) -> LaunchFile:
    """Read and validate a launch file and what it includes; ``overrides`` are {node: {param: value}},
    ``args`` the file's args (``--arg NAME=VALUE``).

    Every error is one :class:`ConfigError` line naming the file, the line and the key.
    """
    path = Path(path)
    where = str(path)
    if not path.exists():
        raise ConfigError(f"{where}: no such launch file")
    composed = compose(path, args)
    doc = composed.doc
    name = doc.get("name", path.stem)
    if not isinstance(name, str) or not ID_RE.match(name):
        raise ConfigError(f"{_at(where, doc, 'name')}: name {name!r} must be letters, digits, '-' or '_'")
    if not isinstance(doc.get("description", ""), str):
        raise ConfigError(f"{_at(where, doc, 'description')}: description must be text")
    machines = _machines(where, doc, composed.machines)
    overrides = dict(overrides or {})
    raws = [_flat_node(d) for d in composed.nodes]
    nodes = [_node_entry(d.where, d.index, raw, machines, overrides) for d, raw in zip(composed.nodes, raws)]
    seen: dict[str, NodeEntry] = {}
    for draft, raw, entry in zip(composed.nodes, raws, nodes):
        if entry.id in seen:
            raise ConfigError(f"{_at(draft.where, raw, 'id')}: node id {entry.id!r} is used twice")
        seen[entry.id] = entry
    for node_id in overrides:
        if node_id not in seen:
            raise ConfigError(f"{where}: --param for unknown node {node_id!r} (nodes: {sorted(seen)})")
    _rename_outputs(composed.nodes, nodes, raws)
    names = set(seen) | set(machines)
    links = [parse_link(link_at, raw, names) for link_at, raw in composed.links]
    launch = LaunchFile(path=path, name=name, nodes=nodes, machines=machines, links=links)
    remapped = {(n.id, inp): why for d, n in zip(composed.nodes, nodes) for inp, why in d.remapped.items()}
    _check_wiring(where, launch, dict(zip((n.id for n in nodes), raws)), remapped)
    return launch


def _flat_node(draft: Draft) -> Any:
    """The node mapping as the validator reads it: namespaced id, sources resolved across files."""
    raw = draft.raw
    if not isinstance(raw, Located) or not draft.rel_id:
        return raw
    out = raw.derive()
    out["id"] = draft.rel_id
    if isinstance(raw.get("inputs"), Located):
        out["inputs"] = raw["inputs"].derive({k: draft.resolved.get(k, v) for k, v in raw["inputs"].items()})
    return out


def _rename_outputs(drafts: list[Draft], nodes: list[NodeEntry], raws: list[Any]) -> None:
    """Output remaps: check the names, then point every source at the class's own output name."""
    by_id = {}
    for draft, entry in zip(drafts, nodes):
        for alias, real in draft.aliases.items():
            if real not in entry.ports.outputs:
                raise ConfigError(f"{draft.alias_at[alias]}: node {entry.id!r}: remap of output {real!r}: no such "
                                  f"output (outputs: {sorted(entry.ports.outputs) or 'none'})")
            entry.renamed[real] = alias
        if draft.aliases:
            by_id[entry.id] = (draft, entry)
    for entry, raw in zip(nodes, raws):
        for name, src in entry.inputs.items():
            src_id, slash, output = src.partition("/")
            if src_id not in by_id:
                continue
            draft, source = by_id[src_id]
            if output in draft.aliases:
                entry.inputs[name] = f"{src_id}/{draft.aliases[output]}"
            elif output in source.renamed:
                raise ConfigError(f"{_at('', raw.get('inputs'), name)}: node {entry.id!r}: input {name!r}: "
                                  f"{src_id}'s output {output!r} is remapped to {source.renamed[output]!r} "
                                  f"({draft.alias_at[source.renamed[output]]})")


def _machines(where: str, doc: Any, raw: Any) -> dict[str, Machine]:
    if not isinstance(raw, dict):
        raise ConfigError(f"{_at(where, doc, 'machines')}: 'machines' must map a name to {{host, port_base}}")
    out = {}
    for name, spec in raw.items():
        at = f"{_at(where, raw, name)}: machine {name!r}"
        if not isinstance(name, str) or not ID_RE.match(name):
            raise ConfigError(f"{at}: a machine name is letters, digits, '-' or '_'")
        spec = spec if spec is not None else {}
        if not isinstance(spec, dict):
            raise ConfigError(f"{at}: expected a mapping with host, port_base")
        _unknown_keys(where, spec, {"host", "port_base"}, f"machine {name!r}: ")
        host = spec.get("host", "127.0.0.1")
        if not isinstance(host, str) or not host or len(host) > 253 or any(c.isspace() for c in host):
            raise ConfigError(f"{_at(where, spec, 'host')}: machine {name!r}: host must be a host name or address")
        port = _int_in(where, spec, "port_base", 47000, 1024, 65000, f"machine {name!r}: ")
        out[name] = Machine(name, host, port)
    return out


def _node_entry(where: str, index: int, raw: Any, machines: dict[str, Machine],
                overrides: dict[str, dict[str, Any]]) -> NodeEntry:
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: nodes[{index}] must be a mapping with id and node")
    node_id = raw.get("id")
    if not isinstance(node_id, str) or not NODE_ID_RE.match(node_id):
        raise ConfigError(f"{_at(where, raw, 'id')}: nodes[{index}]: id {node_id!r} must start with a letter "
                          "and use letters, digits, '-' or '_'")
    what = f"node {node_id!r}: "
    _unknown_keys(where, raw, NODE_KEYS, what)
    if not isinstance(raw.get("node"), str):
        raise ConfigError(f"{_at(where, raw, 'node')}: {what}'node' must be 'module.path:ClassName'")
    try:
        cls = load_node_class(raw["node"])
    except ConfigError as exc:
        raise ConfigError(f"{_at(where, raw, 'node')}: {what}{exc}") from None
    raw_params = raw.get("params")
    if raw_params is not None and not isinstance(raw_params, dict):
        raise ConfigError(f"{_at(where, raw, 'params')}: {what}'params' must be a mapping of name: value")
    params = dict(raw_params or {})
    params.update(overrides.get(node_id, {}))
    try:
        config = cls.make_config(params)
        ports = cls.resolve_ports(config)
    except ConfigError as exc:
        overridden = exc.key in overrides.get(node_id, {})
        at = "--param" if overridden else _at(where, raw_params if exc.key in (raw_params or {}) else raw,
                                              exc.key if exc.key in (raw_params or {}) else "params")
        raise ConfigError(f"{at}: {what}{exc}") from None
    except Exception as exc:  # noqa: BLE001 - a Config.__post_init__ saying what is wrong
        raise ConfigError(f"{_at(where, raw, 'params')}: {what}params: {type(exc).__name__}: {exc}") from None
    inputs = raw.get("inputs") or {}
    if not isinstance(inputs, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in inputs.items()):
        raise ConfigError(f"{_at(where, raw, 'inputs')}: {what}'inputs' must map input names to 'node/output'")
    restart = raw.get("restart", "never")
    if restart not in RESTART_POLICIES:
        raise ConfigError(f"{_at(where, raw, 'restart')}: {what}restart {restart!r} must be one of {RESTART_POLICIES}")
    max_restarts = _int_in(where, raw, "max_restarts", 3, 0, MAX_RESTARTS, what)
    rt_priority = _int_in(where, raw, "rt_priority", 0, 0, MAX_RT_PRIORITY, what)
    machine = raw.get("machine") or ""
    if not isinstance(machine, str) or (machine and machine not in machines):
        raise ConfigError(f"{_at(where, raw, 'machine')}: {what}machine {machine!r} is not declared under 'machines'")
    if machines and not machine:
        raise ConfigError(f"{_at(where, raw)}: {what}the file declares machines, so every node names its 'machine'")
    return NodeEntry(id=node_id, node=raw["node"], params=params, inputs=dict(inputs), restart=restart,
                     max_restarts=max_restarts, machine=machine, env=_env(where, raw, what), rt_priority=rt_priority,
                     cls=cls, ports=ports)


def _env(where: str, raw: Any, what: str) -> dict[str, str]:
    env = raw.get("env")
    if env is None:
        return {}
    if not isinstance(env, dict):
        raise ConfigError(f"{_at(where, raw, 'env')}: {what}'env' must map NAME: value, not a {type(env).__name__}")
    out = {}
    for key, value in env.items():
        at = f"{_at(where, env, key)}: {what}env {key!r}"
        if not isinstance(key, str) or not ENV_RE.match(key):
            raise ConfigError(f"{at}: a variable name is letters, digits and '_', not starting with a digit")
        if isinstance(value, bool) or not isinstance(value, (str, int, float)):
            raise ConfigError(f"{at}: the value must be text or a number, not {type(value).__name__}")
        text = str(value)
        if "\0" in text or len(text) > 32768:
            raise ConfigError(f"{at}: the value holds a NUL byte or is longer than 32768 characters")
        out[key] = text
    return out


def _check_wiring(where: str, launch: LaunchFile, raws: Mapping[str, Any],
                  remapped: Mapping[tuple[str, str], str]) -> None:
    by_id = {n.id: n for n in launch.nodes}
    for entry in launch.nodes:
        raw_inputs = raws[entry.id].get("inputs")
        for name, src in entry.inputs.items():
            # a remapped source is blamed on the remap that set it
            at = f"{remapped.get((entry.id, name)) or _at(where, raw_inputs, name)}: node {entry.id!r}"
            port = entry.ports.inputs.get(name)
            if port is None:
                raise ConfigError(f"{at}: unknown input {name!r} (inputs: {sorted(entry.ports.inputs) or 'none'})")
            if TIMER_RE.match(src):
                if port.type is not Tick:
                    raise ConfigError(f"{at}: input {name!r} takes {port.type.type_name()}, not a timer")
                try:
                    timer_period_ns(src)
                except ConfigError as exc:
                    raise ConfigError(f"{at}: input {name!r}: {exc}") from None
                continue
            src_id, slash, output = src.partition("/")
            if not slash or src_id not in by_id:
                raise ConfigError(f"{at}: input {name!r} comes from {src!r}: no node {src_id!r} "
                                  f"(expected 'node/output' or 'timer/hz/N')")
            # Every node also publishes its statistics on <id>/_stats: a monitor may take them as an input.
            out_type = NodeStats if output == "_stats" else by_id[src_id].ports.outputs.get(output)
            if out_type is None:
                raise ConfigError(f"{at}: input {name!r}: node {src_id!r} has no output {output!r} "
                                  f"(outputs: {sorted(by_id[src_id].ports.outputs) or 'none'})")
            if out_type is not port.type:
                raise ConfigError(f"{at}: input {name!r} takes {port.type.type_name()} but {src} "
                                  f"publishes {out_type.type_name()}")
            if src_id == entry.id:
                launch.warnings.append(_self_loop(at, entry, name, src))


def _self_loop(at: str, entry: NodeEntry, name: str, src: str) -> str:
    """The warning for an input wired to its own node's output.

    Allowed (the runtime delivers it, as ROS 2 delivers a node's own topic to its own
    subscription), but a Tether topic has one publisher: the input gets back only what the
    node published itself, which it already had. Usually a mistyped source; with no other
    input, timer or ``run()`` to start it, the node can never publish at all."""
    others = [n for n, s in entry.inputs.items() if n != name and s.partition("/")[0] != entry.id]
    starts = others or entry.ports.timers or (entry.cls is not None and entry.cls.run is not Node.run)
    return (f"{at}: input {name!r} takes the node's own output {src}: it gets back only what {entry.id!r} "
            "publishes itself" + ("" if starts else ", and nothing else starts the node: it never publishes")
            + " (meant as feedback: keep it; else wire another node's output)")


def timer_period_ns(src: str) -> int:
    match = TIMER_RE.match(src)
    if match is None:
        raise ConfigError(f"timer {src!r}: expected timer/hz/N or timer/ms/N (N a positive number)")
    kind, value = match.groups()
    hz = float(value) if kind == "hz" else (1e3 / float(value) if float(value) > 0 else 0.0)
    if not 0 < hz <= MAX_TIMER_HZ or (kind == "ms" and float(value) > 1e7):
        raise ConfigError(f"timer {src!r} must tick between every 10^7 ms and {MAX_TIMER_HZ:g} Hz")
    return int(round(1e9 / hz)) if kind == "hz" else int(round(float(value) * 1e6))


def plan(launch: LaunchFile, *, token: str, curve: dict[str, Any] | None = None,
         epoch_ns: int = 0) -> dict[str, RunSpec]:
    """A RunSpec per node: where it binds, where each input connects, who will subscribe.
    ``epoch_ns``: when the launch started (the clock of the links' outage schedules)."""
    local_ep = {n.id: ipc_endpoint(launch.name, n.id, token) for n in launch.nodes}
    clash: dict[str, str] = {}
    for node_id, ep in local_ep.items():       # socket names are cut short: long namespaced ids may meet
        if ep in clash:
            raise ConfigError(f"{launch.path}: nodes {clash[ep]!r} and {node_id!r} get the same socket name "
                              f"({ep.rsplit('/', 1)[-1]}): shorten the graph name, a namespace or an id")
        clash[ep] = node_id
    tcp_ep: dict[str, str] = {}
    port_next = {m: launch.machines[m].port_base for m in launch.machines}
    for n in launch.nodes:
        remote_subs = any(_source_node(src) == n.id and other.machine != n.machine
                          for other in launch.nodes for src in other.inputs.values())
        if launch.machines and remote_subs:
            machine = launch.machines[n.machine]
            tcp_ep[n.id] = f"tcp://{machine.host}:{port_next[n.machine]}"
            port_next[n.machine] += 1
    subscribers: dict[str, int] = {}
    for n in launch.nodes:
        for src in n.inputs.values():
            if not TIMER_RE.match(src):
                subscribers[src] = subscribers.get(src, 0) + 1
    specs = {}
    for n in launch.nodes:
        binds = [local_ep[n.id]]         # sinks too: every node publishes its statistics
        if n.id in tcp_ep:
            binds.append(tcp_ep[n.id].replace(f"//{launch.machines[n.machine].host}:", "//*:")
                         if launch.machines[n.machine].host in ("0.0.0.0", "*") else tcp_ep[n.id])
        inputs = {}
        for name, src in n.inputs.items():
            if TIMER_RE.match(src):
                inputs[name] = Source(timer_ns=timer_period_ns(src))
                continue
            src_node = launch.node(_source_node(src))
            same = not launch.machines or src_node.machine == n.machine
            secure = src_node.id in tcp_ep
            model = launch.link_between(src_node, n)
            link = None
            if model is not None:
                link = model.to_json() | {"epoch_ns": epoch_ns,
                                          "seed": model.seed * 1_000_003 + sum(map(ord, f"{src}>{n.id}/{name}"))}
            inputs[name] = Source(topic=src, endpoint=local_ep[src_node.id] if same else tcp_ep[src_node.id],
                                  secure=secure, server_key=curve["peers"].get(src_node.machine, "")
                                  if secure and curve else "", link=link)
        expect = {f"{n.id}/{out}": subscribers.get(f"{n.id}/{out}", 0) for out in n.ports.outputs}
        uses_tcp = n.id in tcp_ep or any(s.secure for s in inputs.values())
        specs[n.id] = RunSpec(graph=launch.name, node_id=n.id, node=n.node, params=n.params, binds=binds,
                              inputs=inputs, expect_subscribers=expect, curve=curve if uses_tcp else None,
                              state_file=str(state_file(launch.name, n.id, token)), rt_priority=n.rt_priority)
    return specs


def state_file(graph: str, node_id: str, token: str) -> Path:
    """Where a launched node keeps its seq numbers across restarts (see :class:`tether.inputs.SeqStore`)."""
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in f"{graph}.{node_id}")
    return runtime_dir() / "state" / f"{safe}.{token}.seq"


def _source_node(src: str) -> str:
    return "" if TIMER_RE.match(src) else src.partition("/")[0]


def to_dot(launch: LaunchFile) -> str:
    """Graphviz DOT of the pipeline: nodes, and an edge per connected input labelled with its topic."""
    lines = [f'digraph "{launch.name}" {{', "  rankdir=LR;", "  node [shape=box, fontname=Helvetica];"]
    for n in launch.nodes:
        label = f"{n.id}\\n{n.node.split(':')[-1]}" + (f"\\n@{n.machine}" if n.machine else "")
        lines.append(f'  "{n.id}" [label="{label}"];')
    for src, dst, name in launch.edges():
        if TIMER_RE.match(src):
            timer = src.replace("/", "_")
            lines.append(f'  "{timer}" [shape=ellipse, label="{src}"];')
            lines.append(f'  "{timer}" -> "{dst}" [label="{name}"];')
        else:
            src_id, _, out = src.partition("/")
            lines.append(f'  "{src_id}" -> "{dst}" [label="{out} -> {name}"];')
    lines.append("}")
    return "\n".join(lines)


def to_text(launch: LaunchFile) -> str:
    """A readable listing: each node, its class, its inputs with their sources and its outputs with types."""
    out = [f"{launch.name}  ({launch.path})"]
    for n in launch.nodes:
        out.append(f"  {n.id}  [{n.node}]" + (f"  @{n.machine}" if n.machine else ""))
        for name, port in n.ports.inputs.items():
            src = n.inputs.get(name) or ("(timer)" if name in n.ports.timers else "(unconnected)")
            out.append(f"    <- {name:14s} {port.type.type_name():24s} {src}")
        for name, tp in n.ports.outputs.items():
            alias = f"  (remapped: the launch file calls it {n.id}/{n.renamed[name]})" if name in n.renamed else ""
            out.append(f"    -> {name:14s} {tp.type_name():24s} {n.id}/{name}{alias}")
    return "\n".join(out)
