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
from tether.node import Node, Tick

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
    """``-o DIR`` was an IsADirectoryError traceback (log cut) or a Rust error naming no file (export);
    now refused before reading the input (:func:`tether.paths.check_writable`)."""
    log = _log(tmp_path / "a.mcap")
    (tmp_path / "out").mkdir()
    assert main(["log", "cut", str(log), "-o", str(tmp_path / "out")]) == 2
    _one_error_line(capsys, "out: a directory, not a file to write")
    assert main(["export", "foxglove", str(log), "-o", str(tmp_path / "out")]) == 2
    _one_error_line(capsys, "out: a directory, not a file to write")


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
    assert main(["learn", "train", "--param", "nope=1", "--steps", "4096", "-o", out]) == 2
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
    assert main(["export", "foxglove", str(cut), "-o", str(tmp_path / "e.mcap"), "--allow-empty", "--overwrite"]) == 0


# -- second pass -------------------------------------------------------------------------------
class Feedback(Node):
    """A node that takes its own output back (a loop meant as feedback: its timer starts it)."""

    inputs = {"tick": Tick, "value": Float64}
    outputs = {"value": Float64}

    def on_tick(self, tick: Tick) -> dict[str, Float64]:
        return {"value": Float64(data=1.0)}

    def on_value(self, msg: Float64) -> None:
        pass


def test_an_input_wired_to_its_own_node_is_a_warning_and_strict_refuses_it(tmp_path, capsys):
    """``inputs: {value: scale/value}`` on node scale was accepted silently: a Tether topic has one
    publisher, so the input gets back only what the node published (here never: nothing starts it)."""
    dead = tmp_path / "dead.yaml"
    dead.write_text("name: x\nnodes:\n  - id: scale\n    node: nodes.std.demo:Scale\n    inputs: {value: scale/value}\n")
    assert main(["check", str(dead)]) == 0
    err = capsys.readouterr().err
    assert "tether: warning: " in err and "dead.yaml:5: node 'scale': input 'value' takes the node's own output " \
        "scale/value" in err and "nothing else starts the node: it never publishes" in err, err
    assert main(["check", "--strict", str(dead)]) == 1
    _one_error_line(capsys, "1 warning(s) with --strict")
    loop = tmp_path / "loop.yaml"
    loop.write_text(f"name: x\nnodes:\n  - id: fb\n    node: {__name__}:Feedback\n"
                    "    inputs: {tick: timer/hz/5, value: fb/value}\n")
    assert main(["check", str(loop)]) == 0
    err = capsys.readouterr().err
    assert "takes the node's own output fb/value" in err and "never publishes" not in err, err
    assert main(["check", "--strict", str(REPO / "launch/counter.yaml")]) == 0     # no warning: no error


def test_a_record_file_that_cannot_be_written_is_refused_before_anything_starts(tmp_path):
    """``tether launch f.yaml --record DIR`` ran the whole graph, then said the recorder failed."""
    from tether.launch import load_launch
    from tether.supervisor import Supervisor

    launch = load_launch(REPO / "launch/counter.yaml")
    a_file = tmp_path / "notes.txt"
    a_file.write_text("x")
    for target, needle in [(tmp_path, "a directory, not a file to write"),
                           (a_file / "run.mcap", "notes.txt is not a folder")]:
        with pytest.raises(ConfigError, match=f"^--record {target}: .*{needle}"):
            Supervisor(launch, record=str(target))
    Supervisor(launch, record=str(tmp_path / "new" / "run.mcap"))      # a folder still to be made is fine
    assert a_file.read_text() == "x" and list(tmp_path.iterdir()) == [a_file]    # nothing left behind



def test_launch_record_into_its_own_launch_file_is_refused(tmp_path, capsys):
    """``tether launch run.yaml --record run.yaml`` ran the graph and recorded over the launch file."""
    launch = tmp_path / "run.yaml"
    launch.write_text((REPO / "launch/counter.yaml").read_text())
    before = launch.read_text()
    assert main(["launch", str(launch), "--record", str(tmp_path / "." / "run.yaml"), "--duration", "1"]) == 2
    _one_error_line(capsys, "is the input", "would destroy the input")
    assert launch.read_text() == before


@pytest.mark.parametrize("action", ["hz", "bw"])
def test_topic_hz_and_bw_of_a_silent_topic_say_so_and_end_with_their_graph(action, monkeypatch, capsys):
    """Both printed 'no messages yet' each second for ever, also after the graph had stopped."""
    import zmq

    from tether import introspect, registry
    from tether.registry import TopicInfo

    info = TopicInfo(topic="a/value", type_name="std.Float64", endpoint="ipc:///nonexistent/x", graph="g")
    sock = zmq.Context.instance().socket(zmq.SUB)
    monkeypatch.setattr(introspect, "subscribe", lambda topic: (info, sock))
    monkeypatch.setattr(introspect, "WAIT_NOTICE_S", 0.2)
    listed = [{"a/value": info}]
    monkeypatch.setattr(registry, "topics", lambda: listed[-1])
    args = argparse.Namespace(action=action, topic="a/value", window=5.0, window_msgs=0, duration=None)
    result: list[int] = []
    worker = threading.Thread(target=lambda: result.append(introspect._rate(args)), daemon=True)
    worker.start()
    worker.join(0.8)
    assert worker.is_alive()                            # still waiting while the graph runs ...
    listed.append({})                                   # ... which then stops
    worker.join(5.0)
    assert result == [1]
    out, err = capsys.readouterr()
    assert "waiting for a/value (std.Float64, graph 'g'): nothing published yet" in err
    assert "a/value: its graph 'g' stopped" in err and out == ""
    args.duration, listed[-1] = 0.3, {"a/value": info}     # --duration bounds a silent one too
    assert introspect._rate(args) == 0
    sock.close(linger=0)


def test_learn_train_with_fewer_steps_than_one_rollout_is_an_error(tmp_path, capsys):
    """``--steps 10`` trained nothing (PPO updates on whole rollouts of n_steps x n_envs = 4096),
    wrote no checkpoint, and said 'wrote p.ckpt (0 steps)' with exit 0."""
    pytest.importorskip("jax")
    out = tmp_path / "p.ckpt"
    assert main(["learn", "train", "--steps", "10", "-o", str(out)]) == 2
    _one_error_line(capsys, "--steps 10 is less than one PPO rollout (n_steps 256 x --n-envs 16 = 4096 env steps)")
    assert main(["learn", "train", "--steps", "100", "--n-envs", "2", "--ppo", "n_steps=64", "-o", str(out)]) == 2
    _one_error_line(capsys, "= 128 env steps")
    assert not out.exists()


def _damaged(tmp_path: Path) -> tuple[Path, Path]:
    """A log with its first chunks' bytes flipped, and one cut in the middle (a killed recorder's)."""
    good = tmp_path / "good.mcap"
    with LogWriter(good, chunk_size=2000) as w:
        for i in range(300):
            w.write("a/value", Float64(data=float(i)), log_time_ns=1_000_000_000 + i * 10_000_000)
    data = bytearray(good.read_bytes())
    (tmp_path / "cut.mcap").write_bytes(data[:len(data) // 2])
    for k in range(400, 2000, 97):
        data[k] ^= 0x55
    (tmp_path / "flipped.mcap").write_bytes(data)
    return tmp_path / "flipped.mcap", tmp_path / "cut.mcap"


def test_merging_or_cutting_a_damaged_log_is_not_success_without_skip_bad(tmp_path, capsys):
    """``tether log merge`` logged 'skipping damaged chunk' errors, wrote the rest and exited 0."""
    flipped, cut = _damaged(tmp_path)
    out = str(tmp_path / "m.mcap")
    assert main(["log", "merge", str(flipped), str(cut), "-o", out]) == 1
    _one_error_line(capsys, "flipped.mcap: 3 damaged chunk(s); ", "cut.mcap: unreadable from byte ",
                    "m.mcap was written without their messages (--skip-bad to accept)")
    written = sum(1 for _ in LogReader(out).messages())
    assert 0 < written < 600                            # what was readable is kept
    assert main(["log", "merge", str(flipped), str(cut), "-o", out, "--skip-bad", "--overwrite"]) == 0
    assert main(["log", "cut", str(flipped), "-o", out, "--overwrite"]) == 1
    _one_error_line(capsys, "flipped.mcap: 3 damaged chunk(s)")
    assert main(["log", "cut", str(flipped), "-o", out, "--end", "100", "--skip-bad", "--overwrite"]) == 0
    assert main(["log", "merge", str(tmp_path / "good.mcap"), "-o", out, "--overwrite"]) == 0


def test_a_fifo_given_as_a_launch_file_is_refused_not_waited_on(tmp_path, capsys):
    """``tether check pipe.yaml`` on a FIFO with no writer blocked in open() for ever; /dev/zero was read
    up to the size bound. Refused before opening, as a log or a pose graph is."""
    import os

    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs here")
    fifo = tmp_path / "pipe.yaml"
    os.mkfifo(fifo)
    result: list[int] = []
    worker = threading.Thread(target=lambda: result.append(main(["check", str(fifo)])), daemon=True)
    worker.start()
    worker.join(5.0)
    if worker.is_alive():                               # unblock the old code's open() so the thread ends
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        pytest.fail("tether check blocked on a FIFO")
    assert result == [2]
    _one_error_line(capsys, "pipe.yaml: a device or pipe, not a configuration file")
    inc = tmp_path / "inc.yaml"                         # an include of it too
    inc.write_text(f"name: x\nnodes: []\ninclude: [{{file: {fifo}}}]\n")
    assert main(["check", str(inc)]) == 2
    _one_error_line(capsys, "pipe.yaml")


# -- found by mutating every verb's arguments ----------------------------------------------------
def _within(argv: list[str], fifo: Path, seconds: float = 5.0) -> int:
    """main(argv) on a thread; a call still blocked on ``fifo`` after ``seconds`` fails the test
    (the FIFO is then opened for writing once, so the old code's blocked open returns)."""
    import os

    result: list[int] = []
    worker = threading.Thread(target=lambda: result.append(main(argv)), daemon=True)
    worker.start()
    worker.join(seconds)
    if worker.is_alive():
        os.close(os.open(fifo, os.O_RDWR | os.O_NONBLOCK))
        pytest.fail(f"{argv} blocked on a FIFO")
    return result[0]


@pytest.mark.parametrize("verb, needle", [
    (["import", "candump", "FIFO", "-o", "OUT"], "a device or pipe, not a log file"),        # blocked in open()
    (["selfcal", "FIFO", "FIFO"], "a device or pipe, not an image"),                         # blocked in imread
    (["learn", "eval", "FIFO"], "a device or pipe, not a checkpoint"),                       # blocked; /dev/zero read for ever
    (["learn", "export", "FIFO", "OUT"], "a device or pipe, not a checkpoint"),
])
def test_a_fifo_input_is_refused_by_every_verb_that_reads_a_file(verb, needle, tmp_path, capsys):
    import os

    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs here")
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    argv = [str(fifo) if a == "FIFO" else str(tmp_path / "out") if a == "OUT" else a for a in verb]
    assert _within(argv, fifo) == 2
    _one_error_line(capsys, f"{fifo}: {needle}")


def test_an_output_that_cannot_be_written_is_refused_before_the_work(tmp_path, capsys, monkeypatch):
    """learn train -o DIR trained a whole chunk before its save failed; a FIFO as -o blocked the
    writer's open(); slam optimize and learn export wrote over their input."""
    import os

    import nodes.learn.train as train_module

    monkeypatch.setattr(train_module, "train", lambda *a, **k: pytest.fail("trained before checking -o"))
    assert main(["learn", "train", "--steps", "4096", "-o", str(tmp_path)]) == 2
    _one_error_line(capsys, f"-o {tmp_path}: a directory, not a file to write")
    if hasattr(os, "mkfifo"):
        os.mkfifo(tmp_path / "pipe")
        log = _log(tmp_path / "a.mcap")
        assert _within(["log", "cut", str(log), "-o", str(tmp_path / "pipe")], tmp_path / "pipe") == 2
        _one_error_line(capsys, "pipe: a FIFO: opening it waits for a reader")
    graph = tmp_path / "g.g2o"
    graph.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    before = graph.read_text()
    assert main(["slam", "optimize", str(graph), "-o", str(graph)]) == 2
    _one_error_line(capsys, "is the input")
    assert graph.read_text() == before
    ckpt = tmp_path / "p.ckpt"
    ckpt.write_bytes(b"\x80")
    assert main(["learn", "export", str(ckpt), str(ckpt)]) == 2        # would strip its optimiser state
    _one_error_line(capsys, "is the input")


@pytest.mark.parametrize("setting", ["lr=-1", "gamma=2", "gae_lambda=-0.1", "n_steps=0", "minibatches=0",
                                     "epochs=-1", "clip=0", "max_grad_norm=0", "squash=sigmoid",
                                     "hidden=[100000, 100000]"])
def test_a_ppo_setting_out_of_its_range_is_refused(setting, tmp_path, capsys, monkeypatch):
    """lr=-1 and gamma=2 trained (exit 0); n_steps=0 and minibatches=0 were ZeroDivisionError
    tracebacks, epochs=-1 a JAX traceback (hidden=[100000, 100000] too: 40 GB asked of JAX),
    n_steps=-1 'negative dimensions are not allowed'."""
    pytest.importorskip("jax")
    import nodes.learn.train as train_module

    monkeypatch.setattr(train_module, "train", lambda *a, **k: pytest.fail("trained with " + setting))
    assert main(["learn", "train", "--ppo", setting, "--steps", "1e6", "-o", str(tmp_path / "p.ckpt")]) == 2
    _one_error_line(capsys, f"--ppo {setting.split('=')[0]}=", ": give ")


def test_exporting_a_damaged_log_is_not_success_without_skip_bad(tmp_path, capsys):
    """The readable rest was exported with exit 0, as log merge did."""
    flipped, cut = _damaged(tmp_path)
    out = str(tmp_path / "e.mcap")
    assert main(["export", "foxglove", str(flipped), "-o", out]) == 1
    _one_error_line(capsys, "flipped.mcap: 3 damaged chunk(s)", "(--skip-bad to accept)")
    assert main(["export", "foxglove", str(cut), "-o", out, "--skip-bad", "--overwrite"]) == 0


def test_replaying_a_damaged_log_is_not_success_without_skip_bad(tmp_path, capsys, runtime_env):
    """``tether replay`` of a damaged or cut-short log logged 'skipping damaged chunk', replayed the rest
    and exited 0 (export and log merge exit 1); --into too. The readable messages are still replayed."""
    flipped, cut = _damaged(tmp_path)
    readable = sum(1 for _ in LogReader(flipped).messages())
    assert 0 < readable < 300
    assert main(["replay", str(flipped), "--rate", "0", "--delay", "0"]) == 1
    out, err = capsys.readouterr()
    assert f"replayed {readable} messages" in out and "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("tether: error: ") and "flipped.mcap: 3 damaged chunk(s): replayed without" in last
    assert main(["replay", str(cut), "--rate", "0", "--delay", "0"]) == 1
    _one_error_line(capsys, "cut.mcap: unreadable from byte ", "(--skip-bad to accept)")
    assert main(["replay", str(flipped), "--rate", "0", "--delay", "0", "--skip-bad"]) == 0
    assert main(["replay", str(tmp_path / "good.mcap"), "--rate", "0", "--delay", "0"]) == 0
    into = ["--into", "nodes.std.demo:Scale", "--map", "value=a/value", "--lockstep"]
    assert main(["replay", str(flipped), *into, "--record", str(tmp_path / "o.mcap")]) == 1
    _one_error_line(capsys, "3 damaged chunk(s): nodes.std.demo:Scale was fed and ", "o.mcap written without")
    assert sum(1 for _ in LogReader(tmp_path / "o.mcap").messages()) == readable
    assert main(["replay", str(flipped), *into, "--record", str(tmp_path / "o2.mcap"), "--skip-bad"]) == 0


def test_options_that_were_silently_ignored_are_errors(tmp_path, capsys, runtime_env):
    """Each of these ran (or listed) as if the option had not been given, with exit 0."""
    log = _log(tmp_path / "a.mcap")
    counter = str(REPO / "launch/counter.yaml")
    cases = [
        (["launch", counter, "--record-topics", "counter/*", "--duration", "1"], "--record-topics without --record"),
        (["launch", counter, "--record-max-size", "1M", "--duration", "1"], "--record-max-size without --record"),
        (["launch", counter, "--keys", str(tmp_path), "--duration", "1"], "the file declares no machines"),
        (["run", "nodes.std.demo:Counter", "--id", "", "--duration", "1"], "--id ''"),   # ran as 'counter'
        (["topic", "list", "a/value"], "tether topic list takes no TOPIC"),                # listed every topic
        (["log", "merge", str(log), str(tmp_path / "." / "a.mcap"), "-o", str(tmp_path / "m.mcap")],
         "is given twice"),                                                             # every message twice
        (["verify", counter, "--focus", "nope"], "--focus applies to --ctl formulas"),
    ]
    for argv, needle in cases:
        assert main(argv) == 2, argv
        _one_error_line(capsys, needle)


@pytest.mark.parametrize("argv", [
    ["check", ""],                                    # '': a directory with no .yaml launch file in it
    ["log", ""],                                      # '.: a directory, not a log file'
    ["record", "-o", ""],
    ["export", "foxglove", "x.mcap", "-o", ""],
    ["log", "x.mcap", "--check", "--no-check"],       # --no-check won silently
    ["slam", "optimize", "x.g2o", "--rel-tol", "-1"],
])
def test_an_empty_path_or_contradictory_flags_are_refused_by_the_parser(argv, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "error: argument" in err and "Traceback" not in err


def test_the_allow_empty_that_log_cut_points_to_exists(tmp_path, capsys):
    """'the cut selected no message (--allow-empty to accept)': tether log had no --allow-empty."""
    log = _log(tmp_path / "a.mcap")
    assert main(["log", "cut", str(log), "-o", str(tmp_path / "c.mcap"), "--start", "100"]) == 1
    assert "--allow-empty to accept" in capsys.readouterr().err
    assert main(["log", "cut", str(log), "-o", str(tmp_path / "c.mcap"), "--start", "100", "--allow-empty",
                 "--overwrite"]) == 0


@pytest.mark.parametrize("argv", [
    ["learn", "train", "--seed", "-1", "-o", "p.ckpt"],           # gymnasium.error.Error traceback
    ["learn", "eval", "p.ckpt", "--seed", "99999999999999999999"],  # OverflowError traceback
    ["replay", "x.mcap", "--start", "1e308"],                     # 'cannot convert float infinity to integer'
    ["replay", "x.mcap", "--delay", "1e308"],                     # 'timestamp out of range for platform time_t'
    ["log", "cut", "x.mcap", "-o", "y.mcap", "--end", "1e308"],
    ["run", "nodes.std.demo:Counter", "--duration", "1e308"],     # OverflowError from threading.Timer
    ["import", "candump", "c.log", "-o", "o.mcap", "--topic", ""],    # wrote a log on the topic ''
    ["import", "candump", "c.log", "-o", "o.mcap", "--topic", "a b"],
])
def test_huge_seeds_and_times_and_nameless_topics_are_refused_by_the_parser(argv, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "error: argument" in err and "Traceback" not in err


def test_a_scenario_parameter_that_is_not_a_number_is_named(tmp_path, capsys):
    """``--param max_range_m=nan`` reached ReachCar.configure as the text 'nan': a TypeError traceback
    ('<=' not supported between 'float' and 'str')."""
    pytest.importorskip("gymnasium")
    from nodes.learn.sim_node import load_sim

    for value in ("abc", True, [1]):
        with pytest.raises(ValueError, match="ReachCar: parameter max_range_m=.*: give a number"):
            load_sim("sim.car_env:ReachCar", params={"max_range_m": value})
    with pytest.raises(ValueError, match=r"need 0 <= min_range_m <= max_range_m, got 0.3, nan"):   # configure's range
        load_sim("sim.car_env:ReachCar", params={"max_range_m": "nan"})
    assert load_sim("sim.car_env:ReachCar", params={"max_range_m": "2"}).ranges_m == (0.3, 2.0)   # YAML's '1e-3' text


def test_a_topic_name_the_log_lacks_is_an_error_beside_a_good_one(tmp_path, capsys, runtime_env):
    """``--topics 'a/*' a/valeu``: the typo was dropped silently and the rest replayed."""
    from tether.replay import select_topics

    with pytest.raises(ConfigError, match="the log has no topic a/valeu"):
        select_topics(["a/value", "b/value"], ["a/*", "a/valeu"])
    assert select_topics(["a/value", "b/value"], ["a/*", "c/*"]) == ["a/value"]     # a glob may match nothing
    log = _log(tmp_path / "a.mcap")
    assert main(["log", "cut", str(log), "-o", str(tmp_path / "c.mcap"), "--topics", "a/value", "a/valeu"]) == 2
    _one_error_line(capsys, "--topics: the log has no topic a/valeu (its topics: a/value)")


def test_a_second_graph_on_the_same_topics_is_refused(capsys, runtime_env):
    """The same launch file started twice (one left running in another terminal), or ``run --id``
    of a running node: both registered, and every tool read whichever the registry listed last."""
    from tether import registry

    entry = registry.register({"name": "counter", "machine": "", "nodes": {},
                               "topics": {"counter/value": {"type": "std.Float64", "endpoint": "ipc:///x"}}})
    try:
        assert main(["launch", str(REPO / "launch/counter.yaml"), "--duration", "1"]) == 2
        _one_error_line(capsys, "graph 'counter': counter/value is already published by the running graph 'counter'")
        assert main(["run", "nodes.std.demo:Counter", "--id", "counter", "--duration", "1"]) == 2
        _one_error_line(capsys, "--id counter: counter/value is already published")
    finally:
        registry.unregister(entry)


def test_node_list_with_an_id_and_a_one_message_rate_window_are_refused(capsys, runtime_env):
    """``node list counter`` listed every node; ``topic hz -w 1`` said 'no messages yet' for ever."""
    assert main(["node", "list", "counter"]) == 2
    _one_error_line(capsys, "tether node list takes no ID")
    with pytest.raises(SystemExit):
        main(["topic", "hz", "a/b", "-w", "1"])
    assert "a rate needs at least 2 messages" in capsys.readouterr().err


def test_check_of_several_files_reports_every_bad_one(tmp_path, capsys):
    """The first bad file stopped 'tether check launch/': the files after it were never checked."""
    bad = tmp_path / "a_bad.yaml"
    bad.write_text("name: x\nnodes:\n  - {id: a, node: 'nodes.std.demo:Nope'}\n")
    worse = tmp_path / "b_worse.yaml"
    worse.write_text("name: [\n")
    good = tmp_path / "c_good.yaml"
    good.write_text((REPO / "launch/counter.yaml").read_text())
    assert main(["check", str(tmp_path)]) == 2
    out, err = capsys.readouterr()
    assert "a_bad.yaml" in err and "b_worse.yaml" in err and "c_good.yaml: ok" in out, (out, err)
    assert err.strip().splitlines()[-1] == "tether: error: 2 of 3 files failed"


def test_keys_list_of_a_graph_without_keystore_says_how_to_make_one(tmp_path, capsys):
    """It said 'cannot read the allow-list .../peers.json: [Errno 2] No such file or directory: ...';
    --machines with list was ignored."""
    assert main(["keys", "list", "boat", "--keys", str(tmp_path / "none")]) == 2
    _one_error_line(capsys, "no keystore for graph 'boat'", "'tether keys init boat --machines A,B' creates one")
    assert main(["keys", "list", "boat", "--machines", "a", "--keys", str(tmp_path)]) == 2
    _one_error_line(capsys, "--machines applies to 'tether keys init'")


def test_a_log_output_never_writes_over_a_file_that_is_not_a_log(tmp_path, capsys):
    """``-o`` naming an existing launch file or image by mistake (a shell completion one letter off)
    emptied it: a log is written over an older log only (and that only with --overwrite)."""
    log = _log(tmp_path / "a.mcap")
    notes = tmp_path / "notes.yaml"
    notes.write_text("name: x\n")
    for argv in (["log", "cut", str(log), "-o", str(notes)], ["export", "foxglove", str(log), "-o", str(notes)],
                 ["log", "merge", str(log), "-o", str(notes)]):
        assert main(argv) == 2, argv
        _one_error_line(capsys, "notes.yaml: an existing file that is not an MCAP log")
    assert notes.read_text() == "name: x\n"
    older = _log(tmp_path / "older.mcap", n=3)
    assert main(["log", "cut", str(log), "-o", str(older), "--overwrite"]) == 0   # an older log, when asked
    assert sum(1 for _ in LogReader(older).messages()) == 20
    for argv in (["log", "cut", str(log), "-o", str(notes), "--overwrite"],):     # --overwrite is for logs only
        assert main(argv) == 2, argv
        _one_error_line(capsys, "notes.yaml: an existing file that is not an MCAP log")


def test_empty_or_repeated_names_and_the_base_node_class_are_refused(tmp_path, capsys, runtime_env):
    """``launch --machine ''`` started every node (as without --machine); ``keys init --machines a,,b``
    and ``a,a`` were taken as 'a,b' and 'a'; ``run tether.node:Node`` ran a node with no ports until stopped."""
    with pytest.raises(SystemExit):
        main(["launch", str(REPO / "launch/counter.yaml"), "--machine", "", "--duration", "1"])
    assert "give a machine name" in capsys.readouterr().err
    for machines in ("a,,b", "a,a", ",a"):
        assert main(["keys", "init", "g", "--machines", machines, "--keys", str(tmp_path / "k")]) == 2
        _one_error_line(capsys, f"--machines {machines!r}: give distinct names")
    assert not (tmp_path / "k").exists()
    assert main(["run", "tether.node:Node", "--duration", "1"]) == 2
    _one_error_line(capsys, "tether.node:Node is the base class of nodes")


def _verbs_writing(log: Path, out: str, tmp_path: Path) -> list[list[str]]:
    can = tmp_path / "c.log"
    can.write_text("(1.000000) can0 123#00\n")
    into = ["--into", "nodes.std.demo:Scale", "--map", "value=a/value", "--lockstep"]
    return [["log", "cut", str(log), "-o", out], ["log", "merge", str(log), "-o", out],
            ["log", str(log), "--recover", "-o", out], ["export", "foxglove", str(log), "-o", out],
            ["import", "candump", str(can), "-o", out], ["replay", str(log), *into, "--record", out],
            ["record", "a/value", "-o", out, "--duration", "1"],
            ["launch", str(REPO / "launch/counter.yaml"), "--duration", "1", "--record", out]]


def test_an_existing_log_is_not_overwritten_without_overwrite(tmp_path, capsys, runtime_env):
    """Every verb writing a log (-o, --record) wrote over an existing log without a word (a second
    'launch --record run.mcap' lost the first run); ros2 bag record refuses an existing output. Now
    one line proposing a new name, unless --overwrite; the older log is untouched."""
    log = _log(tmp_path / "a.mcap")
    older = _log(tmp_path / "run.mcap", n=3)
    before = older.read_bytes()
    (tmp_path / "run-2.mcap").write_bytes(b"")
    for argv in _verbs_writing(log, str(older), tmp_path):
        assert main(argv) == 2, argv
        _one_error_line(capsys, "run.mcap: a log exists there", "--overwrite to replace it", "run-3.mcap")
        assert older.read_bytes() == before, argv
    for argv in _verbs_writing(log, str(older), tmp_path)[:6]:
        assert main([*argv, "--overwrite"]) == 0, argv
        assert older.read_bytes() != before, argv
        older.write_bytes(before)
    empty = tmp_path / "empty.mcap"                 # nothing to lose: mktemp's file is taken
    empty.write_bytes(b"")
    assert main(["log", "cut", str(log), "-o", str(empty)]) == 0


def test_a_split_recording_does_not_run_into_an_older_part(tmp_path, capsys, runtime_env):
    """With --max-size / --record-max-size the recording goes on into OUT_1.mcap, OUT_2.mcap, ...:
    an older recording's parts were written over silently."""
    _log(tmp_path / "run_1.mcap", n=3)
    for argv in (["record", "a/value", "-o", str(tmp_path / "run.mcap"), "--max-size", "1M", "--duration", "1"],
                 ["launch", str(REPO / "launch/counter.yaml"), "--duration", "1", "--record",
                  str(tmp_path / "run.mcap"), "--record-max-duration", "10"]):
        assert main(argv) == 2, argv
        _one_error_line(capsys, "run.mcap: the recording would go on into run_1.mcap, which exists")
    assert not (tmp_path / "run.mcap").exists()


@pytest.mark.parametrize("robust, width", [("huber", "1e308"), ("cauchy", "1e308"), ("cauchy", "1e160"),
                                           ("huber", "2e6"), ("gnc", "1e308"), (None, "3")])
def test_a_kernel_width_past_float_range_or_without_a_kernel_is_one_line(tmp_path, capsys, robust, width):
    """``slam optimize --robust cauchy --kernel-width 1e308`` squared the width to inf: a numpy
    RuntimeWarning, a NaN cost, 'no step lowers the cost' and exit 0; without --robust the width
    was ignored. The optimiser is never called."""
    import nodes.slam.pose_graph as pose_graph

    graph = tmp_path / "g.g2o"
    graph.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pose_graph, "optimize", lambda *a, **k: pytest.fail("optimised"))
        argv = ["slam", "optimize", str(graph), "--kernel-width", width] + (["--robust", robust] if robust else [])
        assert main(argv) == 2
    _one_error_line(capsys, "--kernel-width")
    assert main(["slam", "optimize", str(graph), "--robust", robust or "huber", "--kernel-width", "1e6"]) == 0


# -- Config values outside their meaning -------------------------------------------------------
def test_a_config_value_outside_its_bounds_is_one_line_for_run_launch_and_check(tmp_path, capsys, runtime_env):
    """``tether run Counter --param count=-1`` ran (a count below 0 meant 'for ever'), and so did a launch
    file's ``count: -3`` (check said ok); RawFuzzer rate_hz=0 divided by zero in its loop. Config fields carry msgspec ``Meta`` bounds (tether.NonNegativeInt,
    ...), checked by Node.make_config, reported in one line naming the field and the value."""
    assert main(["run", "nodes.std.demo:Counter", "--param", "count=-1", "--duration", "1"]) == 2
    _one_error_line(capsys, "nodes.std.demo:Counter params: count=-1: expected `int` >= 0")
    assert main(["run", "nodes.std.chaos:RawFuzzer", "--param", "rate_hz=0", "--duration", "1"]) == 2
    _one_error_line(capsys, "rate_hz=0: expected `float` > 0")
    graph = tmp_path / "g.yaml"
    graph.write_text("name: g\nnodes:\n  - id: counter\n    node: nodes.std.demo:Counter\n"
                     "    params: {rate_hz: 5, count: -3}\n")
    for verb in (["check"], ["launch", "--duration", "1"]):
        assert main([*verb, str(graph)]) == 2
        _one_error_line(capsys, "g.yaml:5", "count=-3: expected `int` >= 0")
    assert main(["check", str(REPO / "launch/counter.yaml"), "--param", "counter.count=-1"]) == 2
    _one_error_line(capsys, "--param", "count=-1: expected `int` >= 0")
    assert main(["check", str(REPO / "launch/counter.yaml"), "--param", "counter.count=3"]) == 0


def test_every_bounded_config_default_is_inside_its_bounds():
    """The bounds are not checked on defaults (msgspec checks decoded values only): a default outside
    its own bound would make the node refuse a launch file that merely restates it."""
    import importlib
    import inspect

    import msgspec

    from tether.node import Node

    bounded = [p for p in sorted((REPO / "nodes").rglob("*.py"))
               if any(name in p.read_text() for name in ("NonNegativeInt", "PositiveInt", "NonNegativeFloat",
                                                           "PositiveFloat", "msgspec.Meta("))]
    assert any(p.name == "demo.py" for p in bounded)
    checked = 0
    for path in bounded:
        module = importlib.import_module(".".join(path.relative_to(REPO).with_suffix("").parts))
        for cls in vars(module).values():
            if inspect.isclass(cls) and issubclass(cls, Node) and cls.__module__ == module.__name__:
                try:
                    defaults = msgspec.to_builtins(cls.Config())
                except TypeError:                # a required field: no defaults to check
                    continue
                assert cls.make_config(defaults) == cls.Config(), cls
                checked += 1
    assert checked >= 8


class _Frame:
    def __init__(self, data: bytes) -> None:
        self.bytes, self.buffer = data, memoryview(data)


class _FiftyHz:
    """A SUB socket stand-in: a Float64 on a/value every 20 ms (poll waits for it)."""

    def __init__(self) -> None:
        import time

        from tether.codec import Codec

        self.codec, self.clock, self.seq = Codec(), time, 0
        self.next = time.monotonic()

    def poll(self, timeout_ms: int) -> bool:
        wait = self.next - self.clock.monotonic()
        if wait > timeout_ms / 1000:
            self.clock.sleep(timeout_ms / 1000)
            return False
        self.clock.sleep(max(wait, 0.0))
        return True

    def recv_multipart(self, copy: bool = False) -> list[_Frame]:
        self.seq += 1
        self.next += 0.02
        msg = Float64(data=1.0, seq=self.seq, stamp_ns=self.seq * 20_000_000)
        return [_Frame(b"a/value"), *[_Frame(bytes(f)) for f in self.codec.encode(msg)]]


@pytest.mark.parametrize("action", ["hz", "bw"])
def test_a_rate_window_shorter_than_the_topic_period_says_so(action, monkeypatch, capsys):
    """``topic bw a/value --window 0.001`` on a 50 Hz topic printed 'no messages yet' every second while
    messages came (a 1 ms window never holds the 2 a rate needs); bw of 100-byte messages read
    'bw 0.00 MB/s  mean 0.1 kB'."""
    from tether import introspect
    from tether.registry import TopicInfo

    info = TopicInfo(topic="a/value", type_name="std.Float64", endpoint="ipc:///nonexistent/x", graph="g")
    monkeypatch.setattr(introspect, "subscribe", lambda topic: (info, _FiftyHz()))
    args = argparse.Namespace(action=action, topic="a/value", window=0.001, window_msgs=0, duration=1.3)
    assert introspect._rate(args) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1 and "no messages yet" not in lines[0]
    assert all("in the last 0.001 s of " in line and "give a --window longer than the topic's period" in line
               for line in lines), lines
    args.window = 0.5
    assert introspect._rate(args) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    want = "Hz  window 2" if action == "hz" else " kB/s  mean "     # 25 or 26 messages in 0.5 s
    assert want in last and "rate needs" not in last, last
    if action == "bw":
        size = float(last.split("mean ")[1].split(" B x")[0])   # a Float64 is about 50 bytes on the wire
        rate = float(last.split(" x ")[1].split(" Hz")[0])
        assert 20 < size < 200 and 45 < rate < 55 and f"{size * rate / 1e3:9.2f} kB/s" in last


def test_training_into_an_existing_checkpoint_needs_resume_or_overwrite(tmp_path, capsys, monkeypatch):
    """``learn train -o p.ckpt`` without --resume started from scratch and its first checkpoint
    replaced the older training (hours of it) without a word."""
    pytest.importorskip("jax")
    import nodes.learn.train as train_module

    class Trained(Exception):
        pass

    def fake_train(*args, **kw):
        raise Trained(kw["resume"])

    monkeypatch.setattr(train_module, "train", fake_train)
    ckpt = tmp_path / "p.ckpt"
    ckpt.write_bytes(b"older training")
    assert main(["learn", "train", "--steps", "1e6", "-o", str(ckpt)]) == 2
    _one_error_line(capsys, "p.ckpt: a checkpoint exists there; --resume to go on training it, --overwrite")
    for flag in ("--resume", "--overwrite"):
        with pytest.raises(Trained, match=str(flag == "--resume")):
            main(["learn", "train", "--steps", "1e6", "-o", str(ckpt), flag])
    with pytest.raises(Trained):
        main(["learn", "train", "--steps", "1e6", "-o", str(tmp_path / "new.ckpt")])
    assert ckpt.read_bytes() == b"older training"


@pytest.mark.parametrize("argv, needle", [
    (["replay", "LOG", "--record", "out.mcap"], "--record without --into"),      # published the log, recorded nothing
    (["replay", "LOG", "--map", "value=a/value", "--lockstep"], "--map, --lockstep without --into"),
    (["replay", "LOG", "--param", "gain=3"], "--param without --into"),
    (["launch", str(REPO / "launch/counter.yaml"), "--overwrite", "--duration", "1"], "--overwrite without --record"),
    (["log", "LOG", "--overwrite"], "--overwrite without -o OUT"),
])
def test_replay_options_of_into_and_overwrite_alone_are_errors(tmp_path, capsys, runtime_env, argv, needle):
    """Each ran as if the option had not been given (replay --record OUT without --into published the
    log and wrote no OUT), exit 0."""
    log = str(_log(tmp_path / "a.mcap"))
    assert main([log if a == "LOG" else a for a in argv]) == 2
    _one_error_line(capsys, needle)
    assert not (Path.cwd() / "out.mcap").exists()
