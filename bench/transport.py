"""Transport benchmark: tether nodes vs raw pyzmq over ipc, side by side in one run.

(a) 64-byte round trip p50/p99: Pinger <-> Echo nodes vs a raw PUB/SUB ping-pong.
(b) one-way throughput of a 1 MiB and an 8 MiB uint8 image: BlobSource -> BlobSink (shared
    memory: one copy at publish; with ``loan``: none; with TETHER_SHM=0: frames) vs raw
    ``send_multipart(copy=False)``; iceoryx2's own publish-subscribe (Python bindings) too.
    ``mib_ratio_shm``/``mib8_ratio_shm`` are the loaned rows: a node that writes its image into
    ``self.loan(...)`` (as dora's and iceoryx2's zero-copy publishers do), the transport costing
    no copy at all; ``mib_ratio_copy``/``mib8_ratio_copy`` a node left unchanged (one memcpy into
    the slot). Neither side pays for making the image: the raw source resends one prebuilt
    buffer, the loaned source writes a stamp row into each slot.
(c) fan-out: one source to 1, 2, 4, 8, 16 sinks, 64 B and 1 MiB: aggregate throughput of a
    burst and p99 latency (publish to handler) at a fixed rate, tether vs raw pyzmq.
(d) graph scale: a 50-node ``tether launch`` to all-ready, idle CPU and memory per node;
    sockets held by a 100-node launch against the minimum its connections need.

    python bench/transport.py [--quick] [--json] [--only rtt,mib,mib8,iox,fanout,graph]
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
    while True:
        try:
            return json.loads(path.read_text())
        except ValueError:          # a peer still writing it (the nodes replace it whole; raw peers too now)
            time.sleep(0.05)
            if time.monotonic() > deadline:
                raise


def _write_json(path: str, doc: dict) -> None:
    Path(path + ".tmp").write_text(json.dumps(doc))
    os.replace(path + ".tmp", path)


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


def tether_throughput(tmp: Path, count: int, rows: int = 512, cols: int = 2048, *,
                      env: dict[str, str] | None = None, loan: bool = False) -> tuple[float, int]:
    # The raw pair queues up to 1000 messages; the source gets the same budget (the default 64 MiB
    # per subscriber would drop most of a 500 MiB burst at the publisher, counted as a seq gap by
    # the sink: bounded memory is the point of the default, not a speed). See tether_blob.
    times = np.array(tether_blob(tmp, count, rows, cols, env=env, loan=loan)[0]["recv_ns"])
    return _rate(times), len(times)


def tether_blob(tmp: Path, count: int, rows: int, cols: int, *, sinks: int = 1, rate_hz: float = 0.0,
                env: dict[str, str] | None = None, loan: bool = False) -> list[dict]:
    """One BlobSource to ``sinks`` BlobSinks; each sink's result (recv_ns, latency_ns)."""
    ep = f"ipc://{tmp}/fan"
    outs = [tmp / f"fan{i}.json" for i in range(sinks)]
    for out in outs:
        out.unlink(missing_ok=True)
    specs = [RunSpec(graph="bench", node_id=f"sink{i}", node="nodes.std.perf:BlobSink",
                     params={"count": count, "result_path": str(out), "rows": rows, "cols": cols},
                     inputs={"image": Source(topic="source/image", endpoint=ep)}) for i, out in enumerate(outs)]
    source = RunSpec(graph="bench", node_id="source", node="nodes.std.perf:BlobSource", binds=[ep],
                     params={"count": count, "rows": rows, "cols": cols, "rate_hz": rate_hz, "loan": loan},
                     expect_subscribers={"source/image": sinks}, wait_subscribers_s=60)
    budget = str(min(1 << 31, max(64 << 20, min(1000, count) * rows * cols)))   # the raw pair's queue, as in (b)
    procs = [_node(spec, env) for spec in specs]
    procs.append(_node(source, {**(env or {}), "TETHER_PUB_QUEUE_BYTES": budget}))
    try:
        return [_wait_file(out, procs, 300) for out in outs]
    finally:
        _stop(procs)


def _aggregate(results: list[dict]) -> tuple[float, float, int]:
    """Deliveries per second over all sinks (first to last delivery), p99 latency (us), deliveries."""
    times = [np.array(r["recv_ns"]) for r in results if len(r["recv_ns"])]
    lat = np.concatenate([np.array(r["latency_ns"]) for r in results]) if results else np.zeros(0)
    total = sum(len(t) for t in times)
    if total < 2:
        return 0.0, float("nan"), total
    span = max(t[-1] for t in times) - min(t[0] for t in times)
    return total / (span / 1e9), float(np.percentile(lat, 99)) / 1e3 if lat.size else float("nan"), total


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
    _write_json(out, {"rtt_ns": rtts[warmup:]})


def raw_source(ep: str, count: int, nbytes: int = 1 << 20, sinks: int = 1, rate_hz: float = 0.0) -> None:
    import zmq

    ctx = zmq.Context()
    pub = ctx.socket(zmq.XPUB)      # an XPUB only to wait for the sinks, as tether's own wait does
    pub.setsockopt(zmq.XPUB_VERBOSE, 1)   # every sink's subscription, not only the first
    pub.sndhwm = 1000
    pub.bind(ep)
    joined = 0
    deadline = time.monotonic() + 60
    while joined < sinks and time.monotonic() < deadline:
        if pub.poll(100):
            joined += pub.recv()[0] == 1
    time.sleep(0.2)
    image = np.random.default_rng(0).integers(0, 255, nbytes, dtype=np.uint8)
    period = 1.0 / rate_hz if rate_hz > 0 else 0.0
    start = time.monotonic()
    for i in range(count):
        if period:
            time.sleep(max(0.0, start + i * period - time.monotonic()))
        pub.send_multipart([b"image", time.time_ns().to_bytes(8, "little"), image], copy=False)
    time.sleep(2)


def raw_sink(ep: str, count: int, out: str) -> None:
    import zmq

    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    sub.rcvhwm = 1000
    sub.connect(ep)
    sub.subscribe(b"image")
    sub.rcvtimeo = 5000
    times, latency = [], []
    first = True
    while len(times) < count:
        try:
            frames = sub.recv_multipart(copy=False)
        except zmq.Again:
            if first:
                continue          # the source waits for every sink before its first message
            break
        first = False
        np.frombuffer(frames[2].buffer, np.uint8)
        times.append(time.perf_counter_ns())
        latency.append(time.time_ns() - int.from_bytes(frames[1].bytes, "little"))
    _write_json(out, {"recv_ns": times, "latency_ns": latency})


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


def raw_throughput(tmp: Path, count: int, nbytes: int = 1 << 20) -> tuple[float, int]:
    times = np.array(raw_blob(tmp, count, nbytes)[0]["recv_ns"])
    return _rate(times), len(times)


def raw_blob(tmp: Path, count: int, nbytes: int, *, sinks: int = 1, rate_hz: float = 0.0) -> list[dict]:
    outs = [tmp / f"raw_fan{i}.json" for i in range(sinks)]
    for out in outs:
        out.unlink(missing_ok=True)   # never read a previous repeat's result
    ep = f"ipc://{tmp}/rblob"
    me = str(Path(__file__).resolve())
    procs = [_spawn([me, "--role", "raw-sink", ep, str(count), str(out)]) for out in outs]
    procs.append(_spawn([me, "--role", "raw-source", ep, str(count), str(nbytes), str(sinks), str(rate_hz)]))
    try:
        return [_wait_file(out, procs, 300) for out in outs]
    finally:
        _stop(procs)


# -- iceoryx2 (its own shared-memory publish-subscribe, no ZeroMQ) ---------------------------
def _iox_service(name: str, nbytes: int):
    import ctypes

    import iceoryx2 as iox2

    iox2.set_log_level(iox2.LogLevel.Error)
    node = iox2.NodeBuilder.new().create(iox2.ServiceType.Ipc)
    service = (node.service_builder(iox2.ServiceName.new(name))
               .publish_subscribe(iox2.Slice[ctypes.c_uint8])
               .enable_safe_overflow(False).subscriber_max_buffer_size(64).history_size(0)
               .open_or_create())
    return iox2, node, service


def iox_source(name: str, count: int, nbytes: int) -> None:
    """Loan a slice, copy the image in (as tether's publish does), send; blocks while the sink's buffer is full."""
    import ctypes

    iox2, node, service = _iox_service(name, nbytes)
    pub = (service.publisher_builder().initial_max_slice_len(nbytes).max_loaned_samples(4)
           .backpressure_strategy(iox2.BackpressureStrategy.RetryUntilDelivered).create())
    time.sleep(1.0)             # the sink started first; RetryUntilDelivered then loses nothing
    image = np.random.default_rng(0).integers(0, 255, nbytes, dtype=np.uint8)
    for _ in range(count):
        sample = pub.loan_slice_uninit(nbytes)
        ctypes.memmove(sample.payload_ptr, image.ctypes.data, nbytes)
        sample.assume_init().send()
    time.sleep(2)


def iox_sink(name: str, count: int, out: str) -> None:
    """Busy-polls ``receive`` (iceoryx2's publish-subscribe has no wake-up of its own: that is its Event service)."""
    import ctypes

    iox2, node, service = _iox_service(name, 1 << 20)
    sub = service.subscriber_builder().buffer_size(64).create()
    times = []
    last = time.monotonic()
    while len(times) < count and time.monotonic() - last < 5.0:
        sample = sub.receive()
        if sample is None:
            continue
        view = (ctypes.c_uint8 * 16).from_address(sample.payload_ptr)
        np.frombuffer(view, np.uint8)
        sample.delete()
        times.append(time.perf_counter_ns())
        last = time.monotonic()
    _write_json(out, {"recv_ns": times})


def iox_throughput(tmp: Path, count: int, nbytes: int) -> tuple[float, int]:
    out = tmp / "iox.json"
    out.unlink(missing_ok=True)
    name = f"tether-bench-{os.getpid()}-{time.monotonic_ns()}"
    me = str(Path(__file__).resolve())
    procs = [_spawn([me, "--role", "iox-sink", name, str(count), str(out)])]
    time.sleep(0.5)
    procs.append(_spawn([me, "--role", "iox-source", name, str(count), str(nbytes)]))
    try:
        times = np.array(_wait_file(out, procs, 120)["recv_ns"])
    finally:
        _stop(procs)
    return _rate(times), len(times)


# -- graph scale ---------------------------------------------------------------------------------
def _chain_launch(path: Path, n: int) -> Path:
    """A counter (1 Hz) and n-1 scale nodes, each fed by the one before."""
    lines = ["name: scale%d" % n, "nodes:", "  - {id: n0, node: nodes.std.demo:Counter, params: {rate_hz: 1}}"]
    lines += [f"  - {{id: n{i}, node: nodes.std.demo:Scale, inputs: {{value: n{i - 1}/value}}}}" for i in range(1, n)]
    path.write_text("\n".join(lines) + "\n")
    return path


def _proc_cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _proc_mem_mib(pid: int) -> tuple[float, float]:
    """RSS and PSS (shared pages divided among their users), MiB."""
    rss = pss = 0
    for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
        if line.startswith("Rss:"):
            rss = int(line.split()[1])
        elif line.startswith("Pss:"):
            pss = int(line.split()[1])
    return rss / 1024, pss / 1024


def _sockets_of(pid: int) -> int:
    count = 0
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            count += os.readlink(fd).startswith("socket:")
        except OSError:
            pass
    return count


def launch_graph(tmp: Path, n: int, *, idle_s: float = 0.0) -> dict:
    """``tether launch`` of an n-node chain: seconds to all-ready, then idle CPU, memory and sockets."""
    import zmq

    env = {**os.environ, "TETHER_RUNTIME_DIR": str(tmp / f"rt{n}")}
    path = _chain_launch(tmp / f"chain{n}.yaml", n)
    t0 = time.time_ns()
    launcher = subprocess.Popen([sys.executable, "-m", "tether.cli", "launch", str(path)], cwd=REPO, env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    ready: dict[str, float] = {}
    try:
        entry, deadline = None, time.monotonic() + 120
        graphs = tmp / f"rt{n}" / "graphs"
        while entry is None:
            assert time.monotonic() < deadline and launcher.poll() is None, "the launch did not register"
            found = list(graphs.glob("*.json")) if graphs.is_dir() else []
            doc = json.loads(found[0].read_text()) if found else {}
            if len(doc.get("topics", {})) >= 2 * n:
                entry = doc
            time.sleep(0.05)
        for ep in {info["endpoint"] for info in entry["topics"].values()}:
            sub.connect(ep)
        for i in range(n):
            sub.subscribe(f"n{i}/_stats".encode())
        from tether.stats import NodeStats
        import msgspec

        decoder = msgspec.msgpack.Decoder(NodeStats)
        while len(ready) < n:
            assert time.monotonic() < deadline, f"only {len(ready)} of {n} nodes became ready"
            if sub.poll(200):
                frames = sub.recv_multipart()
                stats = decoder.decode(frames[1])
                # its first statistics went out as its loop started, (seq - 1) periods before this one
                ready.setdefault(stats.node_id, (stats.stamp_ns - (stats.seq - 1) * 1e9 - t0) / 1e9)
        out = {"ready_s": max(ready.values())}
        pids = [info["pid"] for info in json.loads(found[0].read_text())["nodes"].values()]
        if idle_s:
            cpu0 = {p: _proc_cpu_s(p) for p in pids}
            time.sleep(idle_s)
            cpu = [(_proc_cpu_s(p) - cpu0[p]) / idle_s * 100 for p in pids]
            mem = [_proc_mem_mib(p) for p in pids]
            out.update(idle_cpu_pct_per_node=float(np.mean(cpu)), rss_mib_per_node=float(np.mean([m[0] for m in mem])),
                       pss_mib_per_node=float(np.mean([m[1] for m in mem])))
        # minus the n connections this measurement made itself (one accepted socket in each node)
        out["sockets"] = sum(_sockets_of(p) for p in pids) - n
        out["sockets_launcher"] = _sockets_of(launcher.pid)
        # the minimum: per node one listening socket, per connection one socket at each end
        out["sockets_needed"] = n + 2 * (n - 1)
        return out
    finally:
        sub.close(linger=0)
        ctx.term()
        launcher.send_signal(signal.SIGINT)
        try:
            launcher.wait(60)
        except subprocess.TimeoutExpired:
            launcher.kill()


def _print_table(res: dict, args: argparse.Namespace) -> None:
    print(f"{'measure':48s} {'tether':>10s} {'raw pyzmq':>10s} {'ratio':>7s}")
    if "rtt_p50_us" in res:
        print(f"{'64 B round trip p50 (us)':48s} {res['rtt_p50_us']:10.1f} {res['rtt_p50_raw_us']:10.1f} {res['rtt_ratio']:7.3f}")
        print(f"{'64 B round trip p99 (us)':48s} {res['rtt_p99_us']:10.1f} {res['rtt_p99_raw_us']:10.1f} "
              f"{res['rtt_p99_us'] / res['rtt_p99_raw_us']:7.3f}")
    for key, label in (("mib", "1 MiB"), ("mib8", "8 MiB")):
        if f"{key}_msgs_per_s_raw" not in res:
            continue
        raw = res[f"{key}_msgs_per_s_raw"]
        for kind, what in (("", "shm, node unchanged (1 copy)"), ("_loan", "shm, loaned buffer (0 copies)"),
                           ("_frames", "frames (TETHER_SHM=0)")):
            if f"{key}_msgs_per_s{kind}" in res:
                rate = res[f"{key}_msgs_per_s{kind}"]
                print(f"{label + ' one-way msg/s, ' + what:48s} {rate:10.1f} {raw:10.1f} {rate / raw if raw else 0:7.3f}"
                      + ("  <- *_ratio_shm" if kind == "_loan" else ""))
        if f"iox_{key}_msgs_per_s" in res:
            rate = res[f"iox_{key}_msgs_per_s"]
            print(f"{label + ' one-way msg/s, iceoryx2 (Python)':48s} {rate:10.1f} {raw:10.1f} {rate / raw if raw else 0:7.3f}")
    if "mib_received" in res:
        print(f"{'1 MiB received / sent':48s} {res['mib_received']:>5d}/{res['mib_sent']:<4d} "
              f"{res['mib_received_raw']:>5d}/{res['mib_sent']:<4d}")
    if res.get("fanout"):
        print("\nfan-out: one source, N sinks (aggregate deliveries/s of a burst; p99 publish->handler at a fixed rate)")
        print(f"{'N':>3s} {'size':>6s} {'tether/s':>10s} {'raw/s':>10s} {'ratio':>6s} {'p99 us':>9s} {'raw p99':>9s} "
              f"{'got/sent':>10s}")
        for row in res["fanout"]:
            print(f"{row['sinks']:3d} {row['size']:>6s} {row['msgs_per_s']:10.0f} {row['msgs_per_s_raw']:10.0f} "
                  f"{row['ratio']:6.2f} {row['p99_us']:9.0f} {row['p99_raw_us']:9.0f} "
                  f"{row['delivered']:>5d}/{row['sent']:<5d}")
    if "startup50_s" in res:
        print(f"\n50-node launch to all ready: {res['startup50_s']:.2f} s; idle CPU {res['idle_cpu_pct_per_node']:.2f} % "
              f"and RSS {res['rss_mib_per_node']:.1f} MiB (PSS {res['pss_mib_per_node']:.1f}) per node")
    if "sockets100" in res:
        print(f"100-node launch: {res['sockets100']} sockets in the nodes (its connections need {res['sockets100_needed']}), "
              f"{res['sockets100_launcher']} in the launcher; all ready in {res['startup100_s']:.2f} s")
    print(f"({args.repeats} alternating runs each; medians; ipc on this machine)")


def _one_way(res: dict, rows: dict, key: str, tmp: Path, count: int, shape: tuple[int, int], repeats: int) -> None:
    nbytes = shape[0] * shape[1]
    for _ in range(repeats):   # alternate the sides so machine noise hits them alike
        rows[f"{key}_raw"].append(raw_throughput(tmp, count, nbytes))
        rows[key].append(tether_throughput(tmp, count, *shape))
        rows[f"{key}_loan"].append(tether_throughput(tmp, count, *shape, loan=True))
        if key == "mib":
            rows[f"{key}_frames"].append(tether_throughput(tmp, count, *shape, env={"TETHER_SHM": "0"}))
    raw = float(np.median([r for r, _ in rows[f"{key}_raw"]]))
    res[f"{key}_msgs_per_s_raw"] = round(raw, 1)
    for kind in ("", "_loan", "_frames"):
        if rows.get(f"{key}{kind}"):
            rate = float(np.median([r for r, _ in rows[f"{key}{kind}"]]))
            res[f"{key}_msgs_per_s{kind}"] = round(rate, 1)
            res[f"{key}_ratio{kind}" if kind else f"{key}_ratio"] = round(rate / raw, 3) if raw else 0.0
    res[f"{key}_ratio_copy"] = res[f"{key}_ratio"]
    res[f"{key}_msgs_per_s_shm"] = res[f"{key}_msgs_per_s_loan"]     # the zero-copy path: see (b) above
    res[f"{key}_ratio_shm"] = res[f"{key}_ratio_loan"]


def _fanout(tmp: Path, sinks_list: tuple[int, ...], quick: bool) -> list[dict]:
    out = []
    for sinks in sinks_list:
        for size, shape, burst, rate, paced in (("64B", (1, 64), 2000 if not quick else 1000, 500.0, 300),
                                                ("1MiB", (512, 2048), 300 if not quick else 150, 50.0, 100)):
            print(f"fan-out {sinks} x {size} ...", file=sys.stderr, flush=True)
            nbytes = shape[0] * shape[1]
            rate_raw, _, got_raw = _aggregate(raw_blob(tmp, burst, nbytes, sinks=sinks))
            rate_t, _, got = _aggregate(tether_blob(tmp, burst, *shape, sinks=sinks))
            _, p99_raw, _ = _aggregate(raw_blob(tmp, paced, nbytes, sinks=sinks, rate_hz=rate))
            _, p99, _ = _aggregate(tether_blob(tmp, paced, *shape, sinks=sinks, rate_hz=rate))
            out.append({"sinks": sinks, "size": size, "msgs_per_s": round(rate_t, 1), "msgs_per_s_raw": round(rate_raw, 1),
                        "ratio": round(rate_t / rate_raw, 3) if rate_raw else 0.0, "p99_us": round(p99, 1),
                        "p99_raw_us": round(p99_raw, 1), "delivered": got, "delivered_raw": got_raw,
                        "sent": burst * sinks, "rate_hz": rate})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer messages, fan-out to 1 and 8 only")
    ap.add_argument("--json", action="store_true", help="print one JSON object of the headline figures")
    ap.add_argument("--repeats", type=int, default=3, help="alternating runs of each side; medians reported")
    ap.add_argument("--only", default="rtt,mib,mib8,iox,fanout,graph", help="which parts to run (comma-separated)")
    ap.add_argument("--role", nargs="+", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.role:
        role, *rest = args.role
        {"raw-echo": lambda: raw_echo(*rest),
         "raw-pinger": lambda: raw_pinger(rest[0], rest[1], int(rest[2]), int(rest[3]), rest[4]),
         "raw-source": lambda: raw_source(rest[0], int(rest[1]), int(rest[2]), int(rest[3]), float(rest[4])),
         "iox-source": lambda: iox_source(rest[0], int(rest[1]), int(rest[2])),
         "iox-sink": lambda: iox_sink(rest[0], int(rest[1]), rest[2]),
         "raw-sink": lambda: raw_sink(rest[0], int(rest[1]), rest[2])}[role]()
        return
    only = set(args.only.split(","))
    n_rtt = 2000 if args.quick else 10000
    n_blob = 500 if args.quick else 2000
    n_blob8 = 100 if args.quick else 300
    res: dict = {}
    rows: dict[str, list] = {k: [] for k in ("rtt", "rtt_raw", "mib", "mib_raw", "mib_loan", "mib_frames",
                                             "mib8", "mib8_raw", "mib8_loan")}
    with tempfile.TemporaryDirectory(prefix="tb", dir="/tmp") as d:
        tmp = Path(d)
        if "rtt" in only:
            print("round trips ...", file=sys.stderr, flush=True)
            for _ in range(args.repeats):   # alternate the two sides so machine noise hits both alike
                rows["rtt_raw"].append(raw_rtt(tmp, n_rtt))
                rows["rtt"].append(tether_rtt(tmp, n_rtt))
            rtt, rtt_raw = np.concatenate(rows["rtt"]), np.concatenate(rows["rtt_raw"])
            res.update(rtt_p50_us=round(float(np.percentile(rtt, 50)), 1),
                       rtt_p99_us=round(float(np.percentile(rtt, 99)), 1),
                       rtt_p50_raw_us=round(float(np.percentile(rtt_raw, 50)), 1),
                       rtt_p99_raw_us=round(float(np.percentile(rtt_raw, 99)), 1))
            res["rtt_ratio"] = round(res["rtt_p50_us"] / res["rtt_p50_raw_us"], 3)
        if "mib" in only:
            print("1 MiB one-way ...", file=sys.stderr, flush=True)
            _one_way(res, rows, "mib", tmp, n_blob, (512, 2048), args.repeats)
            res.update(mib_received=int(np.median([n for _, n in rows["mib"]])),
                       mib_received_raw=int(np.median([n for _, n in rows["mib_raw"]])), mib_sent=n_blob)
        if "mib8" in only:
            print("8 MiB one-way ...", file=sys.stderr, flush=True)
            _one_way(res, rows, "mib8", tmp, n_blob8, (4096, 2048), args.repeats)
        if "iox" in only:
            print("iceoryx2 ...", file=sys.stderr, flush=True)
            try:
                res["iox_mib_msgs_per_s"] = round(float(np.median(
                    [iox_throughput(tmp, n_blob, 1 << 20)[0] for _ in range(args.repeats)])), 1)
                res["iox_mib8_msgs_per_s"] = round(float(np.median(
                    [iox_throughput(tmp, n_blob8, 8 << 20)[0] for _ in range(args.repeats)])), 1)
                for key in ("mib", "mib8"):
                    if f"{key}_msgs_per_s_raw" in res:
                        res[f"iox_{key}_ratio"] = round(res[f"iox_{key}_msgs_per_s"] / res[f"{key}_msgs_per_s_raw"], 3)
            except (ImportError, RuntimeError, TimeoutError) as exc:
                print(f"iceoryx2 not measured: {exc}", file=sys.stderr)
        if "fanout" in only:
            res["fanout"] = _fanout(tmp, (1, 8) if args.quick else (1, 2, 4, 8, 16), args.quick)
            eight = [r for r in res["fanout"] if r["sinks"] == 8 and r["size"] == "1MiB"]
            if eight:
                res["fanout8_ratio"] = eight[0]["ratio"]
        if "graph" in only:
            print("50-node launch ...", file=sys.stderr, flush=True)
            g50 = [launch_graph(tmp / f"g{i}", 50, idle_s=5.0 if i == 0 else 0.0) for i in range(args.repeats)
                   if (tmp / f"g{i}").mkdir() is None]
            res["startup50_s"] = round(float(np.median([g["ready_s"] for g in g50])), 2)
            res.update({k: round(g50[0][k], 2) for k in ("idle_cpu_pct_per_node", "rss_mib_per_node", "pss_mib_per_node")})
            print("100-node launch ...", file=sys.stderr, flush=True)
            (tmp / "g100").mkdir()
            g100 = launch_graph(tmp / "g100", 100)
            res.update(startup100_s=round(g100["ready_s"], 2), sockets100=g100["sockets"],
                       sockets100_needed=g100["sockets_needed"], sockets100_launcher=g100["sockets_launcher"])
    if args.json:
        print(json.dumps(res))
        return
    _print_table(res, args)


if __name__ == "__main__":
    main()
