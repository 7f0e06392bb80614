"""Self-play on SlimeVolley: GA self-play vs PPO self-play vs PPO against the baseline (seed 16).

Score against the built-in baseline (right slime's points won minus lost, mean +- std over
episodes; the leaderboard's protocol: episode i after ``env.seed(721 + i)``) against training
games and training CPU minutes, for

* ``ga``: tournament-selection self-play (Algorithm 3, estool's settings: 128 agents, the
  273-parameter MLP, noise 0.1), the batched variant (64 disjoint pairs per round) on the
  numpy replica. Resumed from ``--ga-checkpoint`` (a run started earlier, e.g. in the
  background) and continued to ``--ga-games`` if that is more; the curve evaluates the
  champion snapshots (every 1000 games) on the replica.
* ``ppo_selfplay``: PPO with a champion list (Algorithm 2, estool's train_ppo_selfplay:
  threshold 0.5 over 100 games every 100k steps, 4096 steps per update, 10 epochs,
  minibatch 64, no entropy bonus) on ``BusVecEnv(SlimeVsOpponent)`` in-process.
* ``ppo_baseline``: the same PPO against the baseline (Algorithm 1 with the expert fixed).

Each method's delivered policy (GA: the longest lineage; PPO self-play: the latest
champion; PPO: the trainee) is scored over ``--episodes`` (1000) episodes of the ORIGINAL
env; the GA champion also on the replica over the same seeds (the replica restarts the
baseline's memory every episode, the original env does not: the two agree statistically,
and exactly when the original's baseline is restarted too -- tested). The replica's speed
against the original is measured first. PPO results are cached in ``--out`` and reused
unless ``--retrain`` (the GA's evaluation too, while its checkpoint has not moved).

    python bench/selfplay.py [--quick] [--json] [--ppo-cpu-minutes 12] [--png out/selfplay.png]

``--json`` (one object, last): ga_selfplay_score, ppo_selfplay_score, ppo_baseline_score (+ _std),
cpu_minutes (per method), games (per method), curves (per method: games, cpu_min, score, std),
winner_per_cpu_minute, speed (game-steps/s, original and replica at G = 1, 64, 256).
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
import warnings
from pathlib import Path

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1")
warnings.filterwarnings("ignore", module="gym")
import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from nodes.learn import slime_game as sg  # noqa: E402
from nodes.learn.ga_selfplay import GAConfig, TournamentGA  # noqa: E402
from nodes.learn.slime_match import evaluate_original, evaluate_replica  # noqa: E402
from nodes.learn.slime_policy import MlpPolicy  # noqa: E402

LEADERBOARD = {"ppo_baseline": 1.377, "ga": 0.353, "ppo_selfplay": -0.371}


def measure_speed(seconds: float = 1.5) -> dict[str, float]:
    """Game-steps/s of the game physics, random buttons: the original (one Game stepped in
    Python; its rate does not depend on how many games) and the replica at G = 1, 64, 256."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from slimevolleygym.slimevolley import Game
    rng = np.random.default_rng(0)
    acts = rng.integers(0, 2, size=(512, 2, 256, 3))
    game, n, t0 = Game(np_random=np.random.default_rng(0)), 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        a = acts[n % 512, :, 0]
        game.agent_left.setAction(a[0])
        game.agent_right.setAction(a[1])
        game.step()
        if min(game.agent_left.life, game.agent_right.life) <= 0:
            game.reset()
        n += 1
    out = {"original": n / (time.perf_counter() - t0)}
    for g in (1, 64, 256):
        games = sg.new_games(rng.uniform(-20, 20, g), rng.uniform(10, 25, g))
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            a = acts[n % 512, :, :g]
            reward = sg.step_games(games, a[0], a[1])
            scored = reward != 0
            if scored.any():
                k = int(scored.sum())
                sg.serve(games, scored, rng.uniform(-20, 20, k), rng.uniform(10, 25, k))
            over = games.life.min(axis=0) <= 0
            if over.any():
                k = int(over.sum())
                sg.reset_games(games, over, rng.uniform(-20, 20, k), rng.uniform(10, 25, k))
            n += 1
        out[f"replica_G{g}"] = n * g / (time.perf_counter() - t0)
        out[f"speedup_G{g}"] = out[f"replica_G{g}"] / out["original"]
    return out


def score(scores: np.ndarray) -> dict[str, float]:
    return {"mean": float(np.mean(scores)), "std": float(np.std(scores)), "n": int(len(scores))}


def run_ga(args: argparse.Namespace) -> dict:
    ck = Path(args.ga_checkpoint)
    ga = TournamentGA.load(ck) if ck.exists() else TournamentGA(GAConfig(snapshot_every=args.ga_snapshot), seed=612)
    print(f"GA: {'resumed' if ck.exists() else 'new'} at {ga.games} games, {ga.cpu_s / 60:.1f} CPU min", flush=True)
    if ga.games < args.ga_games:
        ck.parent.mkdir(parents=True, exist_ok=True)
        ga.run(args.ga_games, pairs_per_round=min(64, ga.config.population // 2), checkpoint=ck,
               progress=lambda i: print(f"GA {i['games']} games {i['games_per_s']:.0f}/s lineage "
                                        f"{i['champion_lineage']}", flush=True), progress_every=2000)
    cache = Path(args.out) / "ga_result.json"
    key = {"games": ga.games, "episodes": args.episodes, "curve_episodes": args.curve_episodes,
           "curve_points": args.curve_points}
    if cache.exists() and not args.retrain:
        res = json.loads(cache.read_text())
        if res.get("key") == key:
            print(f"GA: reusing the evaluation in {cache}", flush=True)
            return res
    snaps = ga.snapshots
    pick = np.unique(np.linspace(0, len(snaps.games) - 1, min(args.curve_points, len(snaps.games))).astype(int))
    curve = []
    for k in pick:
        s = evaluate_replica(MlpPolicy(snaps.params[k], ga.config.hidden), args.curve_episodes, seed=10_000_000)
        curve.append({"games": snaps.games[k], "cpu_s": snaps.cpu_s[k], "lineage": snaps.lineage[k],
                      "score": float(s.mean()), "score_std": float(s.std())})
        print(f"GA snapshot {snaps.games[k]:>7d} games {snaps.cpu_s[k] / 60:6.1f} CPU min lineage "
              f"{snaps.lineage[k]:>5d}: {s.mean():+.3f} +- {s.std():.3f}", flush=True)
    _, champ = ga.champion()
    policy = MlpPolicy(champ, ga.config.hidden)
    t0 = time.perf_counter()
    final = evaluate_original(policy.predict, args.episodes)
    t_orig = time.perf_counter() - t0
    t0 = time.perf_counter()
    replica = evaluate_replica(policy, args.episodes)
    t_rep = time.perf_counter() - t0
    print(f"GA champion (lineage {ga.lineage.max()}): original {final.mean():+.3f} +- {final.std():.3f} "
          f"({t_orig:.0f} s), replica {replica.mean():+.3f} +- {replica.std():.3f} ({t_rep:.1f} s)", flush=True)
    res = {"final": score(final), "replica": score(replica), "eval_s_original": t_orig, "eval_s_replica": t_rep,
           "games": ga.games, "steps": ga.steps, "cpu_s": ga.cpu_s, "lineage": int(ga.lineage.max()), "curve": curve,
           "key": key}
    cache.parent.mkdir(parents=True, exist_ok=True)
    cache.write_text(json.dumps(res, indent=1))
    return res


def run_ppo(mode: str, args: argparse.Namespace) -> dict:
    from nodes.learn.bus_env import BusVecEnv
    from nodes.learn.ppo import PPO, PPOConfig
    from nodes.learn.ppo_selfplay import ppo_policy, train_ppo_slime

    out = Path(args.out) / mode
    cache = out / "result.json"
    if cache.exists() and not args.retrain:
        res = json.loads(cache.read_text())
        if res.get("cpu_budget_min") == args.ppo_cpu_minutes and res.get("episodes") == args.episodes:
            print(f"PPO {mode}: reusing {cache}", flush=True)
            return res
    env = BusVecEnv("nodes.learn.slime:SlimeVsOpponent", n_envs=8, mode="inproc")
    cfg = PPOConfig(n_steps=512, epochs=10, minibatches=64, lr=3e-4, anneal_lr=False, ent_coef=0.0,
                    gamma=0.99, gae_lambda=0.95, clip=0.2, hidden=(64, 64))
    agent = PPO(env.single_observation_space, env.single_action_space, cfg, seed=0)
    every = args.ppo_check_steps
    run = train_ppo_slime(agent, env, mode=mode.removeprefix("ppo_"), cpu_budget_s=args.ppo_cpu_minutes * 60, out_dir=out,
                          check_every_steps=every, check_episodes=args.check_episodes,
                          curve_every_steps=args.ppo_curve_steps, curve_episodes=args.curve_episodes,
                          progress=lambda m: print(m, flush=True))
    env.close()
    if run.final is None:
        final = evaluate_original(lambda o: np.random.default_rng().integers(0, 2, 3), args.episodes)
    else:
        act = ppo_policy(run.final)
        final = evaluate_original(lambda o: act(o[None, :])[0], args.episodes)
    print(f"PPO {mode}: original {final.mean():+.3f} +- {final.std():.3f}, {len(run.champions)} champions", flush=True)
    res = {"final": score(final), "games": run.games, "steps": run.steps, "cpu_s": run.train_cpu_s,
           "eval_cpu_s": run.eval_cpu_s, "champions": len(run.champions), "curve": run.curve,
           "cpu_budget_min": args.ppo_cpu_minutes, "episodes": args.episodes}
    cache.write_text(json.dumps(res, indent=1))
    return res


def at_cpu(curve: list[dict], cpu_s: float) -> float:
    """Score of the last evaluated policy available after ``cpu_s`` training CPU seconds."""
    rows = [r for r in curve if r["cpu_s"] <= cpu_s + 1e-9]
    return rows[-1]["score"] if rows else float("nan")


def plot(results: dict, path: Path, n_eval: int) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from figures import save_figure

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    colours = {"ga": "tab:green", "ppo_selfplay": "tab:orange", "ppo_baseline": "tab:blue"}
    for name, res in results.items():
        c = res["curve"]
        games = np.maximum([r["games"] for r in c], 1)
        cpu = [r["cpu_s"] / 60 for r in c]
        s = np.array([r["score"] for r in c])
        sd = np.array([r["score_std"] for r in c])
        label = f"{name} (final {res['final']['mean']:+.2f} over {res['final']['n']} original eps)"
        for ax, x in zip(axes, (games, cpu)):
            ax.plot(x, s, "-o", ms=3, color=colours[name], label=label)
            se = 2 * sd / np.sqrt(n_eval)
            ax.fill_between(x, s - se, s + se, color=colours[name], alpha=0.15)
    for ax in axes:
        for name, v in LEADERBOARD.items():
            ax.axhline(v, color=colours[name], ls=":", lw=1)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylabel("score vs baseline (replica, mean, ±2 s.e.)")
        ax.grid(alpha=0.3)
    axes[0].set_xscale("log")
    axes[0].set_xlabel("training games")
    axes[1].set_xlabel("training CPU minutes")
    axes[0].legend(fontsize=8, loc="lower right")
    axes[1].set_title("dotted: leaderboard (PPO 1.377, GA 0.353, PPO self-play -0.371)", fontsize=9)
    save_figure(fig, path, dpi=100)


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="a smoke run: tiny budgets in out/selfplay/quick")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--out", default="out/selfplay")
    ap.add_argument("--png", default="out/selfplay.png")
    ap.add_argument("--ga-checkpoint", default="out/selfplay/ga.npz")
    ap.add_argument("--ga-games", type=int, default=0, help="continue the GA to this many games (0: as saved)")
    ap.add_argument("--ga-snapshot", type=int, default=1000)
    ap.add_argument("--ppo-cpu-minutes", type=float, default=12.0)
    ap.add_argument("--ppo-check-steps", type=int, default=100_000)
    ap.add_argument("--ppo-curve-steps", type=int, default=250_000)
    ap.add_argument("--check-episodes", type=int, default=100)
    ap.add_argument("--curve-episodes", type=int, default=200)
    ap.add_argument("--curve-points", type=int, default=30)
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--methods", default="ga,ppo_selfplay,ppo_baseline")
    ap.add_argument("--retrain", action="store_true", help="train PPO and evaluate the GA again even if cached")
    args = ap.parse_args()
    if args.quick:
        args.out, args.png = "out/selfplay/quick", "out/selfplay/quick/selfplay.png"
        args.ga_checkpoint, args.ga_games, args.ga_snapshot = "out/selfplay/quick/ga.npz", 512, 128
        args.ppo_cpu_minutes, args.ppo_check_steps, args.ppo_curve_steps = 0.3, 8192, 16384
        args.check_episodes, args.curve_episodes, args.episodes = 20, 20, 20
    speed = measure_speed(0.5 if args.quick else 1.5)
    print("game-steps/s: " + ", ".join(f"{k} {v:,.0f}" for k, v in speed.items() if "speedup" not in k)
          + "; replica/original: " + ", ".join(f"G={k[9:]} {v:.2f}x" for k, v in speed.items() if "speedup" in k),
          flush=True)
    results = {}
    for m in args.methods.split(","):
        results[m] = run_ga(args) if m == "ga" else run_ppo(m, args)
    common = min(r["cpu_s"] for r in results.values())
    at = {m: at_cpu(r["curve"], common) for m, r in results.items()}
    def best(methods: list[str]) -> str | None:
        return max(methods, key=lambda m: -np.inf if np.isnan(at[m]) else at[m]) if methods else None

    winner = best(list(at))
    sp_winner = best([m for m in at if m != "ppo_baseline"])
    print(f"\n{'method':14s} {'games':>8s} {'CPU min':>8s} {'score (original, ' + str(args.episodes) + ' eps)':>30s}"
          f" {'at ' + format(common / 60, '.1f') + ' CPU min':>16s} {'leaderboard':>12s}")
    for m, r in results.items():
        f = r["final"]
        print(f"{m:14s} {r['games']:>8d} {r['cpu_s'] / 60:>8.1f} {f['mean']:>+22.3f} +- {f['std']:.3f} "
              f"{at[m]:>+16.3f} {LEADERBOARD[m]:>+12.3f}")
    print(f"best score at the common {common / 60:.1f} CPU minutes: {winner}; among self-play methods: {sp_winner}")
    plot(results, Path(args.png), args.curve_episodes)
    out = {"ga_selfplay_score": results.get("ga", {}).get("final", {}).get("mean"),
           "ppo_selfplay_score": results.get("ppo_selfplay", {}).get("final", {}).get("mean"),
           "ppo_baseline_score": results.get("ppo_baseline", {}).get("final", {}).get("mean"),
           **{f"{k}_std": results[m]["final"]["std"] for m, k in
              (("ga", "ga_selfplay_score"), ("ppo_selfplay", "ppo_selfplay_score"), ("ppo_baseline", "ppo_baseline_score"))
              if m in results},
           "cpu_minutes": {m: r["cpu_s"] / 60 for m, r in results.items()},
           "games": {m: r["games"] for m, r in results.items()},
           "episodes": args.episodes, "common_cpu_minutes": common / 60, "score_at_common_cpu": at,
           "winner_per_cpu_minute": winner, "selfplay_winner_per_cpu_minute": sp_winner,
           "ga_replica_score": results["ga"]["replica"]["mean"] if "ga" in results else None,
           "curves": {m: [{"games": c["games"], "cpu_min": c["cpu_s"] / 60, "score": c["score"],
                           "std": c["score_std"]} for c in r["curve"]] for m, r in results.items()},
           "speed": speed, "png": args.png}
    if args.json:
        print(json.dumps(out))


if __name__ == "__main__":
    main()
