"""Transport benchmark: tether nodes vs raw pyzmq, two processes over ipc, side by side.

(a) 64-byte round trip p50/p99: Pinger <-> Echo nodes vs a raw PUB/SUB ping-pong.
(b) one-way throughput of a 1 MiB uint8 image (512 x 2048): BlobSource -> BlobSink vs
    raw ``send_multipart(copy=False)``.

    python bench/transport.py [--quick] [--json]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tether.runtime import RunSpec, Source  # noqa: E402


def _spawn(args: list[str], env: dict[str, str] | None = None) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, *args], cwd=REPO, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, **(env or {})})


def _node(spec: RunSpec, env: dict[str, str] | None = None) -> subprocess.Popen:
    import msgspec

    return _spawn(["-m", "tether.runner", msgspec.json.encode(spec).decode()], env)


def _wait_file(path: Path, procs: list[subprocess.Popen], timeout_s: float) -> dict:
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        for p in procs:
            if p.poll() is not None and p.returncode != 0:
                raise RuntimeError(f"benchmark process failed: {p.stderr.read() if p.stderr else ''}")
        if time.monotonic() > deadline:
            raise TimeoutError(f"no result at {path} after {timeout_s} s")
        time.sleep(0.02)
    return json.loads(path.read_text())


def _stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        if p.poll() is None:
            p.terminate()
    for p in procs:
        try:
            p.wait(5)
        except subprocess.TimeoutExpired:
            p.kill()


def tether_rtt(tmp: Path, count: int) -> np.ndarray:
    out = tmp / "rtt.json"
    out.unlink(missing_ok=True)   # never read a previous repeat's result
    ping_ep, pong_ep = f"ipc://{tmp}/ping", f"ipc://{tmp}/pong"
    echo = RunSpec(graph="bench", node_id="echo", node="nodes.std.perf:Echo", binds=[pong_ep],
                   inputs={"ping": Source(topic="pinger/ping", endpoint=ping_ep)})
    pinger = RunSpec(graph="bench", node_id="pinger", node="nodes.std.perf:Pinger", binds=[ping_ep],
                     params={"count": count, "result_path": str(out)},
                     inputs={"pong": Source(topic="echo/pong", endpoint=pong_ep)},
                     expect_subscribers={"pinger/ping": 1})
    procs = [_node(echo), _node(pinger)]
    try:
        return np.array(_wait_file(out, procs, 60 + count / 100)["rtt_ns"]) / 1e3
    finally:
        _stop(procs)


def tether_throughput(tmp: Path, count: int) -> tuple[float, int]:
    out = tmp / "blob.json"
    out.unlink(missing_ok=True)   # never read a previous repeat's result
    ep = f"ipc://{tmp}/blob"
    sink = RunSpec(graph="bench", node_id="sink", node="nodes.std.perf:BlobSink",
                   params={"count": count, "result_path": str(out)},
                   inputs={"image": Source(topic="source/image", endpoint=ep)})
    source = RunSpec(graph="bench", node_id="source", node="nodes.std.perf:BlobSource", binds=[ep],
                     params={"count": count}, expect_subscribers={"source/image": 1})
    # The raw pair below queues up to 1000 x 1 MiB; the source gets the same budget (the default
    # 64 MiB per subscriber would drop most of this 500 MiB burst at the publisher, counted as a
    # seq gap by the sink: bounded memory is the point of the default, not a speed).
    procs = [_node(sink), _node(source, {"TETHER_PUB_QUEUE_BYTES": str(1000 << 20)})]
    try:
        times = np.array(_wait_file(out, procs, 120)["recv_ns"])
    finally:
        _stop(procs)
    return _rate(times), len(times)


def _rate(times: np.ndarray) -> float:
    if len(times) < 2:
        return 0.0
    return (len(times) - 1) / ((times[-1] - times[0]) / 1e9)


# -- raw pyzmq peers (run in their own processes) ----------------------------------------------
def raw_echo(ping_ep: str, pong_ep: str) -> None:
    import zmq

    ctx = zmq.Context()
    sub, pub = ctx.socket(zmq.SUB), ctx.socket(zmq.PUB)
    pub.bind(pong_ep)
    sub.connect(ping_ep)
    sub.subscribe(b"ping")
    while True:
        frames = sub.recv_multipart()
        pub.send_multipart([b"pong", frames[1]])


def raw_pinger(ping_ep: str, pong_ep: str, count: int, warmup: int, out: str) -> None:
    import zmq

    ctx = zmq.Context()
    pub, sub = ctx.socket(zmq.PUB), ctx.socket(zmq.SUB)
    pub.bind(ping_ep)
    sub.connect(pong_ep)
    sub.subscribe(b"pong")
    sub.rcvtimeo = 200
    payload = os.urandom(64)
    rtts = []
    while len(rtts) < count + warmup:
        t0 = time.perf_counter_ns()
        pub.send_multipart([b"ping", payload])
        try:
            sub.recv_multipart()
        except zmq.Again:
            continue   # not connected yet
        rtts.append(time.perf_counter_ns() - t0)
    Path(out).write_text(json.dumps({"rtt_ns": rtts[warmup:]}))


def raw_source(ep: str, count: int) -> None:
    import zmq

    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.sndhwm = 1000
    pub.bind(ep)
    time.sleep(0.5)   # raw pyzmq has no way to know the subscriber joined: the classic slow joiner
    image = np.random.default_rng(0).integers(0, 255, (512, 2048), dtype=np.uint8)
    for _ in range(count):
        pub.send_multipart([b"image", b"hdr", image], copy=False)
    time.sleep(2)


def raw_sink(ep: str, count: int, out: str) -> None:
    import zmq

    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    sub.rcvhwm = 1000
    sub.connect(ep)
    sub.subscribe(b"image")
    sub.rcvtimeo = 3000
    times = []
    while len(times) < count:
        try:
            frames = sub.recv_multipart(copy=False)
        except zmq.Again:
            break
        np.frombuffer(frames[2].buffer, np.uint8)
        times.append(time.perf_counter_ns())
    Path(out).write_text(json.dumps({"recv_ns": times}))


def raw_rtt(tmp: Path, count: int) -> np.ndarray:
    out = tmp / "raw_rtt.json"
    out.unlink(missing_ok=True)   # never read a previous repeat's result
    ping_ep, pong_ep = f"ipc://{tmp}/rping", f"ipc://{tmp}/rpong"
    me = str(Path(__file__).resolve())
    procs = [_spawn([me, "--role", "raw-echo", ping_ep, pong_ep]),
             _spawn([me, "--role", "raw-pinger", ping_ep, pong_ep, str(count), "200", str(out)])]
    try:
        return np.array(_wait_file(out, procs, 60 + count / 100)["rtt_ns"]) / 1e3
    finally:
        _stop(procs)


def raw_throughput(tmp: Path, count: int) -> tuple[float, int]:
    out = tmp / "raw_blob.json"
    out.unlink(missing_ok=True)   # never read a previous repeat's result
    ep = f"ipc://{tmp}/rblob"
    me = str(Path(__file__).resolve())
    procs = [_spawn([me, "--role", "raw-sink", ep, str(count), str(out)])]
    time.sleep(0.2)
    procs.append(_spawn([me, "--role", "raw-source", ep, str(count)]))
    try:
        times = np.array(_wait_file(out, procs, 120)["recv_ns"])
    finally:
        _stop(procs)
    return _rate(times), len(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer messages")
    ap.add_argument("--json", action="store_true", help="print one JSON object of the headline figures")
    ap.add_argument("--repeats", type=int, default=3, help="alternating runs of each side; medians reported")
    ap.add_argument("--role", nargs="+", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.role:
        role, *rest = args.role
        {"raw-echo": lambda: raw_echo(*rest),
         "raw-pinger": lambda: raw_pinger(rest[0], rest[1], int(rest[2]), int(rest[3]), rest[4]),
         "raw-source": lambda: raw_source(rest[0], int(rest[1])),
         "raw-sink": lambda: raw_sink(rest[0], int(rest[1]), rest[2])}[role]()
        return
    n_rtt = 2000 if args.quick else 10000
    n_blob = 500 if args.quick else 2000
    rows = {"rtt": [], "rtt_raw": [], "mib": [], "mib_raw": []}
    with tempfile.TemporaryDirectory(prefix="tb", dir="/tmp") as d:
        tmp = Path(d)
        for _ in range(args.repeats):   # alternate the two sides so machine noise hits both alike
            rows["rtt_raw"].append(raw_rtt(tmp, n_rtt))
            rows["rtt"].append(tether_rtt(tmp, n_rtt))
            rows["mib_raw"].append(raw_throughput(tmp, n_blob))
            rows["mib"].append(tether_throughput(tmp, n_blob))
    rtt = np.concatenate(rows["rtt"])
    rtt_raw = np.concatenate(rows["rtt_raw"])
    mib = float(np.median([r for r, _ in rows["mib"]]))
    mib_raw = float(np.median([r for r, _ in rows["mib_raw"]]))
    res = {
        "rtt_p50_us": round(float(np.percentile(rtt, 50)), 1),
        "rtt_p99_us": round(float(np.percentile(rtt, 99)), 1),
        "rtt_p50_raw_us": round(float(np.percentile(rtt_raw, 50)), 1),
        "rtt_p99_raw_us": round(float(np.percentile(rtt_raw, 99)), 1),
        "mib_msgs_per_s": round(mib, 1),
        "mib_msgs_per_s_raw": round(mib_raw, 1),
        "mib_received": int(np.median([n for _, n in rows["mib"]])),
        "mib_received_raw": int(np.median([n for _, n in rows["mib_raw"]])),
        "mib_sent": n_blob,
    }
    res["rtt_ratio"] = round(res["rtt_p50_us"] / res["rtt_p50_raw_us"], 3)
    res["mib_ratio"] = round(mib / mib_raw, 3) if mib_raw else 0.0
    if args.json:
        print(json.dumps(res))
        return
    print(f"{'measure':34s} {'tether':>10s} {'raw pyzmq':>10s} {'ratio':>7s}")
    print(f"{'64 B round trip p50 (us)':34s} {res['rtt_p50_us']:10.1f} {res['rtt_p50_raw_us']:10.1f} {res['rtt_ratio']:7.3f}")
    print(f"{'64 B round trip p99 (us)':34s} {res['rtt_p99_us']:10.1f} {res['rtt_p99_raw_us']:10.1f} "
          f"{res['rtt_p99_us'] / res['rtt_p99_raw_us']:7.3f}")
    print(f"{'1 MiB one-way (msg/s)':34s} {mib:10.1f} {mib_raw:10.1f} {res['mib_ratio']:7.3f}")
    print(f"{'1 MiB received / sent':34s} {res['mib_received']:>5d}/{n_blob:<4d} {res['mib_received_raw']:>5d}/{n_blob:<4d}")
    print(f"({args.repeats} alternating runs each; medians; ipc on this machine)")


if __name__ == "__main__":
    main()
