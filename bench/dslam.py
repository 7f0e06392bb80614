"""Decentralised multi-robot SLAM benchmark: cost against bytes exchanged and rounds (seed 10).

Every graph in ../shared/data/posegraphs is cut into R contiguous robots (R in {2, 4, 8});
inter-robot closures are the dataset's edges that cross blocks. Each method runs the real
agents (:class:`nodes.slam.dslam.Agent`) and every packet goes through the real wire
encoding (msgs.slam, float32 numbers) -- bytes are the encoded frames plus the topic. The
yardstick is the centralised optimum: the same back end on the whole graph (itself checked
against GTSAM in bench/pose_graph.py). Rounds are Gauss-Seidel sweeps (robot 0 first).

Methods: ``ddf`` (condensed graphs; ``condense=exact`` sweeps ``max_run``, the accuracy
knob: 0 keeps only what must stay, smaller values keep more keyframes), ``ddf_chain``,
``dgs`` (two-stage distributed Gauss-Seidel, ``send_tol`` 1e-4), ``block_gs`` (naive), and
the baseline ``upload``: every robot but robot 0 uploads all its edges to robot 0 (one
packet each, the same encoding), which solves centrally -- its cost ratio is 1 by
construction. The issue's rule counts the upload only; ``bytes_upload_and_return`` adds
sending each robot its trajectory back (float32 poses), which a team needs.

Outliers: on every graph at R = 4, 30 % of the inter-robot closures false (seed 1); ``ddf``
with ``max_run=8`` (PCM, then GNC over the team's closures) is run with and without them and
both results scored on the inlier graph (PNG per graph: closures used in grey, turned down in
red). The methods with PCM alone are not defended further: a few false closures pass PCM's
pairwise test.

CPU: each robot streamed at 10 keyframes/s of simulated time with 5 rounds/s; the agent's
process time over the simulated duration is its share of a core (the runtime adds the
decode/encode, measured in bench/transport.py).

    python bench/dslam.py [--quick] [--json] [--png OUT.png]

``--json``: ``graphs`` maps each graph (R = 4, best method) to {bytes_to_1pct,
bytes_upload_all, cost_ratio_final}, plus ``outlier_cost_change`` and ``outliers_rejected_frac``
(the worst over the graphs; each graph's in ``outlier_studies``), ``cpu_core_frac`` and
``sweep`` (every graph, R and method).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from msgs.slam import ClosureSet, PeerPacket, RobotTrajectory  # noqa: E402
from nodes.slam.dslam import Agent, info_to6  # noqa: E402
from nodes.slam.dslam_agent import transmit  # noqa: E402
from nodes.slam.graph_io import read_graph  # noqa: E402
from nodes.slam.multirobot import centralised, feed, feed_all, robot_stream, run_team, split_graph  # noqa: E402
from tether.codec import Codec  # noqa: E402

DATA = Path(os.environ.get("TETHER_SHARED_DATA", REPO.parent / "shared" / "data")) / "posegraphs"
GRAPHS = {"FR079": "FR079_P_toro.graph", "intel": "sesync_intel.g2o", "M3500": "input_M3500_g2o.g2o"}
METHODS = {"ddf": dict(method="ddf"), "ddf_run8": dict(method="ddf", max_run=8), "ddf_run2": dict(method="ddf", max_run=2),
           "ddf_chain": dict(method="ddf", condense="chain"), "dgs": dict(method="dgs"),
           "block_gs": dict(method="block_gs")}
ROUNDS = {"ddf": 8, "dgs": 80, "block_gs": 40}
ROBUST = "ddf_run8"     # the outlier study's method: PCM, then GNC over the team's closures (dgs and block_gs
#                         have PCM only; their figures with 30 % false closures are in the issue note)


def upload_bytes(scenario) -> tuple[int, int]:
    """(upload all edges to robot 0, plus the trajectories sent back), same encoding as the agents."""
    codec = Codec()
    g, owner = scenario.graph, scenario.owner
    lo = np.minimum(owner[g.edges[:, 0]], owner[g.edges[:, 1]])
    up = back = 0
    for r in range(1, scenario.robots):
        mine = lo == r                     # each edge once, by its lower-numbered end (robot 0 has its own)
        msg = ClosureSet(ids=g.ids[g.edges[mine]].astype(np.int32), z=g.z[mine].astype(np.float32),
                         info=info_to6(g.info[mine]).astype(np.float32), accepted=np.ones(int(mine.sum()), bool))
        up += transmit_bytes(codec, PeerPacket(sender=r, receiver=0, items=[msg]), f"robot{r}/to_0")
        v = scenario.vertices(r)
        traj = RobotTrajectory(robot=r, ids=g.ids[v], poses=np.zeros((len(v), 3), np.float32))
        back += transmit_bytes(codec, traj, "robot0/to_1")
    return up, up + back


def transmit_bytes(codec: Codec, msg, topic: str) -> int:
    """Bytes of ``msg`` on the wire: its frames plus the topic frame (as the runtime counts them)."""
    return sum(len(memoryview(f).cast("B")) for f in codec.encode(msg)) + len(topic)


def run(scenario, reference, params: dict, rounds: int):
    agents = [Agent(r, scenario.robots, **params) for r in range(scenario.robots)]
    for a in agents:
        feed_all(a, scenario)
    t0 = time.process_time()
    codec = Codec()                            # one encoder/decoder pair per run, as a node has
    records = run_team(scenario, agents, rounds=rounds, transmit=lambda p: transmit(p, codec), reference=reference)
    return records, agents, time.process_time() - t0


def summarise(records) -> dict:
    to1 = next((r for r in records if r.cost_ratio <= 1.01), None)
    return {"bytes_to_1pct": to1.bytes if to1 else None, "rounds_to_1pct": to1.round if to1 else None,
            "cost_ratio_final": records[-1].cost_ratio, "bytes_final": records[-1].bytes,
            "curve": [(r.round, r.bytes, r.cost_ratio) for r in records]}


def outlier_study(scenario_clean, name: str, params: dict, rounds: int, png: Path | None = None) -> dict:
    """Best method with and without 30 % false inter-robot closures, both scored on the inlier graph.
    A false closure counts as rejected when no robot uses it at the end (PCM, or GNC in ddf's
    neighbourhood)."""
    g = read_graph(DATA / GRAPHS[name])
    dirty = split_graph(g, scenario_clean.robots, outlier_rate=0.3, seed=1)
    ref = centralised(scenario_clean)
    clean_rec, _, _ = run(scenario_clean, ref, params, rounds)
    dirty_rec, agents, _ = run(dirty, ref, params, rounds)
    false = {(int(dirty.graph.ids[a]), int(dirty.graph.ids[b])) for a, b in dirty.graph.edges[dirty.outlier]}
    true = {(int(dirty.graph.ids[a]), int(dirty.graph.ids[b])) for a, b in dirty.graph.edges[dirty.inter & ~dirty.outlier]}
    used, turned_down = set(), set()
    for a in agents:
        acc, rej = a.closure_pairs()
        used |= {tuple(p) for p in acc.tolist()}
        turned_down |= {tuple(p) for p in rej.tolist()}
    if png is not None:
        from nodes.slam.team_plot import draw_team
        index = {int(v): k for k, v in enumerate(dirty.graph.ids)}
        draw_team(png, {a.robot: (np.array(a.ids), a.estimate) for a in agents},
                  accepted=np.array(sorted(used)), rejected=np.array(sorted(turned_down)),
                  reference={v: ref.poses[k, :2] for v, k in index.items()},
                  title=f"{name}, {dirty.robots} robots, {params}, 30 % false closures ({len(false)}): "
                        f"cost ratio {dirty_rec[-1].cost_ratio:.4f}")
    c0, c1 = clean_rec[-1].cost_ratio, dirty_rec[-1].cost_ratio
    return {"outlier_cost_change": abs(c1 - c0) / c0, "outliers_rejected_frac": 1.0 - len(false & used) / max(len(false), 1),
            "outliers": len(false), "true_rejected": len(true - used), "true": len(true),
            "cost_ratio_clean": c0, "cost_ratio_outliers": c1}


def cpu_share(scenario, params: dict, keyframe_hz: float = 10.0, round_hz: float = 5.0) -> float:
    """Process time per robot over simulated time, keyframes streamed at ``keyframe_hz``, with the
    node's defaults (a solve every second while only odometry grows, at most every 0.4 s while closures keep
    coming; a grown condensed graph resent at most every second)."""
    params = params | {"solve_every": int(round_hz), "solve_gap": max(1, round(0.4 * round_hz)),
                       "resend_rounds": int(round_hz)}
    agents = [Agent(r, scenario.robots, **params) for r in range(scenario.robots)]
    streams = [robot_stream(scenario, r) for r in range(scenario.robots)]
    n = max(len(s) for s in streams)
    rounds = int(np.ceil(n / keyframe_hz * round_hz)) + 5
    fed = [0] * len(agents)

    def before(rnd, team):
        due = int(rnd / round_hz * keyframe_hz)
        for k, a in enumerate(team):
            while fed[k] < min(due, len(streams[k])):
                feed(a, streams[k][fed[k]])
                fed[k] += 1

    ref = centralised(scenario)
    t0 = time.process_time()
    codec = Codec()
    run_team(scenario, agents, rounds=rounds, transmit=lambda p: transmit(p, codec), reference=ref, before_round=before)
    return (time.process_time() - t0) / len(agents) / (rounds / round_hz)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="FR079 only, R = 4")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--png", default="out/bench/dslam.png")
    args = ap.parse_args()
    names = [n for n in GRAPHS if (DATA / GRAPHS[n]).exists()]
    if not names:
        print(f"no pose graphs in {DATA}: nothing to measure", file=sys.stderr)
        sys.exit(0)
    if args.quick:
        names = names[:1]
    robots = [4] if args.quick else [2, 4, 8]
    sweep, best = {}, {}
    for name in names:
        g = read_graph(DATA / GRAPHS[name])
        for R in robots:
            s = split_graph(g, R)
            t0 = time.process_time()
            ref = centralised(s)
            t_central = time.process_time() - t0
            up, up_back = upload_bytes(s)
            row = {"upload": {"bytes_to_1pct": up, "bytes_upload_and_return": up_back, "cost_ratio_final": 1.0,
                              "cpu_s": t_central}}
            for label, params in METHODS.items():
                recs, agents, cpu = run(s, ref, params, ROUNDS[params["method"]])
                row[label] = summarise(recs) | {"cpu_s": cpu}
                r = row[label]
                print(f"{name:6s} R={R} {label:9s} final {r['cost_ratio_final']:.5f}  bytes {r['bytes_final']:>9d}  "
                      f"to 1%: {r['bytes_to_1pct']} B in {r['rounds_to_1pct']} rounds  cpu {cpu:.2f} s "
                      f"(upload-all {up} B, +return {up_back} B; central {t_central:.2f} s)", file=sys.stderr, flush=True)
            sweep[f"{name}/R{R}"] = row
            if R == 4:
                reached = {k: v for k, v in row.items() if k != "upload" and v["bytes_to_1pct"] is not None}
                pick = min(reached, key=lambda k: reached[k]["bytes_to_1pct"]) if reached else \
                    min((k for k in row if k != "upload"), key=lambda k: row[k]["cost_ratio_final"])
                best[name] = {"bytes_to_1pct": row[pick]["bytes_to_1pct"], "bytes_upload_all": up,
                              "bytes_upload_and_return": up_back, "cost_ratio_final": row[pick]["cost_ratio_final"],
                              "method": pick}
    studies = {}
    for name in names:
        s4 = split_graph(read_graph(DATA / GRAPHS[name]), 4)
        pick = ROBUST                                  # the method with a team-wide check behind PCM
        png = Path(args.png).with_name(f"dslam_outliers_{name}.png") if args.png else None
        studies[name] = study = outlier_study(s4, name, METHODS[pick], ROUNDS[METHODS[pick]["method"]], png)
        print(f"outliers ({name}, R=4, {pick}, 30 %): cost ratio {study['cost_ratio_clean']:.5f} -> "
              f"{study['cost_ratio_outliers']:.5f} (change {study['outlier_cost_change']:.2e}); false rejected "
              f"{study['outliers_rejected_frac']:.3f} of {study['outliers']}; true ones lost {study['true_rejected']} "
              f"of {study['true']}", file=sys.stderr, flush=True)
    first = names[0]
    s4 = split_graph(read_graph(DATA / GRAPHS[first]), 4)
    pick = best[first]["method"]
    if args.quick:
        pick = ROBUST
    out = {"outlier_cost_change": max(v["outlier_cost_change"] for v in studies.values()),
           "outliers_rejected_frac": min(v["outliers_rejected_frac"] for v in studies.values())}
    cpu = cpu_share(s4, METHODS[pick])
    print(f"cpu per robot at 10 keyframes/s ({first}, {pick}): {100 * cpu:.1f} % of a core", file=sys.stderr)
    if args.png:
        plot(sweep, best, Path(args.png))
    result = {"graphs": best, "outlier_cost_change": out["outlier_cost_change"],
              "outliers_rejected_frac": out["outliers_rejected_frac"], "cpu_core_frac": cpu, "outlier_studies": studies,
              "sweep": {k: {m: {kk: vv for kk, vv in v.items() if kk != "curve"} for m, v in row.items()}
                        for k, row in sweep.items()}}
    if args.json:
        print(json.dumps(result))


def plot(sweep: dict, best: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from figures import save_figure
    keys = [k for k in sweep if k.endswith("/R4")]
    fig, axes = plt.subplots(1, len(keys), figsize=(5.5 * len(keys), 4.5), squeeze=False)
    for ax, key in zip(axes[0], keys):
        row = sweep[key]
        for label, v in row.items():
            if label == "upload":
                continue
            curve = np.array(v["curve"], float)
            ax.loglog(np.maximum(curve[:, 1], 1), np.maximum(curve[:, 2] - 1.0, 1e-6), ".-", label=label)
        ax.axvline(row["upload"]["bytes_to_1pct"], color="k", ls="--", label="upload all edges")
        ax.axhline(0.01, color="grey", ls=":")
        ax.set_title(f"{key}: cost ratio - 1 vs bytes")
        ax.set_xlabel("bytes exchanged (cumulative)")
        ax.set_ylabel("chi2 / chi2_centralised - 1")
        ax.legend(fontsize=7)
    save_figure(fig, path, dpi=110)
    print(f"wrote {path}", file=sys.stderr)


if __name__ == "__main__":
    main()
