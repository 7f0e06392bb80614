"""Ping360 benchmark: beams parsed per second, and the line end to end at 115200 and 2 Mbaud.

* Parsing: a stream of 2,000 beams of 1,200 samples with 5 % of the frames preceded by
  garbage and 1 % with a wrong checksum, fed in 4 KiB reads; our ``PingParser`` against the
  ``bluerobotics-ping`` package's ``PingParser`` (its reference, byte at a time), same bytes.
  Both must find the same beams.
* End to end: the simulated head (sim/ping360_device.py, paced at the baud rate) on a
  pseudo-terminal, our driver on the other side; beams/s against the line's limit (10 bits a
  byte), and latency from the device's write of a beam to the driver's publish. A pty hands
  the frame over at once, so this is the host's share; a real line adds the frame's own time
  (1,230 bytes: 107 ms at 115200, 6.2 ms at 2 Mbaud).

    python bench/ping360.py [--quick] [--json]

``--json`` keys: parse_beams_per_s, parse_beams_per_s_brping, parse_ratio, and per baud rate
beams_per_s, line_limit_beams_per_s, latency_ms_p50, latency_ms_p99, checksum_errors.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from drivers import ping_protocol as pp  # noqa: E402
from drivers.ping360 import Ping360  # noqa: E402
from sim.ping360_device import Ping360Device  # noqa: E402
from tether.testing import Harness  # noqa: E402


def stream(n_beams: int, seed: int = 0) -> bytes:
    rng = np.random.default_rng(seed)
    s = pp.Settings(number_of_samples=1200)
    parts = []
    for k in range(n_beams):
        frame = bytearray(pp.encode_device_data(s, k % 400, rng.integers(0, 256, 1200, dtype=np.uint8)))
        if rng.random() < 0.01:
            frame[-1] ^= 0x33
        if rng.random() < 0.05:
            parts.append(bytes(rng.integers(0, 256, 30, dtype=np.uint8)))
        parts.append(bytes(frame))
    return b"".join(parts)


def parse_ours(data: bytes) -> list[int]:
    p = pp.PingParser()
    out = []
    for i in range(0, len(data), 4096):
        out += [pp.decode_beam(f.message_id, f.payload).angle for f in p.feed(data[i:i + 4096])
                if f.message_id == pp.DEVICE_DATA]
    return out


def parse_brping(data: bytes) -> list[int] | None:
    try:
        from brping import PingParser
    except ImportError:
        return None
    p = PingParser()
    out = []
    for b in data:
        if p.parse_byte(b) == PingParser.NEW_MESSAGE:
            m = p.rx_msg
            if m.message_id == pp.DEVICE_DATA:
                out.append(m.angle)
    return out


def end_to_end(baud: int, seconds: float, samples: int) -> dict:
    dev = Ping360Device(None, baudrate=baud).start()
    ends: dict[int, float] = {}
    original = dev._write

    def timed_write(frame: bytes) -> None:
        original(frame)
        if frame[4:6] == pp.AUTO_DEVICE_DATA.to_bytes(2, "little"):
            ends[len(ends) + 1] = time.monotonic() - (len(frame) * 10 / baud)   # when the write began
    dev._write = timed_write
    h = Harness(Ping360, params=dict(port=dev.port, baudrate=baud, number_of_samples=samples, data_timeout_s=5.0))
    got: dict[int, float] = {}
    publish = h.node.publish

    def timed_publish(output, msg):
        got[msg.ping_id] = time.monotonic()
        publish(output, msg)
    h.node.publish = timed_publish
    t = threading.Thread(target=h.node.run, daemon=True)
    t.start()
    time.sleep(seconds)
    h.node.stopping.set()
    t.join(5)
    h.close()
    dev.close()
    # beam k published <-> k-th beam written (the line here loses nothing: checked by the counts)
    lat = [1e3 * (got[k] - ends[k]) for k in sorted(got) if k in ends]
    frame_bytes = pp.HEADER_SIZE + 20 + samples + 2
    span = (max(got.values()) - min(got.values())) if len(got) > 1 else float("nan")
    return {"baud": baud, "beams": len(got), "beams_per_s": (len(got) - 1) / span if len(got) > 1 else 0.0,
            "line_limit_beams_per_s": baud / 10 / frame_bytes, "latency_ms_p50": statistics.median(lat),
            "latency_ms_p99": float(np.percentile(lat, 99)), "checksum_errors": h.node.counters["checksum_errors"],
            "sent": dev.beams_sent}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    data = stream(500 if args.quick else 2000)
    t0 = time.perf_counter()
    ours = parse_ours(data)
    t_ours = time.perf_counter() - t0
    t0 = time.perf_counter()
    ref = parse_brping(data[: len(data) // (4 if not args.quick else 1)])
    t_ref = time.perf_counter() - t0
    result = {"parse_beams": len(ours), "parse_beams_per_s": len(ours) / t_ours}
    if ref is not None:
        agree = ref == ours[:len(ref)]
        result.update(parse_beams_per_s_brping=len(ref) / t_ref, parse_ratio=(len(ours) / t_ours) / (len(ref) / t_ref),
                      parse_agree=agree)
    print(f"parse: ours {result['parse_beams_per_s']:.0f} beams/s"
          + (f", brping {result['parse_beams_per_s_brping']:.0f} beams/s, same beams: {result['parse_agree']}"
             if ref is not None else ", brping not installed"), file=sys.stderr)
    rows = []
    for baud in (115200, 2_000_000):
        r = end_to_end(baud, 4.0 if args.quick else 15.0, 1200)
        rows.append(r)
        print(f"{baud} baud: {r['beams_per_s']:.1f} beams/s (line limit {r['line_limit_beams_per_s']:.1f}), latency "
              f"p50 {r['latency_ms_p50']:.2f} ms, p99 {r['latency_ms_p99']:.2f} ms, checksum errors {r['checksum_errors']}",
              file=sys.stderr)
    result["line"] = rows
    if args.json:
        print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
