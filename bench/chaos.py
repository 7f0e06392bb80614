"""Chaos benchmark: a launched two-machine graph (both on this host) under attack for a fixed time.

Attacks, all in one run:

- a raw fuzzer (``nodes.std.chaos:RawFuzzer``) sends crafted frames (header extremes,
  malformed bodies, wrong types, bad arrays, oversize frames) to a relay, a sink and an
  image sink;
- a 4 MiB image stream floods a slow consumer;
- the relay of a known-length stream crosses machines (tcp + CurveZMQ) and is SIGKILLed
  mid-run, then restarted by its launcher;
- both launchers are SIGKILLed at the end (their children must not outlive them);
- the recorded log is bit-flipped in some chunks and checked.

    python bench/chaos.py [--quick] [--duration S] [--json]

``--json`` prints one object: nodes_alive_frac, msgs_fuzzed, decode_errors_counted (of
decode_errors_expected: every malformed frame at every victim reading that output),
lost_uncounted (messages sent minus received minus counted drops; goal 0),
peak_rss_mb_slow_consumer (goal <= 512), orphans_after_kill (goal 0), secrets_on_cmdline
(goal 0), corrupt_chunks_reported (of corrupt_chunks_injected), and details.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tether.probes import (StatsWatch, children_of, corrupt_chunks, find_secrets, peak_rss_mb,  # noqa: E402
                               wait_gone)

GRAPH = """\
name: chaos
machines:
  a: {{host: 127.0.0.1, port_base: {port_a}}}
  b: {{host: 127.0.0.1, port_base: {port_b}}}
nodes:
  - {{id: counter, node: "nodes.std.demo:Counter", machine: a, params: {{rate_hz: {rate}, count: {count}, start: 1}}}}
  - {{id: relay, node: "nodes.std.demo:Scale", machine: b, inputs: {{value: counter/value}},
     restart: on-failure, max_restarts: 5}}
  - {{id: sink, node: "nodes.std.chaos:QuietSink", machine: a, inputs: {{value: relay/value}}}}
  - {{id: fuzz, node: "nodes.std.chaos:RawFuzzer", machine: a,
     params: {{rate_hz: 200, seed: 7, result_path: "{fuzz_out}", oversize_bytes: {oversize}}}}}
  - {{id: victim_relay, node: "nodes.std.demo:Scale", machine: a, inputs: {{value: fuzz/value}}}}
  - {{id: victim_sink, node: "nodes.std.chaos:QuietSink", machine: a, inputs: {{value: fuzz/value}}}}
  - {{id: victim_big, node: "nodes.std.chaos:QuietSink", machine: a, inputs: {{value: fuzz/big}},
     env: {{TETHER_MAX_MESSAGE_BYTES: "{limit}"}}}}
  - {{id: victim_image, node: "nodes.std.chaos:SlowSink", machine: a, inputs: {{image: fuzz/image}},
     params: {{delay_ms: 0}}}}
  - {{id: blob, node: "nodes.std.perf:BlobSource", machine: b, params: {{count: 1000000000, rows: 1024, cols: 4096}}}}
  - {{id: slow, node: "nodes.std.chaos:SlowSink", machine: b, inputs: {{image: blob/image}},
     params: {{delay_ms: 200}}}}
"""
VICTIMS = ("victim_relay", "victim_sink", "victim_image", "victim_big")


def _launcher(graph: Path, machine: str, env: dict[str, str], log: Path, record: Path | None) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "tether.cli", "launch", str(graph), "--machine", machine]
    if record is not None:
        cmd += ["--record", str(record), "--record-topics", "counter/value,sink/*,fuzz/value"]
    return subprocess.Popen(cmd, cwd=REPO, env=env, stdout=open(log, "w"), stderr=subprocess.STDOUT)


def run(duration_s: float, tmp: Path, *, progress: bool = True) -> dict[str, Any]:
    rate = 200
    count = int(rate * duration_s * 0.6)        # the counter finishes well before the end
    env = {**os.environ, "TETHER_RUNTIME_DIR": str(tmp / "run"), "TETHER_KEYS_DIR": str(tmp / "keys"),
           "PYTHONPATH": str(REPO)}
    os.environ.update({k: env[k] for k in ("TETHER_RUNTIME_DIR", "TETHER_KEYS_DIR")})
    fuzz_out = tmp / "fuzz.json"
    graph = tmp / "chaos.yaml"
    # Oversize frames: victim_big accepts at most 64 KiB (TETHER_MAX_MESSAGE_BYTES), the fuzzer
    # sends 128 KiB ones among numbered valid messages: each cuts the connection in libzmq; the
    # runtime must redial, and count what it missed meanwhile as a seq gap.
    graph.write_text(GRAPH.format(port_a=47600, port_b=47650, rate=rate, count=count, fuzz_out=fuzz_out,
                                  oversize=128 << 10, limit=64 << 10))
    record = tmp / "chaos.mcap"

    def say(text: str) -> None:
        if progress:
            print(f"[chaos {time.monotonic() - t0:5.1f} s] {text}", file=sys.stderr, flush=True)

    t0 = time.monotonic()
    subprocess.run([sys.executable, "-m", "tether.cli", "keys", "init", "chaos", "--machines", "a,b"],
                   cwd=REPO, env=env, check=False, capture_output=True)
    launchers = {"a": _launcher(graph, "a", env, tmp / "a.log", record),
                 "b": _launcher(graph, "b", env, tmp / "b.log", None)}
    watch = StatsWatch(["counter", "relay", "sink", "fuzz", *VICTIMS, "blob", "slow"])
    watch.start()
    if not watch.wait_all(20.0):
        say(f"nodes without stats after 20 s: {watch.missing()}")
    say("graph up")
    rss_peak = 0.0
    killed_relay = False
    secrets = None
    deadline = t0 + duration_s
    while time.monotonic() < deadline:
        time.sleep(0.2)
        rss_peak = max(rss_peak, peak_rss_mb(watch.pid("slow")))
        elapsed = time.monotonic() - t0
        if not killed_relay and elapsed > 0.3 * duration_s and watch.pid("relay"):
            os.kill(watch.pid("relay"), signal.SIGKILL)
            killed_relay = True
            say(f"SIGKILLed relay (pid {watch.pid('relay')})")
        if secrets is None and elapsed > 0.5 * duration_s:
            secrets = find_secrets(tmp / "keys", [p.pid for p in launchers.values()])
            say(f"secrets found in argv/environ: {len(secrets)}")
    watch.settle(3.0)                            # last stats of the counter's whole stream
    alive = watch.alive()
    say(f"alive {sum(alive.values())}/{len(alive)}")
    pids = [pid for p in launchers.values() for pid in children_of(p.pid)]
    for p in launchers.values():
        p.send_signal(signal.SIGKILL)
    orphans = wait_gone(pids, 5.0)
    say(f"launchers SIGKILLed: {len(orphans)} of {len(pids)} children still alive after 5 s")
    for pid in orphans:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    watch.stop()
    stale = sorted(p.name for p in (tmp / "run" / "s").glob("*")) if (tmp / "run" / "s").exists() else []
    from tether.transport import sweep_stale_sockets

    swept = sweep_stale_sockets()                # what the next launch does first
    fuzzed = json.loads(fuzz_out.read_text()) if fuzz_out.exists() else {}
    chunks = corrupt_chunks(record, tmp / "flipped.mcap", n=3, seed=1)
    lost = watch.lost_uncounted("counter", "value", via=("relay", "value"), to=("sink", "value"))
    # What each victim must count as a decode error: the malformed cases of the output it reads.
    on_value = sum(n for case, n in fuzzed.items() if case.startswith("malformed") and "array" not in case)
    on_image = sum(n for case, n in fuzzed.items() if case.startswith("malformed_array"))
    expected = {"victim_relay": on_value, "victim_sink": on_value, "victim_image": on_image, "victim_big": 0}
    big_valid = fuzzed.get("big_valid", 0)
    big_handled = watch.counter("victim_big", "handled")
    big_gaps = watch.counter("victim_big", "dropped_seq_gap") + watch.counter("victim_big", "dropped_queue")
    counted = {v: watch.counter(v, "decode_errors") for v in VICTIMS}
    links = {v: watch.counter(v, "link_resets") for v in VICTIMS}
    return {
        "duration_s": duration_s,
        "nodes_alive_frac": sum(alive.values()) / max(len(alive), 1),
        "nodes_dead": sorted(k for k, v in alive.items() if not v),
        "msgs_fuzzed": sum(fuzzed.values()),
        "fuzz_cases": fuzzed,
        "decode_errors_counted": sum(counted.values()),
        "decode_errors_expected": sum(expected.values()),
        "decode_errors_by_victim": {v: [counted[v], expected[v]] for v in VICTIMS},
        "oversize_sent": fuzzed.get("oversize", 0),
        "link_resets_by_victim": links,
        # The numbered stream around the oversize frames: sent = handled + counted gaps (+ the
        # tail sent after the last message it received, which no receiver can see: <= 1 cut).
        "big_stream": {"sent": big_valid, "handled": big_handled, "counted_gaps": big_gaps,
                       "uncounted": big_valid - big_handled - big_gaps},
        "lost_uncounted": lost["lost_uncounted"],
        "stream": lost,
        "relay_restarts": watch.incarnations("relay") - 1,
        "peak_rss_mb_slow_consumer": round(rss_peak, 1),
        "slow_consumer_drops": watch.counter("slow", "dropped_queue") + watch.counter("slow", "dropped_seq_gap"),
        "orphans_after_kill": len(orphans),
        "stale_ipc_sockets": len(stale),
        "stale_ipc_sockets_swept": swept,
        "secrets_on_cmdline": len(secrets or []),
        "secrets_where": secrets or [],
        **chunks,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=30.0, help="seconds under attack (default 30)")
    ap.add_argument("--quick", action="store_true", help="12 s instead of --duration")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="tether-chaos-") as tmp:
        os.chmod(tmp, 0o700)
        result = run(12.0 if args.quick else args.duration, Path(tmp), progress=not args.json)
    if args.json:
        print(json.dumps(result))
        return
    for key, value in result.items():
        print(f"{key:28s} {value}")


if __name__ == "__main__":
    main()
