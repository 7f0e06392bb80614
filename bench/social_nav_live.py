"""Live runs of the social-navigation launch files, scored like the in-process bench (``social_nav.py --live``).

Each run is ``tether launch launch/social_nav.yaml --param sim.scene=<scene>`` (or
``social_nav_dwa.yaml``) in its own ``TETHER_RUNTIME_DIR``: every node in its own process,
talking over ZeroMQ, on the wall clock. A recorder in this process subscribes to the
small topics (odometry, ground-truth pedestrians, the guard's commands, the cost grids)
and the episode is rebuilt from that log: the world clock starts at the first command
(the simulator holds still until then), pedestrians and odometry share stamps (both are
published on the simulator's tick), and contacts are attributed from odometry and the
pedestrians' velocities as :class:`sim.crowd.ContactEvent` does.
"""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TOPICS = ["sim/odom", "sim/pedestrians", "guard/cmd", "cost/costs", "guard/status"]
LAUNCH = {"irl": "launch/social_nav.yaml", "dwa": "launch/social_nav_dwa.yaml"}


def _wait_for_topics(topics: list[str], proc: subprocess.Popen, timeout_s: float = 20.0) -> dict:
    from tether import registry

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and proc.poll() is None:
        available = registry.topics()
        if all(t in available for t in topics):
            return available
        time.sleep(0.05)
    raise RuntimeError(f"the launched graph never published {topics} (exit code {proc.poll()})")


def run_live(scene: str, method: str, *, duration_s: float, out_dir: Path, params: list[str] = ()) -> tuple[Path, str]:
    """Launch one scenario with one method; returns the recorded log and the launcher's output."""
    from tether.record import Recorder

    out_dir.mkdir(parents=True, exist_ok=True)
    runtime = out_dir / f"rt-{scene}-{method}"
    runtime.mkdir(exist_ok=True)
    os.environ["TETHER_RUNTIME_DIR"] = str(runtime)         # the registry of this run (read per call)
    log_path = out_dir / f"{scene}-{method}.mcap"
    cmd = [sys.executable, "-m", "tether.cli", "launch", LAUNCH[method], "--param", f"sim.scene={scene}",
           "--duration", f"{duration_s:g}", *[x for p in params for x in ("--param", p)]]
    proc = subprocess.Popen(cmd, cwd=ROOT, env={**os.environ}, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    topics = [t for t in TOPICS if method == "irl" or not t.startswith("cost/")]
    try:
        available = _wait_for_topics(topics, proc)
        rec = Recorder(log_path, {t: available[t].endpoint for t in topics}).start()
        output, _ = proc.communicate(timeout=duration_s + 60)
        rec.stop()
    finally:
        if proc.poll() is None:
            proc.kill()
    return log_path, output


def _world_start(rows: list) -> int:
    """Stamp of the world's t = 0: the last sample before anything (robot or pedestrian) first moved."""
    for (s0, o0, i0, p0), (_, o1, i1, p1) in zip(rows, rows[1:]):
        if not np.allclose(o0[:3], o1[:3], atol=1e-9) or not np.array_equal(i0, i1) or not np.allclose(p0, p1, atol=1e-9):
            return s0
    return rows[0][0]


def episode_from_log(path: Path, goal: tuple[float, float, float]):
    """Rebuild an :class:`social_nav_episode.Episode` (times from the first command) from a live log."""
    from social_nav_episode import Episode, contact_onsets
    from tether.log import LogReader

    reader = LogReader(path)
    odom, peds, first_cmd, costs = {}, [], None, []
    for rec in reader.messages():
        if rec.topic == "guard/cmd" and first_cmd is None:
            m = reader.decode(rec)
            first_cmd = (m.stamp_ns, m.seq)
        elif rec.topic == "sim/odom":
            m = reader.decode(rec)
            odom[m.stamp_ns] = (m.pose.x_m, m.pose.y_m, m.pose.yaw_rad, m.twist.vx_mps, m.twist.wz_radps)
        elif rec.topic == "sim/pedestrians":
            m = reader.decode(rec)
            peds.append((m.stamp_ns, np.asarray(m.ids).copy(), np.asarray(m.positions_m).copy()))
        elif rec.topic == "cost/costs":
            costs.append((rec.log_time_ns, reader.decode(rec).stamp_ns))
    if first_cmd is None or not peds:
        raise RuntimeError(f"{path}: no command or no pedestrians recorded")
    rows = [(s, odom[s], ids, xy) for s, ids, xy in peds if s in odom and s >= first_cmd[0]]
    t0 = _world_start(rows)
    rows = [r for r in rows if r[0] >= t0]
    t = np.array([(s - t0) * 1e-9 for s, *_ in rows])
    o = np.array([r[1] for r in rows])
    gx, gy, tol = goal
    at_goal = np.flatnonzero(np.hypot(o[:, 0] - gx, o[:, 1] - gy) <= tol)
    goal_t = float(t[at_goal[0]]) if len(at_goal) else None
    n = at_goal[0] + 1 if len(at_goal) else len(t)
    p = [(ids, xy) for *_, ids, xy in rows][:n]
    vel = np.column_stack([o[:, 3] * np.cos(o[:, 2]), o[:, 3] * np.sin(o[:, 2])])
    onsets = contact_onsets(t[:n], o[:n, :2], vel[:n], p)
    ep = Episode(t[:n], o[:n, :3], o[:n, 4], p, goal_t, len(onsets), by_robot=sum(b for *_, b in onsets))
    lat = [(lt - st) * 1e-6 for lt, st in costs if st >= t0]
    rate = (len(lat) - 1) / ((costs[-1][1] - max(t0, costs[0][1])) * 1e-9) if len(lat) > 1 else None
    info = {"first_cmd_seq": first_cmd[1], "cost_hz": None if rate is None else round(rate, 1),
            "cost_latency_ms_median": round(float(np.median(lat)), 1) if lat else None}
    return ep, info
