"""Sonar pipeline benchmark: pings/s the launched pipeline sustains, ping-to-pose latency, error.

Runs ``launch/sonar_localize.yaml`` (simulator -> real protocol over TCP -> driver -> imager,
highlight cloud, ICP localizer -> evaluation) at 256 and 512 beams with the sonar asked for
its highest ping rate, and reads the evaluation's summary. The reference in the same run is
the simulator's own render rate in-process (no sockets, no pipeline): the ceiling any
pipeline fed by it can reach on this machine.

    python bench/sonar_pipeline.py [--quick] [--json]
"""
from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def _free_port_pair() -> int:
    while True:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        if port + 2 < 65535:
            return port


def run_pipeline(beams: int, duration_s: float, tmp: Path) -> dict:
    port = _free_port_pair()
    out = tmp / f"eval{beams}"
    params = [f"sim.port={port}", f"sim.status_port={port + 2}", f"sonar.port={port}", f"sonar.status_port={port + 2}",
              f"sim.beams={beams}", f"sonar.beams={beams}", "sonar.ping_rate=highest", f"eval.out_dir={out}",
              "sim.time_offset_s=6",
              "eval.png=false"]
    env = {**os.environ, "TETHER_RUNTIME_DIR": str(tmp / "rt")}
    cmd = [sys.executable, "-m", "tether.cli", "launch", "launch/sonar_localize.yaml", "--duration", str(duration_s)]
    for p in params:
        cmd += ["--param", p]
    res = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=duration_s + 120)
    if not (out / "summary.json").exists():
        raise RuntimeError(f"pipeline produced no summary (exit {res.returncode}):\n{res.stdout[-2000:]}\n{res.stderr[-2000:]}")
    return json.loads((out / "summary.json").read_text())


def render_rate(beams: int, n: int) -> float:
    """Pings/s of the simulator's pure render on this machine (the reference ceiling)."""
    from sim.fls import PingSettings, load_scene, render_ping

    scene = load_scene("tripod")
    rng = np.random.default_rng(0)
    times = []
    for i in range(n):
        pose = scene.sonar_pose(10.0 + 0.1 * i)
        t0 = time.perf_counter()
        render_ping(scene, pose, PingSettings(n_beams=beams, range_m=20), rng=rng)
        times.append(time.perf_counter() - t0)
    return 1.0 / float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    duration = 16.0 if args.quick else 30.0
    rows = []
    with tempfile.TemporaryDirectory(prefix="tsp", dir="/tmp") as d:
        for beams in (256, 512):
            s = run_pipeline(beams, duration, Path(d))
            s["beams"] = beams
            s["render_only_pps"] = render_rate(beams, 10 if args.quick else 30)
            rows.append(s)
    head = next(r for r in rows if r["beams"] == 512)
    result = {"pings_per_s": round(head["pings_per_s"], 2), "latency_ms_p50": round(head["latency_ms_p50"], 1),
              "render_only_pings_per_s": round(head["render_only_pps"], 2),
              "pipeline_vs_render_ratio": round(head["pings_per_s"] / head["render_only_pps"], 3),
              "loc_err_m": round(head["loc_err_m"], 3), "loc_err_deg": round(head["loc_err_deg"], 2),
              "nav_err_m": round(head["nav_err_m"], 3), "cloud_size": head["cloud_size"],
              "trusted_corrections": head["trusted_corrections"], "corrections": head["corrections"],
              "wrong_trusted": head["wrong_trusted"], "max_trusted_err_m": round(head["max_trusted_err_m"], 3),
              "duration_s": duration}
    if args.json:
        print(json.dumps(result))
        return
    print(f"{'beams':>5s} {'pings/s':>8s} {'render-only':>11s} {'ratio':>6s} {'latency p50':>11s} "
          f"{'loc err':>8s} {'nav err':>8s} {'trusted':>8s} {'wrong':>5s} {'cloud':>7s}")
    for r in rows:
        print(f"{r['beams']:5d} {r['pings_per_s']:8.1f} {r['render_only_pps']:11.1f} "
              f"{r['pings_per_s'] / r['render_only_pps']:6.2f} {r['latency_ms_p50']:9.0f} ms "
              f"{r['loc_err_m']:6.3f} m {r['nav_err_m']:6.3f} m {r['trusted_corrections']:3d}/{r['corrections']:<4d} "
              f"{r['wrong_trusted']:5d} "
              f"{r['cloud_size']:7d}")
    print(f"({duration:.0f} s launches at the sonar's highest ping rate; render-only = the simulator alone, in-process;"
          " errors are steady-state medians vs ground truth)")


if __name__ == "__main__":
    main()
