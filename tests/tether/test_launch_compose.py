"""Launch files for real projects: args and $(arg NAME), include under a namespace, remap,
params_file; every mistake one line naming the file and line, before anything starts."""
from __future__ import annotations

import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from conftest import launch_until, recording_for
from tether.errors import ConfigError
from tether.launch import load_launch, parse_launch_args, parse_overrides, plan, to_text

REPO = Path(__file__).resolve().parents[2]

PIPE = """
name: pipe
args:
  rate: 5
  gain: {default: 2.0, description: the scale's gain}
nodes:
  - id: counter
    node: nodes.std.demo:Counter
    params: {rate_hz: $(arg rate)}
  - id: scale
    node: nodes.std.demo:Scale
    params: {gain: $(arg gain)}
    inputs: {value: counter/value}
"""


def _files(tmp_path: Path, **texts: str) -> Path:
    """Write NAME.yaml for each keyword (``params__x`` -> ``params/x.yaml``); returns the first."""
    paths = []
    for name, text in texts.items():
        path = tmp_path / (name.replace("__", "/") + ".yaml")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))
        paths.append(path)
    return paths[0]


def _error(path: Path, **kw) -> str:
    with pytest.raises(ConfigError) as info:
        load_launch(path, **kw)
    text = str(info.value)
    assert "\n" not in text and "Traceback" not in text
    return text


# -- args --------------------------------------------------------------------------------------
def test_args_keep_their_type_when_alone_and_format_inside_text(tmp_path):
    path = _files(tmp_path, g="""
    name: g
    args: {rate: 5, loud: true}
    nodes:
      - {id: counter, node: nodes.std.demo:Counter, params: {rate_hz: $(arg rate)}, env: {TAG: "r$(arg rate)-$(arg loud)"}}
    """)
    launch = load_launch(path)
    assert launch.node("counter").params == {"rate_hz": 5} and launch.node("counter").env == {"TAG": "r5-true"}
    launch = load_launch(path, args=parse_launch_args(["rate=20", "loud=false"]))
    assert launch.node("counter").params == {"rate_hz": 20} and launch.node("counter").env == {"TAG": "r20-false"}


ARG_ERRORS = [
    ("args: {rate: 5}\nnodes:\n  - {id: a, node: nodes.std.demo:Counter, params: {rate_hz: $(arg rte)}}\n",
     r"g.yaml:4: \$\(arg rte\): the file declares no arg 'rte' \(did you mean 'rate'\?\)"),
    ("args: {rate: null}\nnodes:\n  - {id: a, node: nodes.std.demo:Counter, params: {rate_hz: $(arg rate)}}\n",
     r"g.yaml:2: arg 'rate' has no default and is not given \(--arg rate=VALUE\)"),
    ("nodes:\n  - {id: a, node: nodes.std.demo:Counter, params: {rate_hz: $(env RATE)}}\n",
     r"g.yaml:3: unknown substitution \$\(env RATE\)"),
    ("args: {x: 1}\nnodes:\n  - {id: a, node: nodes.std.demo:Counter, env: {A: \"$(arg x\"}}\n", "unclosed or nested"),
    ("args: {x: [1, 2]}\nnodes:\n  - {id: a, node: nodes.std.demo:Counter, env: {A: \"v$(arg x)\"}}\n",
     "is a list: it cannot be part of a text"),
    ("args: [rate]\nnodes:\n  - {id: a, node: nodes.std.demo:Counter}\n", "g.yaml:2: 'args' must map"),
    ("args: {1x: 2}\nnodes:\n  - {id: a, node: nodes.std.demo:Counter}\n", "arg '1x': a name is"),
    ("args: {on: 2}\nnodes:\n  - {id: a, node: nodes.std.demo:Counter}\n", "arg True: YAML reads on/off"),
    ("args: {rate: fast}\nnodes:\n  - {id: a, node: nodes.std.demo:Counter, params: {rate_hz: $(arg rate)}}\n",
     "g.yaml:4: node 'a'.*rate_hz"),
]


@pytest.mark.parametrize("body, message", ARG_ERRORS)
def test_arg_errors_name_file_and_line(tmp_path, body, message):
    path = _files(tmp_path, g="name: g\n" + body)
    assert re.search(message, _error(path)), _error(path)


def test_dirname_is_the_folder_of_the_file_it_is_written_in(tmp_path, monkeypatch):
    """$(dirname): the includer's folder in its own nodes and in the args it passes down, the included
    file's folder in the included file's nodes, in an arg default too; from any working directory."""
    top = _files(tmp_path, top="""
    name: top
    args: {data: "$(dirname)/data"}
    include:
      - {file: sub/pipe.yaml, namespace: s, args: {where: "$(dirname)/from_top"}}
    nodes:
      - {id: a, node: nodes.std.demo:Counter, env: {SCENE: "$(dirname)/scenes/x.yaml", DATA: $(arg data)}}
    """, sub__pipe="""
    name: pipe
    args: {where: none}
    nodes:
      - {id: b, node: nodes.std.demo:Counter, env: {HERE: "$(dirname)", GIVEN: $(arg where)}}
    """)
    monkeypatch.chdir(tmp_path / "sub")                         # not where the top file is
    launch = load_launch(top)
    here = tmp_path.resolve()
    assert launch.node("a").env == {"SCENE": f"{here}/scenes/x.yaml", "DATA": f"{here}/data"}
    assert launch.node("s.b").env == {"HERE": f"{here}/sub", "GIVEN": f"{here}/from_top"}
    bad = _files(tmp_path, g="name: g\nnodes:\n  - {id: a, node: nodes.std.demo:Counter, env: {A: \"$(dirname x)\"}}\n")
    assert "unknown substitution $(dirname x) (the ones there are: $(arg NAME), $(dirname))" in _error(bad)


def test_a_default_may_use_the_args_declared_before_it(tmp_path):
    path = _files(tmp_path, g="""
    name: g
    args: {site: pier, tag: "$(arg site)-left", late: "$(arg later)", later: 1}
    nodes: [{id: a, node: nodes.std.demo:Counter, env: {TAG: $(arg tag)}}]
    """)
    assert "g.yaml:3: arg 'late': its default uses 'later', declared after it" in _error(path)
    path.write_text(path.read_text().replace(', late: "$(arg later)"', ""))
    assert load_launch(path).node("a").env == {"TAG": "pier-left"}
    assert load_launch(path, args={"site": "dock"}).node("a").env == {"TAG": "dock-left"}
    assert load_launch(path, args={"tag": "x"}).node("a").env == {"TAG": "x"}


def test_an_arg_the_file_does_not_declare_is_refused(tmp_path):
    path = _files(tmp_path, g=PIPE)
    assert _error(path, args={"rat": 3}).startswith(f"--arg: {path} declares no arg 'rat' (did you mean 'rate'?)")
    with pytest.raises(ConfigError, match="expected NAME=VALUE"):
        parse_launch_args(["rate"])
    with pytest.raises(ConfigError, match="--arg rate is given twice"):
        parse_launch_args(["rate=1", "rate=2"])


# -- include -----------------------------------------------------------------------------------
def test_include_twice_under_two_namespaces(tmp_path):
    path = _files(tmp_path, top="""
    name: top
    args: {fast: 20}
    include:
      - {file: pipe.yaml, namespace: left}
      - {file: pipe.yaml, namespace: right, args: {rate: $(arg fast), gain: 3}}
    nodes:
      - {id: printer, node: nodes.std.demo:Printer, inputs: {value: right.scale/value}}
    """, pipe=PIPE)
    launch = load_launch(path)
    assert [n.id for n in launch.nodes] == ["printer", "left.counter", "left.scale", "right.counter", "right.scale"]
    assert launch.node("left.scale").inputs == {"value": "left.counter/value"}
    assert launch.node("right.counter").params == {"rate_hz": 20} and launch.node("right.scale").params == {"gain": 3}
    assert launch.node("left.counter").params == {"rate_hz": 5}
    specs = plan(launch, token="t")
    assert specs["printer"].inputs["value"].topic == "right.scale/value"
    assert specs["printer"].inputs["value"].endpoint == specs["right.scale"].binds[0]
    assert specs["right.scale"].expect_subscribers == {"right.scale/value": 1}
    assert len({s.binds[0] for s in specs.values()}) == 5
    launch = load_launch(path, parse_overrides(["left.counter.rate_hz=9"]), args={"fast": 7})
    assert launch.node("left.counter").params == {"rate_hz": 9} and launch.node("right.counter").params == {"rate_hz": 7}


def test_a_name_an_included_file_does_not_define_is_the_includers(tmp_path):
    """Lexical scope: the included scale reads `counter/value`; only the includer has a counter."""
    path = _files(tmp_path, top="""
    name: top
    include: [{file: sub/consumer.yaml, namespace: a.b}]
    nodes: [{id: counter, node: nodes.std.demo:Counter}]
    """, sub__consumer="""
    name: consumer
    nodes: [{id: scale, node: nodes.std.demo:Scale, inputs: {value: counter/value}}]
    """)
    assert load_launch(path).node("a.b.scale").inputs == {"value": "counter/value"}


def test_include_remap_points_an_included_input_at_the_includers_topic(tmp_path):
    path = _files(tmp_path, top="""
    name: top-$(arg instance)
    args: {instance: 1, feed: counter/value, which: pipe}
    include:
      - file: $(arg which).yaml
        namespace: p
        remap: {$(arg feed): mine/value}
    nodes: [{id: mine, node: nodes.std.demo:Counter}]
    """, pipe=PIPE)
    launch = load_launch(path)
    assert launch.node("p.scale").inputs == {"value": "mine/value"} and launch.name == "top-1"
    assert load_launch(path, args={"instance": "b"}).name == "top-b"     # two copies of a graph on one host


INCLUDE_ERRORS = [
    # (top file, other files, the message's start after the top path or its own file)
    ("include: [{file: a.yaml}]\nnodes: [{id: x, node: nodes.std.demo:Counter}]\n",
     {"a": "include: [{file: b.yaml}]\n", "b": "include: [{file: a.yaml, namespace: again}]\n"},
     r"b.yaml:1: include cycle: a.yaml -> b.yaml -> a.yaml"),
    ("include: [{file: top.yaml, namespace: me}]\nnodes: [{id: x, node: nodes.std.demo:Counter}]\n", {},
     r"top.yaml:2: include cycle: top.yaml -> top.yaml"),
    ("include: [{file: nope.yaml}]\n", {}, r"top.yaml:2: include 'nope.yaml': no such launch file"),
    ("include: [{file: pipe.yaml, args: {rat: 3}}]\n", {"pipe": PIPE},
     r"top.yaml:2: .*pipe.yaml declares no arg 'rat' \(did you mean 'rate'\?\)"),
    ("include: [{file: need.yaml}]\n", {"need": "args: {rate: null}\nnodes: [{id: a, node: nodes.std.demo:Counter}]\n"},
     r"need.yaml:1: arg 'rate' has no default and is not given \(nor by the include at .*top.yaml:2\)"),
    ("include: [{file: pipe.yaml, namespace: 'a/b'}]\n", {"pipe": PIPE}, "namespace 'a/b' must be"),
    ("include: [{file: pipe.yaml, nmespace: a}]\n", {"pipe": PIPE}, r"unknown key 'nmespace' \(did you mean 'namespace'\?\)"),
    ("include: [{file: pipe.yaml}, {file: pipe.yaml}]\n", {"pipe": PIPE}, r"pipe.yaml:\d+: node id 'counter' is used twice"),
    ("include: [{file: bad.yaml, namespace: n}]\n", {"bad": "nodes: [{id: a, node: nodes.std.demo:Nope}]\n"},
     r"bad.yaml:1: node 'n.a': module 'nodes.std.demo' has no class 'Nope'"),
    ("include: [{file: bad.yaml, namespace: n}]\n", {"bad": "nodes: [{id: a.b, node: nodes.std.demo:Counter}]\n"},
     r"bad.yaml:1: nodes\[0\]: id 'a.b': '.' separates namespaces"),
    ("include: [{file: pipe.yaml, remap: {counter/value: nobody/value}}]\n", {"pipe": PIPE},
     r"top.yaml:2: include remap counter/value -> nobody/value: node 'scale': input 'value' comes from "
     r"'nobody/value': no node 'nobody'"),
    ("include: [{file: pipe.yaml, remap: {counter/valu: counter/value}}]\n", {"pipe": PIPE},
     r"top.yaml:2: include remap 'counter/valu' matches no input source"),
    ("include: [{file: pipe.yaml, remap: {value: other}}]\n", {"pipe": PIPE}, "an include remaps sources"),
    ("include: {file: pipe.yaml}\n", {"pipe": PIPE}, r"top.yaml:2: 'include' must be a list"),
    ("include: [{file: m.yaml, namespace: n}]\nmachines: {boat: {host: 10.0.0.1}}\n"
     "nodes: [{id: x, node: nodes.std.demo:Counter, machine: boat}]\n",
     {"m": "machines: {boat: {host: 10.0.0.2}}\nnodes: [{id: a, node: nodes.std.demo:Counter, machine: boat}]\n"},
     r"m.yaml:1: machine 'boat' is declared differently in .*top.yaml:3"),
]


@pytest.mark.parametrize("top, others, message", INCLUDE_ERRORS)
def test_include_errors_name_the_file_and_line(tmp_path, top, others, message):
    for name, text in others.items():
        _files(tmp_path, **{name: text})
    path = _files(tmp_path, top="name: top\n" + top)
    text = _error(path)
    assert re.search(message, text), text


def test_includes_nested_too_deep_or_too_many(tmp_path):
    for k in range(12):
        _files(tmp_path, **{f"f{k}": f"include: [{{file: f{k + 1}.yaml, namespace: n}}]\n"})
    _files(tmp_path, f12="nodes: [{id: a, node: nodes.std.demo:Counter}]\n")
    assert "nested deeper than 8 files" in _error(tmp_path / "f0.yaml")
    _files(tmp_path, leaf="nodes: [{id: a, node: nodes.std.demo:Counter}]\n")
    fan = "include:\n" + "".join(f"  - {{file: {{f}}, namespace: n{k}}}\n" for k in range(20))
    _files(tmp_path, wide=fan.replace("{f}", "leaf.yaml"))
    _files(tmp_path, wider=fan.replace("{f}", "wide.yaml"))      # 20 x 20 leaves: 400 nodes, fine
    assert len(load_launch(tmp_path / "wider.yaml").nodes) == 400
    _files(tmp_path, widest=fan.replace("{f}", "wider.yaml"))    # 8,420 files: refused, not read
    assert "more than 500 files included in all" in _error(tmp_path / "widest.yaml")
    many = "nodes:\n" + "".join(f"  - {{id: c{k}, node: nodes.std.demo:Counter}}\n" for k in range(150))
    _files(tmp_path, many=many, fat=fan.replace("{f}", "many.yaml"))
    assert "the includes expand to more than 2000 nodes" in _error(tmp_path / "fat.yaml")


# -- remap -------------------------------------------------------------------------------------
def test_node_remap_of_a_source_and_of_an_output(tmp_path):
    path = _files(tmp_path, g="""
    name: g
    nodes:
      - &c {id: counter, node: nodes.std.demo:Counter}
      - {<<: *c, id: other}
      - id: scale
        node: nodes.std.demo:Scale
        inputs: {value: counter/value}
        remap: {counter/value: other/value, value: scaled}
      - {id: printer, node: nodes.std.demo:Printer, inputs: {value: scale/scaled}}
    """)
    launch = load_launch(path)
    assert launch.node("scale").inputs == {"value": "other/value"}
    assert launch.node("printer").inputs == {"value": "scale/value"}          # the wire topic stays <id>/<output>
    assert launch.node("scale").renamed == {"value": "scaled"} and "calls it scale/scaled" in to_text(launch)
    assert plan(launch, token="t")["scale"].expect_subscribers == {"scale/value": 1}


REMAP_ERRORS = [
    ("remap: {counter/value: nobody/value}", "", r"g.yaml:7: remap counter/value -> nobody/value: node 'scale': "
                                                 r"input 'value' comes from 'nobody/value': no node 'nobody'"),
    ("remap: {counter/value: counter/nothing}", "", r"g.yaml:7: remap counter/value -> counter/nothing: node 'scale': "
                                                    r"input 'value': node 'counter' has no output 'nothing'"),
    ("remap: {countr/value: counter/value}", "", r"g.yaml:7: node 'scale': remap 'countr/value' matches none"),
    ("remap: {valu: scaled}", "", r"g.yaml:7: node 'scale': remap of output 'valu': no such output"),
    ("remap: {value: scaled}", "scale/value", r"g.yaml:10: node 'printer': input 'value': scale's output 'value' is "
                                              r"remapped to 'scaled' \(.*g.yaml:7\)"),
    ("remap: {value: 'a/b'}", "", "the new name 'a/b' is letters"),
    ("remap: [value]", "", "'remap' maps"),
]


@pytest.mark.parametrize("remap, printer_src, message", REMAP_ERRORS)
def test_remap_errors_name_the_remap(tmp_path, remap, printer_src, message):
    text = ("name: g\nnodes:\n  - {id: counter, node: nodes.std.demo:Counter}\n  - id: scale\n"
            "    node: nodes.std.demo:Scale\n    inputs: {value: counter/value}\n    " + remap + "\n")
    if printer_src:
        text += f"  - id: printer\n    node: nodes.std.demo:Printer\n    inputs: {{value: {printer_src}}}\n"
    path = _files(tmp_path, g=text)
    got = _error(path)
    assert re.search(message, got), got


# -- params_file -------------------------------------------------------------------------------
def test_params_file_is_merged_under_explicit_params(tmp_path):
    path = _files(tmp_path, g="""
    name: g
    nodes:
      - id: counter
        node: nodes.std.demo:Counter
        params_file: [params/base.yaml, params/site.yaml]
        params: {rate_hz: 7}
    """, params__base="rate_hz: 1\nstart: 10\n", params__site="start: 20\n")
    assert load_launch(path).node("counter").params == {"rate_hz": 7, "start": 20}


def test_params_file_errors_name_the_params_file(tmp_path):
    bad = _files(tmp_path, g="name: g\nnodes:\n  - {id: c, node: nodes.std.demo:Counter, params_file: p.yaml}\n",
                 p="start: 1\nrate_hx: 5\n")
    text = _error(bad)
    assert text.startswith(f"{tmp_path / 'p.yaml'}:2: node 'c': ") and "unknown key 'rate_hx'" in text
    _files(tmp_path, p="rate_hz: .inf\n")
    assert _error(bad).startswith(f"{tmp_path / 'p.yaml'}:1: node 'c'")
    _files(tmp_path, p="- 1\n")
    assert "a params file is a mapping" in _error(bad)
    missing = _files(tmp_path, h="name: h\nnodes:\n  - {id: c, node: nodes.std.demo:Counter, params_file: q.yaml}\n")
    assert _error(missing).startswith(f"{missing}:3: node 'c': params_file 'q.yaml': no such file")


# -- the socket names, the command line, the shipped file --------------------------------------------
def test_ids_that_meet_in_a_socket_name_are_refused_before_start(tmp_path):
    long = "n" * 40
    path = _files(tmp_path, g=f"""
    name: g
    include: [{{file: pipe.yaml, namespace: {long}x}}, {{file: pipe.yaml, namespace: {long}y}}]
    """, pipe=PIPE)
    with pytest.raises(ConfigError, match="get the same socket name"):
        plan(load_launch(path), token="t")


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tether.cli", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=120)


def test_the_command_line_takes_args_and_refuses_undeclared_ones():
    res = _cli("check", "launch/two_sonars.yaml", "--arg", "range_m=10", "--arg", "scene=pier4")
    assert res.returncode == 0 and "ok (6 nodes, 2 connections)" in res.stdout, res.stderr
    res = _cli("check", "launch/two_sonars.yaml", "--arg", "rang_m=10")
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "Traceback" not in res.stderr
    assert "declares no arg 'rang_m' (did you mean 'range_m'?)" in res.stderr
    assert "--arg NAME=VALUE" in _cli("launch", "--help").stdout


def test_the_two_sonar_file_includes_one_pipeline_twice():
    launch = load_launch(REPO / "launch" / "two_sonars.yaml", args={"range_m": 15, "scene": "pier4"})
    assert {n.id for n in launch.nodes} == {f"{side}.{n}" for side in ("port", "starboard") for n in ("sim", "sonar", "imager")}
    port, starboard = launch.node("port.sonar").params, launch.node("starboard.sonar").params
    assert (port["range_m"], port["port"], port["frequency"]) == (15, 52190, "low")
    assert (starboard["range_m"], starboard["port"], starboard["frequency"], starboard["beams"]) == (10, 52194, "high", 256)
    assert port["stamp"] == "device" and port["ping_rate"] == "high"               # from params/oculus_m1200d.yaml
    assert launch.node("port.sim").params["scene"] == "pier4"
    assert launch.node("starboard.imager").inputs == {"ping": "starboard.sonar/ping"}


def test_an_included_pipeline_runs_under_its_namespace(tmp_path, runtime_env):
    """The runtime takes namespaced ids as they are: sockets, registry and recorded topics."""
    _files(tmp_path, pipe=PIPE)
    path = _files(tmp_path, top="""
    name: top
    include:
      - {file: pipe.yaml, namespace: left, args: {rate: 20}}
      - {file: pipe.yaml, namespace: right, args: {rate: 20, gain: 3}}
    """)
    log = tmp_path / "run.mcap"
    res = launch_until([str(path), "--record", str(log)], runtime_env, recording_for(1.0))
    assert res.returncode == 0, res.stderr
    from tether.log import LogReader

    reader = LogReader(log)
    assert {"left.counter/value", "left.scale/value", "right.scale/value"} <= set(reader.info().topics)
    right = [reader.decode(r).data for r in reader.messages(["right.scale/value"])]
    left = [reader.decode(r).data for r in reader.messages(["left.scale/value"])]
    assert right and left and all(v % 3 == 0 for v in right) and all(v % 2 == 0 for v in left)
