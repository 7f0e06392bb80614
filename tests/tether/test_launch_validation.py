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
    ("name: g\nnodez: []\n", "unknown top-level key"),
    ("name: g\nnodes: []\n", "non-empty list"),
    ("name: g\nnodes:\n  - {id: 1x, node: nodes.std.demo:Counter}\n", "id '1x'"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.nothere:Counter}\n", "node 'a': cannot import module 'nodes.std.nothere'"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.demo:Nope}\n", "node 'a': module 'nodes.std.demo' has no class 'Nope'"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.demo}\n", "'module.path:ClassName'"),
    ("name: g\nnodes:\n  - {id: a, node: tether.errors:ConfigError}\n", "is not a tether Node"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.demo:Counter, params: {rate_hz: fast}}\n", "node 'a'.*rate_hz"),
    ("name: g\nnodes:\n  - {id: a, node: nodes.std.demo:Counter, params: {rate_hz: 0}}\n", "positive rate"),
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
