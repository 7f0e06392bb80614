"""Double-Ackermann trajectory following: tracking error against control rate, bus latency, controller and path.

    python bench/ackermann.py [--quick] [--json]

Closed loop on the pure 4WS model (sim/vehicle4ws.py), starting on the reference:
controller at ``rate`` Hz -> command delay (bus latency) + zero-order hold -> first-order
drives with rate / acceleration limits -> vehicle; the controller sees the pose and wheels
``state delay`` late.  Controllers, side by side in the same run: the seed's final
two-stage law ("final"), the same with no lead compensation ("final/nolead"), the
outer stage alone ("kinematic", a pure kinematic baseline), the seed's first
feedback-linearisation law ("fblin", singular at |delta_b| = pi/2) and the CasADi MPC
(sqpmethod + qrqp).  Ground truth is the analytic trajectory.

"fig8_rms_mm_can" is the real CANopen loop: ``launch/ackermann_can.yaml`` itself (trajectory,
controller, CiA 402 master, simulated drives with their motor dynamics, vehicle) in lockstep
on a synchronous bus, whole run from rest (``bench/ackermann_can.py`` has the same loop over
python-can's udp_multicast in real time). The launch file runs the cyclic synchronous modes
(steering CSP, wheels CSV, SYNC at 100 Hz): "fig8_rms_mm_csp" is that run; the knob swept
is the SYNC rate (the master's cycle follows it), with the profile modes (PP / PV, no SYNC)
side by side. "fig8_rms_mm_modelled_bus" is this file's bus model (5 ms command latency,
5 ms state delay, 20 ms first-order drives).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)
sys.path.insert(0, os.path.join(REPO, "bench"))

import numpy as np  # noqa: E402

from nodes.control.double_ackermann import FblinController, FinalController, KinematicController  # noqa: E402
from nodes.control.mpc import MpcController  # noqa: E402
from nodes.control.trajectory import make_trajectory  # noqa: E402
from sim.vehicle4ws import VehicleParams, simulate_tracking  # noqa: E402

BUS = dict(latency_s=0.005, state_delay_s=0.005, tau_s=0.020)


def make(law: str, *, lead_s: float = 0.0, horizon: int = 20):
    if law == "final":
        return FinalController(lead_s=lead_s)
    if law == "final/nolead":
        return FinalController()
    if law == "kinematic":
        return KinematicController()
    if law == "fblin":
        return FblinController(lead_s=lead_s)
    if law == "mpc":
        return MpcController(horizon=horizon, lead_s=lead_s)
    raise ValueError(law)


def run(law: str, kind: str, rate: float, duration: float, *, bus: dict | None = None, horizon: int = 20,
        slip: float = 0.0) -> dict:
    """One closed-loop run; returns error summary plus the median controller step time (us)."""
    bus = bus or {}
    tau = bus.get("tau_s", 0.0)
    lead = tau + bus.get("latency_s", 0.0)
    ctrl = make(law, lead_s=lead, horizon=horizon)
    times: list[float] = []
    step = ctrl.step

    def timed(*a, **kw):
        t0 = time.perf_counter()
        out = step(*a, **kw)
        times.append(time.perf_counter() - t0)
        return out
    ctrl.step = timed
    params = VehicleParams(wheel_tau_s=tau, steer_tau_s=tau, slip_std=slip, seed=1)
    res = simulate_tracking(ctrl, make_trajectory(kind), rate_hz=rate, duration_s=duration, params=params,
                            latency_s=bus.get("latency_s", 0.0), state_delay_s=bus.get("state_delay_s", 0.0))
    out = res.summary()
    out["step_us"] = float(np.median(times) * 1e6)
    out["result"] = res
    return out


def fmt(v: float) -> str:
    return f"{v:10.4f}" if v < 1e4 else f"{v:10.3g}"


def table(title: str, head: list[str], rows: list[list]) -> None:
    print(f"\n{title}")
    print("  ".join(f"{h:>12s}" for h in head))
    for r in rows:
        print("  ".join(f"{c:>12s}" if isinstance(c, str) else f"{fmt(c):>12s}" for c in r))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="shorter runs, fewer points")
    ap.add_argument("--json", action="store_true", help="print one JSON object with the headline figures only")
    args = ap.parse_args()
    q = args.quick
    lap = 20.0 if q else 40.0                      # one figure-eight lap is 40 s
    rates = [10, 50, 200] if q else [10, 20, 50, 100, 200]
    laws = ["final", "kinematic", "fblin", "mpc"]
    say = (lambda *a, **k: None) if args.json else print

    # 1. error vs control rate, no bus
    sweep = {law: {r: run(law, "figure8", r, lap) for r in rates} for law in laws}
    rows = [[law, *(sweep[law][r]["rms_mm"] for r in rates)] for law in laws]
    if not args.json:
        table("figure-eight RMS position error (mm) vs control rate (Hz), ideal bus", ["law", *map(str, rates)], rows)

    # 2. per trajectory at 50 Hz (no bus, then modelled bus)
    kinds = ["circle", "figure8", "crab", "spin", "focus"]
    per = {(law, k): run(law, k, 50, lap) for law in laws for k in kinds}
    if not args.json:
        for key, title in (("rms_mm", "RMS position error (mm)"), ("max_deg", "max heading error (deg)"),
                           ("bad_ticks", "share of ticks the law could not answer (singular -> stop)")):
            table(f"{title} at 50 Hz, ideal bus", ["law", *kinds], [[law, *(per[law, k][key] for k in kinds)]
                                                                     for law in laws])

    # 3. modelled bus: latency sweep at 50 Hz, 20 ms drives, 5 ms state delay
    lats = [0.0, 0.005, 0.02] if q else [0.0, 0.002, 0.005, 0.010, 0.020]
    bus_laws = ["final", "final/nolead", "kinematic", "mpc"]
    bus = {law: {lat: run(law, "figure8", 50, lap, bus={**BUS, "latency_s": lat}) for lat in lats} for law in bus_laws}
    if not args.json:
        table("figure-eight RMS (mm) vs command latency (ms); modelled bus: 20 ms drives, 5 ms state delay, 50 Hz",
              ["law", *(f"{lat * 1e3:g}" for lat in lats)], [[law, *(bus[law][lat]["rms_mm"] for lat in lats)]
                                                              for law in bus_laws])
    can = bus["final"][BUS["latency_s"]] if BUS["latency_s"] in bus["final"] else run("final", "figure8", 50, lap, bus=BUS)
    slip = run("final", "figure8", 50, lap, bus=BUS, slip=0.01)

    # the real CANopen loop: the launch file itself in lockstep (deterministic, faster than real time)
    from ackermann_can import lockstep_run
    real_can = lockstep_run(duration_s=lap + 5.0)          # the launch file as shipped: CSP / CSV, SYNC 100 Hz
    profile = lockstep_run(duration_s=lap + 5.0, overrides={"can": {"sync_hz": 0.0, "steer_mode": "pp",
                                                                    "wheel_mode": "pv"}})
    sync_rates = [50.0, 200.0] if q else [50.0, 200.0, 500.0]
    csp = {100.0: real_can}
    for hz in sync_rates:
        print(f"CSP lockstep at SYNC {hz:g} Hz ...", file=sys.stderr, flush=True)
        csp[hz] = lockstep_run(duration_s=lap + 5.0, overrides={"can": {"sync_hz": hz, "rate_hz": hz}})
    if not args.json:
        table(f"launch/ackermann_can.yaml in lockstep, figure-eight from rest over {lap + 5.0:.0f} s: "
              "CSP/CSV vs SYNC rate, and the profile modes",
              ["modes", "SYNC Hz", "rms_mm", "max_mm", "wall_s", "vs profile"],
              [*[["CSP/CSV", f"{hz:g}", r["rms_mm"], r["max_mm"], r["wall_s"], r["rms_mm"] / profile["rms_mm"]]
                 for hz, r in sorted(csp.items())],
               ["PP/PV", "-", profile["rms_mm"], profile["max_mm"], profile["wall_s"], 1.0]])
        for hz, r in sorted(csp.items()):
            if r["tripped"]:
                say(f"  SYNC {hz:g} Hz: TRIPPED ({r['tripped']})")

    # 4. controller step time and MPC solve time vs horizon
    steps = {law: per[law, "figure8"]["step_us"] for law in laws}
    horizons = [5, 10, 20] if q else [5, 10, 20, 40]
    mpc_h = {h: run("mpc", "figure8", 50, 4.0 if q else 10.0, horizon=h) for h in horizons}
    if not args.json:
        table("median controller step (us), figure-eight at 50 Hz", ["law", "step_us", "vs final"],
              [[law, steps[law], steps[law] / steps["final"]] for law in laws])
        table("MPC (CasADi sqpmethod+qrqp, <= 3 SQP iterations, warm start): step time (solve + shaping) vs horizon, 50 Hz",
              ["horizon", "median ms", "rms_mm"], [[str(h), mpc_h[h]["step_us"] / 1e3, mpc_h[h]["rms_mm"]]
                                                   for h in horizons])
        say(f"\nmodelled bus (5 ms latency, 5 ms state delay, 20 ms drives) + 1% slip noise: "
            f"RMS {slip['rms_mm']:.3f} mm, max {slip['max_mm']:.3f} mm")

    headline = {
        "fig8_rms_mm_50hz": per["final", "figure8"]["rms_mm"],
        "fig8_max_mm_50hz": per["final", "figure8"]["max_mm"],
        "fig8_rms_mm_can": real_can["rms_mm"],
        "fig8_max_mm_can": real_can["max_mm"],
        "fig8_rms_mm_can_is": "launch/ackermann_can.yaml in lockstep: CiA 402 master + simulated drives, whole run from rest",
        "fig8_rms_mm_csp": real_can["rms_mm"],
        "fig8_max_mm_csp": real_can["max_mm"],
        "fig8_rms_mm_csp_is": "launch/ackermann_can.yaml in lockstep, steering CSP + wheels CSV, SYNC 100 Hz, "
                              "controller 50 Hz on can/measured, whole run from rest (1 s alignment, 4 s ramp)",
        "fig8_csp_tripped": real_can["tripped"],
        "fig8_rms_mm_profile": profile["rms_mm"],
        "fig8_rms_mm_csp_by_sync_hz": {f"{hz:g}": r["rms_mm"] for hz, r in sorted(csp.items())},
        "fig8_rms_mm_modelled_bus": can["rms_mm"],
        "fig8_rms_mm_modelled_bus_slip1pct": slip["rms_mm"],
        "step_us": steps["final"],
        "mpc_ms_h20": mpc_h[20]["step_us"] / 1e3,
        "fig8_rms_mm_50hz_by_law": {law: per[law, "figure8"]["rms_mm"] for law in laws},
        "step_us_by_law": steps,
        "fblin_bad_tick_share": {k: per["fblin", k]["bad_ticks"] for k in kinds},
        "quick": q,
    }
    path = plot(sweep, rates, bus, lats, per, mpc_h, horizons)
    if args.json:
        print(json.dumps(headline))
    else:
        print(f"\nheadline: fig8 {headline['fig8_rms_mm_50hz']:.4f} mm RMS at 50 Hz (goal <= 1 mm), "
              f"CAN loop {headline['fig8_rms_mm_can']:.4f} mm (goal <= 10 mm), CSP at 100 Hz SYNC "
              f"{headline['fig8_rms_mm_csp']:.4f} mm (goal <= 1 mm; profile modes {profile['rms_mm']:.4f} mm; "
              f"modelled bus "
              f"{headline['fig8_rms_mm_modelled_bus']:.4f} mm), step "
              f"{headline['step_us']:.1f} us (goal <= 100), MPC h20 {headline['mpc_ms_h20']:.2f} ms (goal <= 10)")
        print(f"plot: {path}")


def per_laws(per: dict) -> list[str]:
    return list(dict.fromkeys(law for law, _ in per))


def plot(sweep, rates, bus, lats, per, mpc_h, horizons) -> str:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from figures import save_figure
    fig, ax = plt.subplots(2, 3, figsize=(16, 9.5))
    a = ax[0, 0]
    for law, d in sweep.items():
        a.loglog(rates, [max(d[r]["rms_mm"], 1e-6) for r in rates], "o-", label=law)
    a.axhline(1.0, color="k", ls=":", lw=1)
    a.set(xlabel="control rate (Hz)", ylabel="RMS position error (mm)", title="figure-eight, ideal bus")
    a.legend()
    a = ax[0, 1]
    for law, d in bus.items():
        a.semilogy([lat * 1e3 for lat in lats], [max(d[lat]["rms_mm"], 1e-6) for lat in lats], "o-", label=law)
    a.axhline(10.0, color="k", ls=":", lw=1)
    a.set(xlabel="command latency (ms)", ylabel="RMS position error (mm)",
          title="modelled bus at 50 Hz: 20 ms drives, 5 ms state delay")
    a.legend()
    a = ax[0, 2]
    a.plot(horizons, [mpc_h[h]["step_us"] / 1e3 for h in horizons], "o-")
    a.axhline(10.0, color="k", ls=":", lw=1)
    a.set(xlabel="MPC horizon (intervals of 20 ms)", ylabel="median step time (ms)", title="MPC step (solve + shaping)")
    a = ax[1, 2]
    for law in per_laws(per):
        res = per[law, "figure8"]["result"]
        a.semilogy(res.t_s, np.maximum(res.pos_err_m * 1e3, 1e-7), lw=0.8, label=law)
    res = bus["final"][max(bus["final"])]["result"]
    a.semilogy(res.t_s, np.maximum(res.pos_err_m * 1e3, 1e-7), lw=0.8, label=f"final, modelled bus {max(bus['final']) * 1e3:g} ms")
    a.set(xlabel="t (s)", ylabel="position error (mm)", title="figure-eight at 50 Hz: error over time")
    a.legend(fontsize=7)
    for a, kind in zip(ax[1], ("figure8", "focus")):
        ref = per["final", kind]["result"].ref
        a.plot(ref[:, 0], ref[:, 1], "k-", lw=3, alpha=0.3, label="reference")
        for law, st in (("final", "-"), ("kinematic", "--"), ("fblin", ":")):
            pose = per[law, kind]["result"].pose
            a.plot(pose[:, 0], pose[:, 1], st, label=f"{law} ({per[law, kind]['rms_mm']:.3g} mm RMS)")
        pose = per["final", kind]["result"].pose
        for i in range(0, len(pose), max(1, len(pose) // 12)):       # heading arrows
            a.arrow(pose[i, 0], pose[i, 1], 0.25 * math.cos(pose[i, 2]), 0.25 * math.sin(pose[i, 2]),
                    head_width=0.06, color="C3")
        a.set(aspect="equal", title=f"{kind} at 50 Hz (arrows: heading)", xlabel="x (m)", ylabel="y (m)")
        a.legend(fontsize=7)
    return str(save_figure(fig, os.path.join(REPO, "out", "ackermann.png"), dpi=90))


if __name__ == "__main__":
    main()
