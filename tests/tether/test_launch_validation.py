"""Every launch-file validation error is one clear line naming the file, node and field."""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tether.errors import ConfigError
from tether.launch import load_launch, parse_overrides, plan

GOOD = """
name: g
nodes:
  - id: counter
    node: nodes.std.demo:Counter
    params: {rate_hz: 5}
  - id: scale
    node: nodes.std.demo:Scale
    inputs: {value: counter/value}
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "g.yaml"
    path.write_text(textwrap.dedent(text))
    return path


CASES = [
    ("name: g\nnodes: [\n", "not valid YAML"),
    ("- a\n- b\n", "a launch file is a mapping"),
    ("name: g\nnodez: []\n", "unknown key 'nodez' \\(did you mean 'nodes'\\?\\)"),
    ("name: g\nnodes: []\n", "non-empty list"),
    ("name: g\nnodes:\n  - {id: 1x, node: nodes.std.demo:Counter}\n", "id '1x'"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.nothere:Counter}\n", "node 'a': cannot import module 'nodes.std.nothere'"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.demo:Nope}\n", "node 'a': module 'nodes.std.demo' has no class 'Nope'"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.demo}\n", "'module.path:ClassName'"),
    ("name: g\nnodes:\n  - {id: a, node: tether.errors:ConfigError}\n", "is not a tether Node"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.demo:Counter, params: {rate_hz: fast}}\n", "node 'a'.*rate_hz"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.demo:Counter, params: {rate_hz: 0}}\n", r"rate in \(0, 10000"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.demo:Counter}\n  - {id: a, node: nodes.std.demo:Counter}\n", "'a' is used twice"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.demo:Counter}\n  - {id: b, node: nodes.std.demo:Scale, inputs: {valu: a/value}}\n",
     "node 'b': unknown input 'valu'"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.demo:Counter}\n  - {id: b, node: nodes.std.demo:Scale, inputs: {value: c/value}}\n",
     "node 'b': input 'value' comes from 'c/value': no node 'c'"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.demo:Counter}\n  - {id: b, node: nodes.std.demo:Scale, inputs: {value: a/val}}\n",
     "node 'b': input 'value': node 'a' has no output 'val'"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.perf:Echo}\n  - {id: b, node: nodes.std.demo:Scale, inputs: {value: a/pong}}\n",
     "input 'value' takes std.Float64 but a/pong publishes std.Bytes"),
    ("name: g\nnodes:\n  - {id: b, node: nodes.std.demo:Scale, inputs: {value: timer/hz/5}}\n", "not a timer"),
    ("name: g\nnodes:\n  - {id: b, node: nodes.std.demo:Scale, restart: always}\n", "restart 'always'"),
    ("name: g\nnodes:\n  - {id: b, node: nodes.std.demo:Scale, color: red}\n", "unknown key"),
    ("name: g\nmachines: {m1: {host: 127.0.0.1}}\nnodes:\n  - {id: b, node: nodes.std.demo:Scale}\n", "every node names its 'machine'"),
    ("name: g\nmachines: {m1: {host: 127.0.0.1}}\nnodes:\n  - {id: b, node: nodes.std.demo:Scale, machine: m2}\n", "machine 'm2' is not declared"),
]


@pytest.mark.parametrize("text, message", CASES)
def test_each_validation_error_names_file_node_and_field(tmp_path: Path, text: str, message: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError, match=message) as info:
        load_launch(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


LAUGHS = "".join(f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}" if i else "x"] * 9) + "]\n" for i in range(9))
HEAD = "name: g\nnodes:\n  - id: a\n    node: nodes.std.demo:Counter\n"

# (file text, the line the error must name, what it must say): the malformed files that
# were accepted, hung `tether check` or ended in a traceback before.
HOSTILE = [
    (LAUGHS + "name: g\nnodes: [*l8]\n", 6, "billion laughs"),     # l5 is the first past 10^5
    ("name: g\nx: &x [*x]\nnodes: []\n", 2, "refers to the node that contains it"),
    ("name: g\nnodes: " + "[" * 5000 + "]" * 5000 + "\n", 2, "nested deeper than 64"),
    ("name: g\nname: h\nnodes: []\n", 2, "duplicate key 'name' \\(first on line 1\\)"),
    (HEAD + "    id: b\n", 5, "duplicate key 'id'"),
    (HEAD + "    params:\n      rate_hz: 5\n      rate_hz: 6\n", 7, "duplicate key 'rate_hz'"),
    (HEAD + "    params: {rate_hz: 1e30}\n", 5, r"rate in \(0, 10000"),
    (HEAD + "    params: {rate_hz: .inf}\n", 5, "rate_hz must be a finite number"),
    (HEAD + "    params: {rate_hz: .nan}\n", 5, "rate_hz must be a finite number"),
    (HEAD + "    params:\n      start: 1\n      rate_hx: 5\n", 7, "unknown key 'rate_hx' \\(did you mean 'rate_hz'\\?\\)"),
    (HEAD + "    params: [rate_hz, 5]\n", 5, "'params' must be a mapping"),
    (HEAD + "    max_restarts: -5\n", 5, r"max_restarts must be an integer in \[0, 1000\]"),
    (HEAD + "    max_restarts: 1.5\n", 5, "max_restarts must be an integer"),
    (HEAD + "    max_restarts: true\n", 5, "max_restarts must be an integer"),
    (HEAD + "    rt_priority: 99\n", 5, r"rt_priority must be an integer in \[0, 98\]"),
    (HEAD + "    rt_priority: -1\n", 5, r"rt_priority must be an integer in \[0, 98\]"),
    (HEAD + "    rt_priority: true\n", 5, "rt_priority must be an integer"),
    (HEAD + "    env: [A, B]\n", 5, "'env' must map NAME: value, not a list"),
    (HEAD + "    env: {A: [1]}\n", 5, "must be text or a number"),
    (HEAD + "    env: {1A: x}\n", 5, "a variable name is"),
    (HEAD + "    env: {A: \"x\\0y\"}\n", 5, "NUL"),
    (HEAD + "    restart: [on-failure]\n", 5, "restart"),
    (HEAD + "    inputs: [a]\n", 5, "'inputs' must map"),
    (HEAD + "    inputs: {tick: timer/hz/0}\n", 5, "input 'tick': timer 'timer/hz/0' must tick between"),
    (HEAD + "    inputs:\n      tick: timer/hz/1000000000\n", 6, "10000 Hz"),
    (HEAD + "    inputs:\n      tick: timer/ms/0.00001\n", 6, "10000 Hz"),
    ("name: g\nmachines: {m: {host: h, port_base: 99999}}\nnodes:\n  - {id: a, node: nodes.std.demo:Counter, machine: m}\n",
     2, r"port_base must be an integer in \[1024, 65000\]"),
    ("name: g\nmachines: {m: {host: h, port: 1}}\nnodes:\n  - {id: a, node: nodes.std.demo:Counter, machine: m}\n",
     2, "unknown key 'port'"),
    ("name: g\nmachines: [m]\nnodes:\n  - {id: a, node: nodes.std.demo:Counter}\n", 2, "'machines' must map"),
    ("name: [g]\nnodes:\n  - {id: a, node: nodes.std.demo:Counter}\n", 1, "name \\['g'\\] must be"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.demo:Counter}\n  - {id: a, node: nodes.std.demo:Scale}\n", 4,
     "'a' is used twice"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.demo:Counter, {x: 1}: 2}\n", 3, "key must be a scalar"),
]


@pytest.mark.parametrize("text, line, message", HOSTILE)
def test_hostile_launch_files_are_one_line_naming_file_and_line(tmp_path: Path, text: str, line: int,
                                                                 message: str) -> None:
    path = tmp_path / "g.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message) as info:   # bombs: refused by their count, before expansion
        load_launch(path)
    assert str(info.value).startswith(f"{path}:{line}: ") and "\n" not in str(info.value)


def test_an_anchor_merged_and_overridden_is_fine(tmp_path: Path) -> None:
    path = tmp_path / "g.yaml"
    path.write_text("name: g\nnodes:\n  - &c {id: a, node: nodes.std.demo:Counter, params: {rate_hz: 5}}\n"
                    "  - {<<: *c, id: b}\n")
    launch = load_launch(path)
    assert [n.id for n in launch.nodes] == ["a", "b"] and launch.node("b").params == {"rate_hz": 5}


def test_missing_file_and_bad_override(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such launch file"):
        load_launch(tmp_path / "nope.yaml")
    path = _write(tmp_path, GOOD)
    with pytest.raises(ConfigError, match="unknown node 'nobody'"):
        load_launch(path, parse_overrides(["nobody.gain=3"]))
    with pytest.raises(ConfigError, match="NODE.KEY=VALUE"):
        parse_overrides(["gain=3"])
    with pytest.raises(ConfigError, match="gain"):
        load_launch(path, parse_overrides(["scale.gain=[1,2]"]))
    with pytest.raises(ConfigError, match="^--param: node 'scale'.*gain must be a finite number"):
        load_launch(path, parse_overrides(["scale.gain=.inf"]))


def test_good_file_plans_exact_topics_and_subscriber_counts(tmp_path: Path) -> None:
    launch = load_launch(_write(tmp_path, GOOD), parse_overrides(["scale.gain=3"]))
    assert launch.node("scale").params["gain"] == 3
    specs = plan(launch, token="t")
    assert specs["scale"].inputs["value"].topic == "counter/value"
    assert specs["scale"].inputs["value"].endpoint == specs["counter"].binds[0]
    assert specs["counter"].expect_subscribers == {"counter/value": 1}
    assert specs["counter"].binds[0].startswith("ipc://") and specs["scale"].curve is None


def test_check_cli_exits_nonzero_with_one_line_and_no_traceback(tmp_path: Path) -> None:
    path = _write(tmp_path, "name: g\nnodes:\n  - {id: a, node: nodes.std.demo:Nope}\n")
    res = subprocess.run([sys.executable, "-m", "tether.cli", "check", str(path)], capture_output=True, text=True)
    assert res.returncode == 2
    assert res.stderr.strip().count("\n") == 0 and "Traceback" not in res.stderr
    assert "has no class 'Nope'" in res.stderr
    ok = subprocess.run([sys.executable, "-m", "tether.cli", "check", str(_write(tmp_path, GOOD))],
                        capture_output=True, text=True)
    assert ok.returncode == 0 and "ok (2 nodes, 1 connections)" in ok.stdout


def test_a_node_statistics_are_an_output_a_monitor_can_take(tmp_path: Path) -> None:
    """``<id>/_stats`` is every node's NodeStats stream: wired like an output, typed like one."""
    from nodes.slam.dslam_monitor import TeamMonitor  # noqa: F401  (a node with NodeStats inputs)

    ok = """
    name: g
    nodes:
      - {id: counter, node: nodes.std.demo:Counter}
      - {id: mon, node: nodes.slam.dslam_monitor:TeamMonitor, params: {robots: 1, graph: x.g2o},
         inputs: {stats_0: counter/_stats}}
    """
    launch = load_launch(_write(tmp_path, ok))
    assert plan(launch, token="t")["mon"].inputs["stats_0"].topic == "counter/_stats"
    with pytest.raises(ConfigError, match="takes std.Float64 but counter/_stats publishes std.NodeStats"):
        load_launch(_write(tmp_path, GOOD.replace("counter/value", "counter/_stats")))
