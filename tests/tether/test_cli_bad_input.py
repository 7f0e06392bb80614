"""The command line on wrong input, as a new user meets it: one ``tether: error:`` line and a
non-zero exit, never a traceback, never a silent hang, never an input destroyed.

In-process through :func:`tether.cli.main` (each case fails before any node starts), so the
suite stays fast. Each test names the bug it pins and what the old code did.
"""
from __future__ import annotations

import argparse
import threading
from pathlib import Path

import pytest

from msgs.std import Float64
from tether.cli import main
from tether.errors import ConfigError, DecodeError
from tether.log import LogReader, LogWriter
from tether.node import Node

REPO = Path(__file__).resolve().parents[2]


def _log(path: Path, n: int = 20) -> Path:
    with LogWriter(path) as w:
        for i in range(n):
            w.write("a/value", Float64(data=float(i)), log_time_ns=1_000_000_000 + i * 10_000_000)
    return path


def _one_error_line(capsys: pytest.CaptureFixture, *needles: str) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    last = err.splitlines()[-1]
    assert last.startswith("tether: error: ") and all(n in last for n in needles), err
    return last


# -- logs that are not logs ------------------------------------------------------------------
@pytest.mark.parametrize("verb", [["log"], ["replay", "--rate", "0", "--allow-empty"], ["export", "foxglove", "-o", "OUT"]])
def test_a_directory_or_a_text_file_given_as_a_log_is_one_line(tmp_path, capsys, runtime_env, verb):
    """A directory was an IsADirectoryError traceback; a text file 'ended early at byte 0' and
    replay/export of it exited 0 having done nothing."""
    folder = tmp_path / "run.mcap"
    folder.mkdir()
    text = tmp_path / "notes.mcap"
    text.write_text("hello\n" * 20)
    argv = [str(tmp_path / "out.mcap") if a == "OUT" else a for a in verb]
    assert main([*argv, str(folder)]) == 2
    _one_error_line(capsys, "run.mcap: a directory, not a log file")
    assert main([*argv, str(text)]) == 2
    _one_error_line(capsys, "notes.mcap: not an MCAP log")


def test_a_log_cut_before_its_first_record_still_reads_as_empty(tmp_path):
    """The magic check leaves a log killed before it wrote its first bytes readable (recovered, empty)."""
    whole = _log(tmp_path / "a.mcap").read_bytes()
    for size in (0, 3, 8):
        cut = tmp_path / f"cut{size}.mcap"
        cut.write_bytes(whole[:size])
        assert list(LogReader(cut).messages()) == []
    with pytest.raises(DecodeError, match="not an MCAP log"):
        (tmp_path / "bad.mcap").write_bytes(b"\x89MCAX0\r\n")
        LogReader(tmp_path / "bad.mcap")


# -- an output that is the input -------------------------------------------------------------
def test_writing_over_the_input_is_refused_and_the_input_survives(tmp_path, capsys, runtime_env):
    """``tether log cut a.mcap -o a.mcap`` (and merge, --recover, export, import, replay --record)
    opened the output for writing first: the input was emptied, then '0 messages written'."""
    log = _log(tmp_path / "a.mcap")
    before = log.read_bytes()
    same = str(tmp_path / "." / "a.mcap")                  # another spelling of the same file
    cases = [["log", "cut", str(log), "-o", same], ["log", "merge", str(log), "-o", same],
             ["log", str(log), "--recover", "-o", same], ["export", "foxglove", str(log), "-o", same],
             ["replay", str(log), "--into", "nodes.std.demo:Scale", "--map", "value=a/value", "--record", same,
              "--lockstep"]]
    for argv in cases:
        assert main(argv) == 2, argv
        _one_error_line(capsys, "is the input", "would destroy the input")
        assert log.read_bytes() == before, argv
    can = tmp_path / "c.log"
    can.write_text("(1.000000) can0 123#00\n")
    assert main(["import", "candump", str(can), "-o", str(can)]) == 2
    _one_error_line(capsys, "is the input")
    assert can.read_text() == "(1.000000) can0 123#00\n"


def test_an_output_that_is_a_directory_is_one_line(tmp_path, capsys):
    """``-o DIR`` was an IsADirectoryError traceback (log cut) or a Rust error naming no file (export)."""
    log = _log(tmp_path / "a.mcap")
    (tmp_path / "out").mkdir()
    assert main(["log", "cut", str(log), "-o", str(tmp_path / "out")]) == 2
    _one_error_line(capsys, "out: Is a directory")
    assert main(["export", "foxglove", str(log), "-o", str(tmp_path / "out")]) == 2
    _one_error_line(capsys, "out: cannot write the export there")


# -- option values -----------------------------------------------------------------------------
@pytest.mark.parametrize("argv", [
    ["launch", "missing.yaml", "--duration", "nan"],        # ran forever
    ["launch", "missing.yaml", "--duration", "-1"],         # stopped at once, exit 0
    ["run", "nodes.std.demo:Counter", "--duration", "inf"],
    ["replay", "x.mcap", "--start", "inf"],                 # OverflowError traceback
    ["replay", "x.mcap", "--end", "nan"],                   # 'cannot convert float NaN to integer'
    ["replay", "x.mcap", "--delay", "inf"],                 # OverflowError in threading
    ["replay", "x.mcap", "--rate", "nan"],
    ["record", "-o", "x.mcap", "--max-size", "inf"],        # OverflowError traceback
    ["topic", "hz", "a/b", "--window", "0"],
    ["topic", "hz", "a/b", "-w", "-5"],                     # 'no messages yet' for ever
    ["topic", "echo", "a/b", "-n", "0"],
    ["verify", "missing.yaml", "--faults", "-1"],
    ["slam", "optimize", "x.g2o", "--robust", "gnc", "--kernel-width", "-1"],   # ZeroDivisionError
    ["slam", "optimize", "x.g2o", "--max-iterations", "0"],
    ["selfcal", "a.png", "--chessboard", "2x5"],            # cv2.error traceback from findChessboardCorners
    ["selfcal", "a.png", "--chessboard", "abc"],            # "invalid literal for int() with base 10: 'abc'"
    ["foxglove", "--port", "-1"],                           # OverflowError from the Foxglove SDK
    ["foxglove", "--port", "99999"],
])
def test_an_option_value_out_of_its_range_is_refused_by_the_parser(argv, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "error: argument" in err and "Traceback" not in err


def test_a_parameter_given_as_the_text_nan_is_refused(tmp_path, capsys):
    """``--param scale.gain=nan`` reaches msgspec as the text 'nan', which it turns into a float NaN
    after the finite check had passed: ``tether check`` said ok, the graph ran with NaN."""
    from nodes.std.demo import Scale

    for text in ("nan", "inf", "-Infinity"):
        with pytest.raises(ConfigError, match=f"gain must be a finite number, got '{text}'"):
            Scale.make_config({"gain": text})
    assert Scale.make_config({"gain": "2.5"}).gain == 2.5
    assert main(["check", str(REPO / "launch/counter.yaml"), "--param", "scale.gain=nan"]) == 2
    _one_error_line(capsys, "gain must be a finite number")


# -- tether run ----------------------------------------------------------------------------------
@pytest.mark.parametrize("node, extra, needle", [
    ("Scale", ["--input", "nope=timer/hz/1"], "has no input 'nope' (inputs: value)"),   # ignored: ran unconnected
    ("Scale", ["--input", "value=timer/hz/1"], "takes std.Float64, not a timer"),      # handler error per tick
    ("Counter", ["--input", "tick=timer/abc"], "expected timer/hz/N or timer/ms/N"),   # AttributeError traceback
    ("Scale", ["--id", "a/b"], "--id 'a/b'"),                                          # a socket file's errno
])
def test_tether_run_refuses_wiring_the_launch_file_would_refuse(node, extra, needle, capsys, runtime_env):
    assert main(["run", f"nodes.std.demo:{node}", "--duration", "1", *extra]) == 2
    _one_error_line(capsys, needle)


def test_a_machine_asked_of_a_file_without_machines_is_an_error(runtime_env):
    """``tether launch counter.yaml --machine boat`` ignored --machine and started every node."""
    from tether.launch import load_launch
    from tether.supervisor import Supervisor

    with pytest.raises(ConfigError, match="--machine boat: the file declares no machines"):
        Supervisor(load_launch(REPO / "launch/counter.yaml"), machine="boat")


def test_replay_into_without_a_map_says_what_to_map(tmp_path, capsys):
    """It said '--topics  leaves none of the --map topics ()'."""
    log = _log(tmp_path / "a.mcap")
    assert main(["replay", str(log), "--into", "nodes.std.demo:Scale", "--record", str(tmp_path / "o.mcap"),
                 "--lockstep"]) == 2
    _one_error_line(capsys, "--into needs --map INPUT=TOPIC (Scale's inputs: value; the log's topics: a/value)")


def test_a_timer_that_is_not_one_is_a_config_error():
    from tether.launch import timer_period_ns

    with pytest.raises(ConfigError, match="expected timer/hz/N"):
        timer_period_ns("timer/abc")


def test_topic_echo_of_a_silent_topic_says_so_and_ends_with_its_graph(monkeypatch, capsys):
    """A topic no one publishes on: echo blocked in recv for ever, printing nothing."""
    import zmq

    from tether import introspect, registry
    from tether.registry import TopicInfo

    info = TopicInfo(topic="a/value", type_name="std.Float64", endpoint="ipc:///nonexistent/x", graph="g")
    sock = zmq.Context.instance().socket(zmq.SUB)
    sock.connect(info.endpoint)
    monkeypatch.setattr(introspect, "subscribe", lambda topic: (info, sock))
    monkeypatch.setattr(introspect, "WAIT_NOTICE_S", 0.2)
    listed = [{"a/value": info}]
    monkeypatch.setattr(registry, "topics", lambda: listed[-1])
    args = argparse.Namespace(topic="a/value", count=None, raw=False, duration=None)
    result: list[int] = []
    worker = threading.Thread(target=lambda: result.append(introspect._echo(args)), daemon=True)
    worker.start()
    worker.join(1.0)
    assert worker.is_alive()                            # still waiting while the graph runs ...
    listed.append({})                                   # ... which then stops
    worker.join(5.0)
    sock.close(linger=0)
    assert result == [1]
    err = capsys.readouterr().err
    assert "waiting for a/value (std.Float64, graph 'g'): nothing published yet" in err
    assert "a/value: its graph 'g' stopped" in err
    args.duration, listed[-1] = 0.5, {"a/value": info}     # --duration bounds a silent echo too
    sock = zmq.Context.instance().socket(zmq.SUB)
    monkeypatch.setattr(introspect, "subscribe", lambda topic: (info, sock))
    assert introspect._echo(args) == 0
    sock.close(linger=0)


# -- keys, slam, learn -----------------------------------------------------------------------------
def test_keystore_names_cannot_leave_the_keystore(tmp_path):
    """``tether keys init g --machines ../../etc`` wrote ../../etc.key beside the keystore's parent."""
    from tether import keystore

    with pytest.raises(ConfigError, match="machine '../../x'"):
        keystore.init(tmp_path / "store", ["../../x"])
    with pytest.raises(ConfigError, match="machine 'a b'"):
        keystore.init(tmp_path / "store", ["a b"])
    with pytest.raises(ConfigError, match="graph '../x'"):
        keystore.keystore_dir("../x")
    assert not any(tmp_path.rglob("*.key"))
    assert keystore.init(tmp_path / "store", ["boat", "shore-2"]) == ["boat", "shore-2"]


def test_a_malformed_pose_graph_is_one_line(tmp_path, capsys):
    """An id past int64 was an OverflowError traceback; a directory (or /dev/zero, read for ever)
    is refused before reading."""
    big = tmp_path / "big.g2o"
    big.write_text("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 99999999999999999999 1 0 0 1 0 0 1 0 1\n")
    assert main(["slam", "optimize", str(big)]) == 2
    _one_error_line(capsys, "big.g2o:2: vertex id 99999999999999999999 does not fit 64 bits")
    folder = tmp_path / "graph.g2o"
    folder.mkdir()
    assert main(["slam", "optimize", str(folder)]) == 2
    _one_error_line(capsys, "graph.g2o: not a regular file")


def test_a_file_that_is_not_a_checkpoint_is_named(tmp_path, capsys):
    """``tether learn eval run.mcap`` said only 'unpack(b) received extra data.'"""
    pytest.importorskip("jax")
    log = _log(tmp_path / "run.mcap")
    assert main(["learn", "eval", str(log)]) == 2
    _one_error_line(capsys, "run.mcap: not a tether PPO checkpoint (not msgpack")
    assert main(["learn", "eval", str(tmp_path / "none.ckpt")]) == 2
    _one_error_line(capsys, "none.ckpt: no such checkpoint")


def test_a_truncated_log_is_reported_once_per_reader(tmp_path, caplog):
    """info() of a log without a summary reads every message, then replay reads them again: the
    'log ends early' warning came twice."""
    whole = _log(tmp_path / "a.mcap", n=200).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[:len(whole) // 2])
    reader = LogReader(cut)
    with caplog.at_level("WARNING", logger="tether.log"):
        reader.info()
        list(reader.messages())
    assert sum("log ends early" in r.getMessage() for r in caplog.records) == 1


class BrokenPorts(Node):
    """A node whose port declaration fails (a node author's bug, met through the command line)."""

    @classmethod
    def resolve_ports(cls, config):
        raise RuntimeError("ports broke")


def test_a_node_whose_ports_fail_is_one_line_as_in_tether_check(tmp_path, capsys, runtime_env):
    """``tether check`` said 'params: RuntimeError: ports broke'; run and replay --into gave the traceback."""
    assert main(["run", f"{__name__}:BrokenPorts", "--duration", "1"]) == 2
    _one_error_line(capsys, "BrokenPorts: params: RuntimeError: ports broke")
    log = _log(tmp_path / "a.mcap")
    assert main(["replay", str(log), "--into", f"{__name__}:BrokenPorts", "--map", "value=a/value",
                 "--record", str(tmp_path / "o.mcap"), "--lockstep"]) == 2
    _one_error_line(capsys, "BrokenPorts: params: RuntimeError: ports broke")


def test_learn_train_refuses_settings_it_cannot_use(tmp_path, capsys):
    """A mistyped --env module was a ModuleNotFoundError traceback, an unknown --param a TypeError
    traceback; '--ppo lr=abc' and '--steps -5' trained (0 steps) and exited 0."""
    pytest.importorskip("jax")
    from nodes.learn.sim_node import load_sim

    with pytest.raises(ConfigError, match="cannot import 'sim.no_such_env'"):
        load_sim("sim.no_such_env:X")
    with pytest.raises(ValueError, match=r"ReachCar: unknown scenario parameter\(s\) \['nope'\] \(known: min_range_m"):
        load_sim("sim.car_env:ReachCar", params={"nope": 1})
    out = str(tmp_path / "p.ckpt")
    for setting, needle in [("lr=abc", "--ppo lr='abc': give a finite number"), ("lr=.nan", "give a finite number"),
                            ("n_steps=2.5", "give a whole number"), ("hidden=[64, 0]", "layer widths")]:
        assert main(["learn", "train", "--ppo", setting, "--steps", "10", "-o", out]) == 2, setting
        _one_error_line(capsys, needle)
    assert main(["learn", "train", "--param", "nope=1", "--steps", "10", "-o", out]) == 2
    _one_error_line(capsys, "unknown scenario parameter(s) ['nope']")
    with pytest.raises(SystemExit):
        main(["learn", "train", "--steps", "-5", "-o", out])
    assert not Path(out).exists()


def test_a_chessboard_search_on_a_tiny_image_is_not_found_not_a_traceback(tmp_path, capsys):
    """OpenCV's adaptive threshold asserts on an 8x8 image: a cv2.error traceback."""
    cv2 = pytest.importorskip("cv2")
    import numpy as np

    paths = [tmp_path / f"{k}.png" for k in range(3)]
    for path in paths:
        cv2.imwrite(str(path), np.zeros((8, 8), np.uint8))
    assert main(["selfcal", *map(str, paths), "--chessboard", "9x6"]) == 2
    _one_error_line(capsys, "the 9x6 pattern was found in 0 images")


def test_exporting_nothing_is_not_success(tmp_path, capsys):
    """A log cut inside its header exported 0 messages and exited 0 (replay and record say so)."""
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(_log(tmp_path / "a.mcap").read_bytes()[:8])
    assert main(["export", "foxglove", str(cut), "-o", str(tmp_path / "e.mcap")]) == 1
    assert "nothing exported from" in capsys.readouterr().err
    assert main(["export", "foxglove", str(cut), "-o", str(tmp_path / "e.mcap"), "--allow-empty"]) == 0
