"""RL car benchmark (seed 14): PPO over the bus against hand controllers, error against training.

1. PPO validated on CartPole-v1 (Gymnasium's own env): mean return of the deterministic policy
   over 100 episodes after CleanRL's budget of 500k steps, for each of ``--seeds`` training seeds;
   the commonly published figure is 500 (the cap; "solved" at 475). (At 200k steps, the budget
   before, the same PPO gave 495, 124 and 177 for seeds 0-2: one seed said little.)
2. Reach the point: PPO trained on the bus env (16 instances); every ``--every`` steps the
   policy is scored on 100 held-out episodes (seeds 10,000+; training uses 0+): final distance
   to the target (mm, mean +- std, median, p95) against env steps and wall minutes. Baseline in
   the same run: the classic go-to-goal law (turn toward the target, drive forward or backward
   by the cosine of the bearing), with the same observation, its two gains set by a sweep on
   training seeds. Trained from ``--seeds`` seeds; the goal is judged on the held-out episodes of
   every seed's picked checkpoint, pooled (the rule before: seed 0 alone, still in the JSON).
   Training signal: the paper's eq. (5) without its constant -1 per step (``ReachCar(step_cost=0)``;
   ``--reach-step-cost 1`` trains on eq. (5) as printed). Every episode lasts 100 steps, so the
   constant ranks no policy differently, but with it every return is negative (-100 far away) while
   the critic starts at 0: states the car has not visited yet (metres away) look better than the
   target, GAE pays for driving toward them, and beyond ~1 m eq. (5) is too flat (e^{-5x}) to pull
   the car back (seed 2: by 40k steps the car drives straight off at full speed, 9.7 m at the end;
   at 16k steps its critic valued a point 8 m past the target at +0.65, the target at -1.92).
   Measured (this protocol, 4M steps, held-out mean of the checkpoint picked on validation, mm),
   step cost 1 -> 0: seed 0 13.96 -> 1.05, seed 1 395.03 -> 0.06, seed 2 5145.13 -> 0.89,
   seed 3 41.92 -> 0.14, seed 4 236.45 -> 0.92 (median of the 5 seeds 236 -> 0.89 mm, worst
   5145 -> 1.05). With the step cost kept: potential-based shaping (``shaping``, Phi = -k distance)
   at k = 10/m gives 0.06, 0.97, 1.54 mm on seeds 0-2 (validation means 0.80 mm against 0.68 for
   step cost 0), at k = 1/m 3.77, 13.71, 3136.87 (seed 2 still drives off); PPO's target_kl 0.02
   gives 8.17, 490.52, 6115.46 (the cause is in the returns, not the step size).
3. Maze: PPO with the paper's straight-line distance in its reward (the default), and with the
   corridor (geodesic) distance, same budget; success = the exit reached within 30 s, over 100
   held-out episodes. Baseline: a left-hand wall follower on the same range readings, gains by a
   sweep on training seeds.

Checkpoints live in out/learn/ and are resumed (``--fresh`` retrains); the minutes reported are
those the checkpoints recorded. PNG: out/bench_rl_car.png.

    python bench/rl_car.py [--quick] [--fresh] [--seeds 3] [--json]

``--json`` keys: reach_err_mm_mean, reach_err_mm_std, maze_success_frac, train_minutes, and
cartpole, reach (curve, baseline), maze (per reward rule, baseline).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from nodes.learn.bus_env import BusVecEnv  # noqa: E402
from nodes.learn.ppo import PPO, PPOConfig  # noqa: E402
from nodes.learn.train import evaluate  # noqa: E402

OUT = REPO / "out" / "learn"
REACH, MAZE = "sim.car_env:ReachCar", "sim.car_env:MazeCar"
HELD_OUT = 10_000
VALIDATION = 5_000      # picks the checkpoint (early stopping); never the figures reported


# -- hand controllers (same observation as the policy) --------------------------------------------
def go_to_goal(obs: np.ndarray, k_v: float, k_w: float) -> np.ndarray:
    """Turn toward the target and drive by the cosine of the bearing (backward when it is behind)."""
    bx, by, d = obs[:, 6], obs[:, 7], obs[:, 8]
    bearing = np.arctan2(by, bx)
    back = np.abs(bearing) > np.pi / 2
    bearing = np.where(back, np.angle(np.exp(1j * (bearing + np.pi))), bearing)
    v = k_v * d * np.cos(bearing) * np.where(back, -1.0, 1.0)
    return np.column_stack([np.clip(v, -1, 1), np.clip(k_w * bearing / np.pi, -1, 1)])


def wall_follower(obs: np.ndarray, gap_m: float, k_w: float) -> np.ndarray:
    """Keep a wall on the left at ``gap_m``; turn right when blocked ahead, left when the wall ends."""
    rays = obs[:, 11:]            # 16 rays from -pi in steps of pi/8: index 8 ahead, 10 front-left, 12 left
    front, front_left, left = rays[:, 8], rays[:, 10], rays[:, 12]
    w = np.clip(k_w * (np.minimum(left, front_left / np.sqrt(2)) - gap_m), -1, 1)
    v = np.full(len(obs), 0.6)
    blocked = front < 0.35
    lost = (left > 2 * gap_m + 0.3) & ~blocked
    w = np.where(blocked, -1.0, np.where(lost, 0.7, w))
    v = np.where(blocked, 0.1, v)
    return np.column_stack([v, w])


def run_hand(sim: str, law, seed: int, episodes: int) -> dict:
    env = BusVecEnv(sim, episodes)
    obs, _ = env.reset(seed=seed)
    final = {n: np.full(episodes, np.nan) for n in env.metric_names}
    pending = np.ones(episodes, bool)
    steps = np.zeros(episodes)
    while pending.any():
        obs, _, term, trunc, info = env.step(law(obs))
        steps += pending
        ended = pending & (term | trunc)
        for n in env.metric_names:
            final[n][ended] = info[n][ended]
        pending &= ~ended
    env.close()
    return {**final, "steps": steps}


def tune(sim: str, make_law, grid: list[tuple[float, float]], score) -> tuple[tuple[float, float], float]:
    """The gains that score best on training seeds (0-99)."""
    best = None
    for g in grid:
        s = score(run_hand(sim, make_law(*g), 0, 100))
        if best is None or s < best[1]:
            best = (g, s)
    return best


# -- PPO runs ----------------------------------------------------------------------------------------
def train_and_score(name: str, sim: str, steps: int, every: int, params: dict, fresh: bool, episodes: int,
                    score_key: str, seed: int = 0, eval_params: dict | None = None) -> tuple[PPO, list[dict]]:
    """Train (resuming) to ``steps`` in chunks of ``every``; score each chunk on held-out episodes.
    ``seed`` draws the initial weights and the rollouts (the held-out episodes are the same);
    ``eval_params`` (default ``params``): the scenario the chunks are scored in."""
    eval_params = params if eval_params is None else eval_params
    path = OUT / f"bench_{name}.ppo"
    curve_path = path.with_suffix(".curve.json")
    if fresh:
        path.unlink(missing_ok=True)
        curve_path.unlink(missing_ok=True)
    curve = json.loads(curve_path.read_text()) if curve_path.exists() else []
    env = BusVecEnv(sim, 16, params=params)
    agent = PPO.load(path) if path.exists() else PPO(env.single_observation_space, env.single_action_space,
                                                     PPOConfig(), seed=seed)
    minutes = curve[-1]["train_minutes"] if curve else 0.0
    first = not curve
    while steps - agent.steps_done >= agent.config.n_steps * env.num_envs:
        t0 = time.perf_counter()
        agent.learn(env, min(every, steps - agent.steps_done), seed=seed if first else None, total_steps=steps,
                    progress=lambda s: print(f"  [{name}] {s}", file=sys.stderr, flush=True)
                    if int(s.split()[1]) % (every // 4 or 1) < 4096 else None)
        first = False
        minutes += (time.perf_counter() - t0) / 60
        agent.save(path)
        agent.save(path.with_suffix(f".{agent.steps_done}.ppo"))
        rep = evaluate(agent, sim, episodes=episodes, seed=HELD_OUT, params=eval_params)
        val = evaluate(agent, sim, episodes=episodes, seed=VALIDATION, params=eval_params)
        curve.append({"steps": agent.steps_done, "train_minutes": minutes,
                      **{k: v for k, v in rep.items() if not isinstance(v, list)},
                      "values": rep[score_key], "validation": val[f"{score_key}_mean"]})
        curve_path.write_text(json.dumps(curve))
        print(f"  [{name}] {agent.steps_done} steps, {minutes:.1f} min: {score_key} "
              f"{rep[score_key + '_mean']:.4f}", file=sys.stderr, flush=True)
    env.close()
    return agent, curve


#: CleanRL's CartPole settings (ppo.py): 8 envs of 128 steps, 4 epochs of 4 minibatches
CARTPOLE_PPO = PPOConfig(n_steps=128, epochs=4, minibatches=4, lr=2.5e-4, ent_coef=0.01, clip_value=True,
                         norm_reward=False)


def cartpole(steps: int, seed: int = 0, cfg: PPOConfig = CARTPOLE_PPO) -> dict:
    """PPO trained on CartPole-v1 for ``steps``, scored by its deterministic policy's mean return over
    100 held-out episodes; ``history`` is the training's per-update log."""
    import gymnasium
    from gymnasium.vector import AutoresetMode

    env = gymnasium.make_vec("CartPole-v1", num_envs=8, vectorization_mode="sync",
                             vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP})
    agent = PPO(env.single_observation_space, env.single_action_space, cfg, seed=seed)
    t0 = time.perf_counter()
    history = agent.learn(env, steps, seed=seed)
    minutes = (time.perf_counter() - t0) / 60
    env.close()
    ev = gymnasium.make("CartPole-v1")
    rets = []
    for ep in range(100):
        o, _ = ev.reset(seed=HELD_OUT + ep)
        total, done = 0.0, False
        while not done:
            o, r, te, tr, _ = ev.step(int(agent.act(o[None])[0]))
            total, done = total + r, te or tr
        rets.append(total)
    return {"steps": steps, "seed": seed, "minutes": minutes, "return_mean": float(np.mean(rets)),
            "return_std": float(np.std(rets)), "published": 500.0, "history": history}


def plot(reach: list[dict], reach_base: dict, mazes: dict, maze_base: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from figures import save_figure

    fig, ax = plt.subplots(1, 3, figsize=(15, 4))
    s = np.array([c["steps"] for c in reach])
    m = np.array([c["distance_m_mean"] for c in reach]) * 1000
    med = np.array([np.median(c["values"]) for c in reach]) * 1000
    ax[0].semilogy(s / 1e6, m, "o-", label="PPO mean")
    ax[0].semilogy(s / 1e6, med, "s--", label="PPO median")
    ax[0].axhline(reach_base["mean_mm"], color="k", ls=":", label=f"go-to-goal law mean ({reach_base['mean_mm']:.2g} mm)")
    ax[0].axhline(8.12, color="r", ls="--", lw=1, label="paper 8.12 mm")
    ax[0].set_xlabel("env steps (M)")
    ax[0].set_ylabel("final distance (mm), 100 held-out episodes")
    ax[0].set_title("reach the point")
    ax[1].semilogy([c["train_minutes"] for c in reach], m, "o-", label="PPO mean")
    ax[1].axhline(8.12, color="r", ls="--", lw=1, label="paper 8.12 mm")
    ax[1].set_xlabel("training wall minutes")
    ax[1].set_title("reach: error against time")
    for name, curve in mazes.items():
        ax[2].plot([c["steps"] / 1e6 for c in curve], [c["success_mean"] for c in curve], "o-", label=f"PPO, {name} distance")
    ax[2].axhline(maze_base["success"], color="k", ls=":", label=f"wall follower ({maze_base['success']:.2f})")
    ax[2].set_xlabel("env steps (M)")
    ax[2].set_ylabel("exit reached (fraction of 100)")
    ax[2].set_title("maze")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
    save_figure(fig, path, dpi=90)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="tiny budgets (a smoke run, not a result)")
    ap.add_argument("--fresh", action="store_true", help="retrain instead of resuming the checkpoints in out/learn")
    ap.add_argument("--reach-steps", type=float, default=4e6)
    ap.add_argument("--maze-steps", type=float, default=1e6)
    ap.add_argument("--every", type=float, default=5e5)
    ap.add_argument("--reach-step-cost", type=float, default=0.0,
                    help="the constant taken off each step of the reach reward in training (the paper's 1)")
    ap.add_argument("--seeds", type=int, default=3, help="training seeds for CartPole and reach (the maze: seed 0)")
    ap.add_argument("--cartpole-steps", type=float, default=5e5, help="CleanRL's CartPole budget (500k)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    q = args.quick
    reach_steps, maze_steps, every = (int(8192 * 2), int(8192 * 2), 8192) if q else \
        (int(args.reach_steps), int(args.maze_steps), int(args.every))
    tag = "quick_" if q else ""
    episodes = 20 if q else 100

    seeds = range(1 if q else args.seeds)
    cps = [cartpole(20_480 if q else int(args.cartpole_steps), seed) for seed in seeds]
    for c in cps:
        del c["history"]
    for c in cps:
        print(f"CartPole-v1, seed {c['seed']}: PPO {c['return_mean']:.1f} +- {c['return_std']:.1f} over 100 episodes "
              f"after {c['steps']} steps ({c['minutes']:.1f} min); published 500 (solved at 475)")
    cp = {"steps": cps[0]["steps"], "minutes": sum(c["minutes"] for c in cps),
          "return_mean": float(np.mean([c["return_mean"] for c in cps])),
          "return_min_seed": float(min(c["return_mean"] for c in cps)),
          "return_std": float(np.mean([c["return_std"] for c in cps])), "published": 500.0, "by_seed": cps}

    (kv, kw), _ = tune(REACH, lambda a, b: (lambda o: go_to_goal(o, a, b)),
                       [(a, b) for a in (1, 2, 4, 8) for b in (2, 4, 8, 16)], lambda r: np.mean(r["distance_m"]))
    base = run_hand(REACH, lambda o: go_to_goal(o, kv, kw), HELD_OUT, episodes)["distance_m"] * 1000
    reach_base = {"k_v": kv, "k_w": kw, "mean_mm": float(base.mean()), "std_mm": float(base.std()),
                  "median_mm": float(np.median(base))}
    # scored in the paper's scenario (the final distance does not depend on the reward)
    cost = args.reach_step_cost
    reach_name = f"{tag}reach" + ("" if cost == 1.0 else f"_cost{cost:g}")
    reaches = {seed: train_and_score(reach_name + (f"_s{seed}" if seed else ""), REACH, reach_steps, every,
                                     {"step_cost": cost}, args.fresh, episodes, "distance_m", seed, eval_params={})[1]
               for seed in seeds}
    picks = {seed: min(curve, key=lambda c: c["validation"]) for seed, curve in reaches.items()}   # early stopping
    by_seed = {seed: float(np.mean(p["values"]) * 1000) for seed, p in picks.items()}
    median_seed = sorted(by_seed, key=by_seed.get)[len(by_seed) // 2]
    reach, pick = reaches[median_seed], picks[median_seed]      # the table and plot: the median seed's run
    pooled = np.concatenate([np.array(p["values"]) * 1000 for p in picks.values()])
    at_end = np.array(reach[-1]["values"]) * 1000
    print(f"\nreach the point, {episodes} held-out episodes (final distance, mm):")
    print(f"{'steps':>10}{'minutes':>9}{'mean':>9}{'std':>9}{'median':>9}{'p95':>9}{'valid.':>9}")
    for c in reach:
        v = np.array(c["values"]) * 1000
        print(f"{c['steps']:>10}{c['train_minutes']:>9.1f}{v.mean():>9.2f}{v.std():>9.2f}{np.median(v):>9.2f}"
              f"{np.percentile(v, 95):>9.2f}{c['validation'] * 1000:>9.2f}{'  <- picked' if c is pick else ''}")
    print(f"{'go-to-goal law (k_v %g, k_w %g)' % (kv, kw):<28}{base.mean():>9.3f}{base.std():>9.3f}"
          f"{np.median(base):>9.3f}{np.percentile(base, 95):>9.3f}")
    print(f"(the table is training seed {median_seed}, the median of {len(by_seed)}; each seed's picked checkpoint: "
          + ", ".join(f"seed {s} {v:.2f} mm at {picks[s]['steps']} steps" for s, v in by_seed.items()) + ")")
    print(f"(trained with step cost {cost:g}; the paper's eq. (5) takes 1)")
    print(f"goal: PPO better than the paper's 8.12 +- 1.23 mm: {pooled.mean():.2f} +- {pooled.std():.2f} mm over the "
          f"{len(by_seed)} seeds' checkpoints picked on validation seeds ({'met' if pooled.mean() < 8.12 else 'NOT met'} "
          f"on the mean; worst seed {max(by_seed.values()):.2f} mm); seed {median_seed} at the end of training "
          f"{at_end.mean():.2f} +- {at_end.std():.2f} mm")

    (gap, kw2), _ = tune(MAZE, lambda a, b: (lambda o: wall_follower(o, a, b)),
                         [(a, b) for a in (0.3, 0.4, 0.5) for b in (1, 2, 4)], lambda r: -np.mean(r["success"]))
    mb = run_hand(MAZE, lambda o: wall_follower(o, gap, kw2), HELD_OUT, episodes)
    maze_base = {"gap_m": gap, "k_w": kw2, "success": float(np.mean(mb["success"])),
                 "steps_mean": float(np.mean(mb["steps"]))}
    mazes = {}
    for rule in ("euclidean", "geodesic"):
        _, mazes[rule] = train_and_score(f"{tag}maze_{rule}", MAZE, maze_steps, max(every // 5, 8192),
                                         {"distance": rule}, args.fresh, episodes, "success")
    print(f"\nmaze, {episodes} held-out episodes: exit reached")
    for rule, curve in mazes.items():
        print(f"  PPO, {rule} distance in the reward: " + ", ".join(
            f"{c['steps'] / 1e6:.1f}M {c['success_mean']:.2f} ({c['steps_mean']:.0f} steps)" for c in curve))
    print(f"  wall follower (gap {gap} m, k_w {kw2}): {maze_base['success']:.2f} ({maze_base['steps_mean']:.0f} steps)")
    geo = mazes["euclidean"][-1]["success_mean"]
    print(f"goal: exit in >= 90 % of episodes (the paper's straight-line rule): {geo:.2f} "
          f"({'met' if geo >= 0.9 else 'NOT met'}); corridor distance: {mazes['geodesic'][-1]['success_mean']:.2f}")

    minutes = sum(r[-1]["train_minutes"] for r in reaches.values()) + sum(c[-1]["train_minutes"] for c in mazes.values())
    png = REPO / "out" / "bench_rl_car.png"
    plot(reach, reach_base, mazes, maze_base, png)
    print(f"wrote {png}; training minutes in all: {minutes:.1f}")
    if args.json:
        strip = lambda curve: [{k: v for k, v in c.items() if k != "values"} for c in curve]  # noqa: E731
        print(json.dumps({"reach_err_mm_mean": float(pooled.mean()), "reach_err_mm_std": float(pooled.std()),
                          "reach_err_mm_median": float(np.median(pooled)), "reach_steps_picked": pick["steps"],
                          "reach_err_mm_is": f"held-out episodes of the checkpoints picked on validation seeds, "
                                             f"pooled over {len(by_seed)} training seeds (before: seed 0 alone)",
                          "reach_err_mm_by_seed": {str(k): v for k, v in by_seed.items()},
                          "reach_err_mm_median_seed": float(np.median(list(by_seed.values()))),
                          "reach_err_mm_worst_seed": float(max(by_seed.values())), "reach_step_cost": cost,
                          "reach_err_mm_mean_seed0": by_seed[0], "reach_median_seed": median_seed,
                          "reach_err_mm_mean_end": float(at_end.mean()), "reach_err_mm_std_end": float(at_end.std()),
                          "maze_success_frac": geo,
                          "maze_success_frac_geodesic": mazes["geodesic"][-1]["success_mean"],
                          "train_minutes": minutes, "cartpole": cp, "reach": {"curve": strip(reach), "baseline": reach_base},
                          "maze": {"curves": {k: strip(v) for k, v in mazes.items()}, "baseline": maze_base}}))


if __name__ == "__main__":
    main()
