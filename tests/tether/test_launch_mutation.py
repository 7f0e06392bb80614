"""Every shipped launch file under seeded mutation: ``tether check`` ends in success or one
:class:`ConfigError` line naming a file (and the line), never another exception, never a hang.

The mutants are textual (bit flips, a cut, a line deleted, duplicated or re-indented, YAML
punctuation or control bytes dropped in) and structural (the file read, one value swapped for
one of another type, a list for a mapping, an unknown key, a key deleted, a node duplicated, an
input rewired to another node's output, a timer or the node itself, the class swapped), plus
a fixed list of hostile files (empty, not a mapping, a "billion laughs", deep nesting, a
self-including file, non-UTF-8, NUL bytes, /dev/zero as an include). Model:
tests/drivers/test_import_mutation.py.
"""
from __future__ import annotations

import copy
import pathlib
import random
import shutil
from pathlib import Path
from typing import Any

import pytest
import yaml

from tether.errors import ConfigError
from tether.launch import load_launch
from tether.yamlsafe import load_yaml, load_yaml_file

REPO = Path(__file__).resolve().parents[2]
LAUNCH = REPO / "launch"
ODD: list[Any] = [None, "", "x", "1e999", 0, -1, 1e308, float("nan"), float("inf"), True, [], {}, [1, "a"],
                  {"a": {"b": None}}, "timer/hz/0", "timer/ms/-5", "timer/hz/1e9", "nope/out", "$(arg missing)",
                  "$(dirname)", "$(", "nodes.std.demo:Nope", "no.such.module:X", "os:system", ":", "a" * 300, "\x00",
                  2**70, -(2**70)]
CLASSES = ["nodes.std.demo:Counter", "nodes.std.demo:Nope", "nope:Nope", "tether.node:Node", "nodes.std.demo",
           "tether.errors:ConfigError", "json:loads", "nodes.std.demo:Scale"]
SNIPPETS = [b"\xff\xfe", b"\t", b"{", b"[", b"&a", b"*a", b"<<: ", b": ", b"- ", b"\x00", b"\x7f", b"\x0c",
            b"!!python/object/apply:os.system ", b"%YAML 1.1\n---\n", b"\n---\n", b"$(arg ", b"$(dirname)"]
LAUGHS = b"".join(b"%c: &%c [%s]\n" % (ord("a") + k, ord("a") + k, b",".join([b"*%c" % (ord("a") + k - 1)] * 9) if k else b"x")
                  for k in range(7))
HOSTILE = [b"", b"\n", b"---\n", b"null", b"[]", b"- a\n", b"42", b"name: x\n", b"name: x\nnodes:\n",
           b"name: x\nnodes: {}\n", b"\xff\xfe\x00n", LAUGHS, b"[" * 10000 + b"]" * 10000, b"{" * 100000,
           b"a:\n" + b"".join(b" " * (i + 1) + b"a:\n" for i in range(200)),
           b"name: x\nnodes:\n  - &n {id: a, node: 'nodes.std.demo:Counter', inputs: *n}\n",
           b"\xef\xbb\xbfname: x\nnodes: []\n", b"name: x\nnodes: []\n\x00", b"name: !!binary aGk=\nnodes: []\n",
           b"name: x\nnodes: []\nmachines: [a]\n", b"name: x\nnodes: []\nlinks: 5\n", b"name: x\nnodes: []\nargs: [1]\n",
           b"name: x\nnodes: []\ninclude: x.yaml\n", b"name: x\nnodes: []\ninclude: [{file: /dev/zero}]\n",
           b"name: x\nnodes: []\ninclude: [{file: .}]\n", b"name: x\ninclude: [{file: SELF}]\n", b"? [a]\n: 1\n",
           b"{? {a: 1}: 2}\n", b"name: 2020-01-01\nnodes: []\n",
           b"name: x\nnodes:\n  - id: a\n    node: nodes.std.demo:Scale\n    inputs: {value: a/value}\n",
           b"name: x\nnodes:\n  - {id: a, node: 'nodes.std.demo:Counter', params: {rate_hz: .nan}}\n"]


def _paths(obj: Any, path: tuple = ()) -> list[tuple]:
    out = [path] if path else []
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, path + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += _paths(v, path + (i,))
    return out


def structural(doc: Any, rng: random.Random) -> Any:
    """The document with one seeded change to its values, keys, wiring or node classes."""
    doc = copy.deepcopy(doc)
    where = rng.choice(_paths(doc))
    parent = doc
    for step in where[:-1]:
        parent = parent[step]
    last = where[-1]
    nodes = [n for n in doc.get("nodes") or [] if isinstance(n, dict)]
    op = rng.randrange(7)
    if op == 0:
        parent[last] = copy.deepcopy(rng.choice(ODD))
    elif op == 1 and isinstance(parent, dict):
        parent[rng.choice(["zzz", "Params", 3, None, "inputs2"])] = 1
    elif op == 2 and nodes:                          # a topic wired to another input, a timer, or itself
        node = rng.choice(nodes)
        ids = [n.get("id") for n in nodes]
        src = rng.choice([f"{rng.choice(ids)}/{rng.choice(['value', 'image', 'pose', 'out', 'ping', '_stats'])}",
                          f"{node.get('id')}/{rng.choice(['value', 'image', 'pose'])}", "timer/hz/10", "timer/ms/3"])
        inputs = node.get("inputs")
        if isinstance(inputs, dict) and inputs:
            inputs[rng.choice(list(inputs))] = src
        else:
            node["inputs"] = {rng.choice(["value", "ping", "tick", "x"]): src}
    elif op == 3:                                    # a list where a mapping is, and the other way round
        value = parent[last]
        parent[last] = (list(value.items()) if isinstance(value, dict) else
                        {str(i): x for i, x in enumerate(value)} if isinstance(value, list) else [value])
    elif op == 4 and nodes:
        rng.choice(nodes)["node"] = rng.choice(CLASSES)
    elif op == 5:
        del parent[last]
    elif nodes:
        doc["nodes"].append(copy.deepcopy(rng.choice(nodes)))
    return doc


def textual(data: bytes, rng: random.Random) -> bytes:
    """The file's bytes with one seeded edit: flips, a cut, a line deleted/duplicated/re-indented, a snippet."""
    out, lines = bytearray(data), data.split(b"\n")
    op = rng.randrange(6)
    if op == 0:
        for _ in range(rng.randint(1, 8)):
            out[rng.randrange(len(out))] ^= 1 << rng.randrange(8)
        return bytes(out)
    if op == 1:
        return bytes(out[:rng.randrange(len(out))])
    i = rng.randrange(len(lines))
    if op == 2:
        del lines[i]
    elif op == 3:
        lines.insert(i, lines[i])
    elif op == 4:
        lines[i] = lines[i].replace(b"  ", b" ", 1) if rng.random() < 0.5 else b"  " + lines[i]
    else:
        at = rng.randrange(len(out) + 1)
        out[at:at] = rng.choice(SNIPPETS)
        return bytes(out)
    return b"\n".join(lines)


def _cases(per_file: int, seed: int) -> list[tuple[str, bytes]]:
    rng = random.Random(seed)
    cases = []
    for f in sorted(LAUNCH.glob("*.yaml")):
        data = f.read_bytes()
        doc = yaml.safe_load(data)
        for k in range(per_file):
            cases.append((f"{f.name}#{k}", textual(data, rng) if k % 2 else
                          yaml.safe_dump(structural(doc, rng), allow_unicode=True).encode()))
    return cases + [(f"hostile#{k}", h) for k, h in enumerate(HOSTILE)]


def test_every_launch_file_mutant_is_a_result_or_one_config_error_line(tmp_path):
    work = tmp_path / "launch"
    shutil.copytree(LAUNCH, work)                    # mutants sit beside the files they include
    tally = {"ok": 0, "refused": 0}
    for k, (name, data) in enumerate(_cases(per_file=16, seed=62)):
        target = work / f"mutant_{k}.yaml"
        target.write_bytes(data.replace(b"SELF", target.name.encode()))
        try:
            load_launch(target)
            tally["ok"] += 1
        except ConfigError as exc:                   # anything else fails the test with its traceback
            text = str(exc)
            assert text and "\n" not in text and "Traceback" not in text, (name, text)
            assert str(work) in text or text.startswith("/dev/"), (name, text)   # names the file at fault
            tally["refused"] += 1
        target.unlink()
    assert tally["refused"] > 200 and tally["ok"] > 30, tally      # the mutants reached the validator


# -- the crash classes found, pinned ---------------------------------------------------------
@pytest.mark.parametrize("char", ["\x00", "\x7f", "\x0c", "\x1a", "\ufffe"])
def test_a_control_character_is_one_line_naming_its_line(char):
    """PyYAML's reader refuses these in its constructor, which ran outside the error handling:
    ``yaml.reader.ReaderError: unacceptable character #x007f`` came out as a traceback."""
    with pytest.raises(ConfigError, match=r"^f\.yaml:3: character 0x[0-9a-f]+ is not allowed in YAML text"):
        load_yaml(f"name: x\nnodes:\n  - id: a{char}\n", where="f.yaml")


def test_a_control_character_in_a_launch_file_is_a_config_error(tmp_path):
    path = tmp_path / "f.yaml"
    path.write_bytes(b"name: x\nnodes:\n  - id: a\x7f\n    node: nodes.std.demo:Counter\n")
    with pytest.raises(ConfigError, match=r"f\.yaml:3: character 0x7f"):
        load_launch(path)


def test_an_endless_file_is_read_no_further_than_the_size_limit(monkeypatch, tmp_path):
    """``tether check /dev/zero`` (or an include of it) read the whole file first: MemoryError after
    eating the machine's memory."""
    monkeypatch.setattr(pathlib.Path, "read_bytes", lambda self: pytest.fail("an unbounded read"))
    monkeypatch.setattr("tether.yamlsafe.MAX_BYTES", 1000)
    big = tmp_path / "big.yaml"
    big.write_bytes(b"# " + b"x" * 2000 + b"\n")
    with pytest.raises(ConfigError, match=r"big\.yaml: larger than a configuration file can be \(1000 bytes\)"):
        load_yaml_file(big)
    if Path("/dev/zero").exists():       # refused before reading: it is not a regular file
        with pytest.raises(ConfigError, match=r"^/dev/zero: a device or pipe, not a configuration file"):
            load_yaml_file("/dev/zero")


def test_an_unknown_arg_hint_does_not_offer_dirname(tmp_path):
    """$(dirname) waits among the args: the hint listed '$dirname' as a declared arg."""
    path = tmp_path / "f.yaml"
    path.write_text("name: x\nargs: {rate: 5}\nnodes:\n  - {id: a, node: 'nodes.std.demo:Counter', "
                    "params: {rate_hz: $(arg rte)}}\n")
    with pytest.raises(ConfigError) as info:
        load_launch(path)
    assert "declares no arg 'rte'" in str(info.value) and "$dirname" not in str(info.value)
    path.write_text(path.read_text().replace("args: {rate: 5}", "args: {}"))
    with pytest.raises(ConfigError) as info:
        load_launch(path)
    assert "declared: none" in str(info.value), str(info.value)


def test_command_line_overrides_of_every_file_are_a_result_or_one_line():
    """``tether check FILE --param NODE.KEY=VALUE --arg NAME=VALUE`` with seeded keys and values
    (the file's own parameters and args, and unknown ones), each VALUE as the shell hands it."""
    from tether.launch import parse_launch_args, parse_overrides

    rng = random.Random(7)
    texts = ["nan", "inf", "-1", "0", "1e999", "", "[1, 2]", "{a: 1}", "x", "true", "null", "&a [*a]", "'", "[",
             "\x7f", "9" * 40, "timer/hz/0", "$(arg x)"]
    tally = {"ok": 0, "refused": 0}
    for f in sorted(LAUNCH.glob("*.yaml")):
        doc = yaml.safe_load(f.read_bytes())
        nodes = [n for n in doc.get("nodes") or [] if isinstance(n, dict)]
        declared = list(doc.get("args") or {})
        for _ in range(6):
            node = rng.choice(nodes + [{"id": "nope"}])
            keys = list(node.get("params") or {}) + ["zzz"]
            params = [f"{node['id']}.{rng.choice(keys)}={rng.choice(texts)}"]
            args = [f"{rng.choice(declared + ['zzz'])}={rng.choice(texts)}"] if declared and rng.random() < 0.5 else []
            try:
                load_launch(f, parse_overrides(params), args=parse_launch_args(args))
                tally["ok"] += 1
            except ConfigError as exc:
                text = str(exc)
                assert text and "\n" not in text and "Traceback" not in text, (f.name, params, args, text)
                tally["refused"] += 1
    assert tally["refused"] > 60, tally
