#!/usr/bin/env python3
"""A Tether peer written from docs/wire.md alone: plain pyzmq + msgpack, no Tether import.

It joins running graphs on this host both ways:

* publisher: binds a PUB socket on an ipc endpoint in the runtime directory, registers its
  topic in the registry (so ``tether run --input``, ``tether topic echo``, ``tether record``
  find it) and publishes ``std.Float64`` messages numbered 1, 2, 3, ...;
* subscriber: finds topics in the registry, subscribes, and prints every message it gets as
  one JSON line (arrays: dtype, shape and the buffer in hex).

    python wire_client.py --publish wire/value --subscribe relay/value --subscribe relay/image -n 5

It publishes until it has received ``-n`` messages on every subscribed topic (exit 0) or
``--timeout`` passes (exit 1), then removes its registry entry. Non-loopback (CurveZMQ)
topics are out of its scope: see docs/wire.md, section 8.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import msgpack
import zmq

WIRE_VERSION = 1


def runtime_dir() -> Path:
    """docs/wire.md 6.1: $TETHER_RUNTIME_DIR, else <temp dir>/tether-<uid>; must be ours and 0700."""
    path = Path(os.environ.get("TETHER_RUNTIME_DIR") or os.path.join(tempfile.gettempdir(), f"tether-{os.getuid()}"))
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    info = path.lstat()
    if info.st_uid != os.getuid() or info.st_mode & 0o022:
        sys.exit(f"wire_client: runtime directory {path} is not private to this user")
    return path


def live_topics() -> dict[str, dict]:
    """docs/wire.md 6.2: every topic of every registry entry whose pid is alive."""
    found = {}
    for entry_path in sorted((runtime_dir() / "graphs").glob("*.json")):
        try:
            entry = json.loads(entry_path.read_text())
            os.kill(int(entry["pid"]), 0)
        except ProcessLookupError:
            continue                                   # a dead graph's entry: ignore it
        except (OSError, ValueError, KeyError):
            continue
        for topic, info in entry.get("topics", {}).items():
            found[topic] = info
    return found


def register(graph: str, topics: dict[str, dict]) -> Path:
    """docs/wire.md 6.2: write the entry atomically (temporary file, then rename)."""
    folder = runtime_dir() / "graphs"
    folder.mkdir(mode=0o700, exist_ok=True)
    path = folder / f"{graph}.local.{os.getpid()}.json"
    tmp = folder / f".{path.name}.tmp"
    tmp.write_text(json.dumps({"name": graph, "machine": "", "nodes": {}, "topics": topics, "pid": os.getpid()}))
    os.chmod(tmp, 0o600)
    os.replace(tmp, path)
    return path


def float64(value: float, seq: int) -> bytes:
    """docs/wire.md 4: the body of a std.Float64 message, a msgpack map."""
    return msgpack.packb({"type": "std.Float64", "data": float(value), "stamp_ns": time.time_ns(),
                          "frame_id": "", "seq": seq})


def decode(frames: list[bytes]) -> dict:
    """docs/wire.md 3 and 5: the body, with each array map's buffer taken from its frame."""
    body = msgpack.unpackb(frames[1], raw=False, strict_map_key=False)

    def arrays(node):
        if isinstance(node, dict):
            if set(node) == {"dtype", "shape", "frame"}:
                return {"dtype": node["dtype"], "shape": node["shape"], "hex": frames[2 + node["frame"]].hex()}
            if set(node) == {"dtype", "shape", "data"}:
                return {"dtype": node["dtype"], "shape": node["shape"], "hex": bytes(node["data"]).hex()}
            return {k: arrays(v) for k, v in node.items()}
        if isinstance(node, list):
            return [arrays(v) for v in node]
        if isinstance(node, bytes):
            return node.hex()
        return node

    return arrays(body)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--publish", default="", metavar="TOPIC", help="publish std.Float64 on TOPIC (node-id/output)")
    ap.add_argument("--subscribe", action="append", default=[], metavar="TOPIC", help="print messages of TOPIC")
    ap.add_argument("-n", "--count", type=int, default=5, help="messages to receive per subscribed topic")
    ap.add_argument("--rate", type=float, default=50.0, help="messages per second published")
    ap.add_argument("--timeout", type=float, default=30.0, help="seconds before giving up")
    args = ap.parse_args()

    ctx = zmq.Context()
    pub = sub = entry = None
    endpoint = ""
    if args.publish:
        endpoint = f"ipc://{runtime_dir() / 's'}/wirepy.{os.getpid()}"
        (runtime_dir() / "s").mkdir(mode=0o700, exist_ok=True)
        pub = ctx.socket(zmq.PUB)
        pub.bind(endpoint)
        entry = register(f"wirepy-{os.getpid()}", {args.publish: {"type": "std.Float64", "endpoint": endpoint}})
    got = {topic: 0 for topic in args.subscribe}
    pending = set(args.subscribe)                  # topics not found in the registry yet
    if args.subscribe:
        sub = ctx.socket(zmq.SUB)
    deadline = time.monotonic() + args.timeout
    seq, next_pub = 0, time.monotonic()
    try:
        while any(n < args.count for n in got.values()) or not args.subscribe:
            now = time.monotonic()
            if now > deadline:
                if not args.subscribe:
                    return 0                       # a publisher only: it published for --timeout seconds
                print(f"wire_client: timed out; received {got}", file=sys.stderr)
                return 1
            if pending:
                topics = live_topics()
                for topic in [t for t in pending if t in topics]:
                    sub.connect(topics[topic]["endpoint"])
                    sub.setsockopt(zmq.SUBSCRIBE, topic.encode())   # prefix match: frame 0 is compared below
                    pending.discard(topic)
            if pub is not None and now >= next_pub:
                seq += 1
                pub.send_multipart([args.publish.encode(), float64(seq, seq)])
                next_pub = now + 1.0 / args.rate
            if sub is not None and sub.poll(10):
                frames = sub.recv_multipart()
                topic = frames[0].decode(errors="replace")
                if topic in got and len(frames) >= 2:
                    got[topic] += 1
                    print(json.dumps({"topic": topic, "frames": len(frames), **decode(frames)}), flush=True)
            elif sub is None:
                time.sleep(0.01)
        return 0
    finally:
        if entry is not None:
            entry.unlink(missing_ok=True)
        ctx.destroy(linger=0)
        if endpoint:
            Path(endpoint[len("ipc://"):]).unlink(missing_ok=True)     # ZeroMQ may leave the socket file


if __name__ == "__main__":
    raise SystemExit(main())
