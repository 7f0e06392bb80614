"""Feature-expectation matching of the conflict price with the planner in the loop (sim.irl_match)."""
import json

import numpy as np
import pytest

from nodes.nav.irl_cost import DEFAULT_WEIGHTS
from sim.irl_match import (ENCOUNTER_M, ReactiveCrowd, Walk, bootstrap_prices, crowd_drift, human_among_reactive,
                           human_encounters, loso_prices, match_price, pick_walks, replace_walker, weights_with_price)
from sim.pedestrian_data import Tracks

CROSS_T = 4.6          # the crosser is on the robot's line (x = 4) when a robot driving straight at 1 m/s gets there


def _crossing(demonstrator_waits: bool) -> Tracks:
    """Walker 1 goes (0, 0) -> (8, 0); walker 2 crosses x = 4 northward at 1 m/s, at y = 0 at ``CROSS_T``.
    A waiting demonstrator stops at x = 2.5 until the crosser is 1.5 m past, keeping its distance."""
    t = np.arange(0.0, 20.01, 0.4)
    if demonstrator_waits:
        x = np.interp(t, [0.0, 2.5, CROSS_T + 1.5, CROSS_T + 7.0], [0.0, 2.5, 2.5, 8.0])
        t1 = t[t <= CROSS_T + 7.0]
    else:
        t1 = t[t <= 8.0]
        x = t1
    demo = np.column_stack([x[:len(t1)], np.zeros(len(t1))])
    cross = np.column_stack([np.full(len(t), 4.0), t - CROSS_T])
    return Tracks("synth", np.array([1, 2]), (t1, t), (demo, cross), 0.4, 1.0)


@pytest.fixture(scope="module")
def price_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("w")
    return {p: weights_with_price(DEFAULT_WEIGHTS, p, d / f"w_{p}.json") for p in (0.1, 4.0, 40.0)}


def test_matched_price_moves_the_planner_toward_a_demonstrator_who_keeps_his_distance(price_files, tmp_path):
    tracks = _crossing(demonstrator_waits=True)
    walk = Walk("synth", 1, tracks.t_s[0], tracks.xy_m[0])
    human = human_encounters(tracks, walk)
    assert human.rate == 0.0 and human.closest_m > 1.0
    prices = np.array([0.1, 4.0])
    rates = np.array([replace_walker(tracks, walk, price_files[p]).rate for p in prices])
    assert rates[0] > human.rate                         # a cheap conflict: the planner drives into the crosser
    m = match_price(prices, rates, human.rate)
    assert m.censored == "" and m.price > prices[0]
    at = replace_walker(tracks, walk, weights_with_price(DEFAULT_WEIGHTS, m.price, tmp_path / "m.json"))
    assert abs(at.rate - human.rate) < abs(rates[0] - human.rate)
    assert at.closest_m >= ENCOUNTER_M


def test_encounters_fall_as_the_conflict_gets_dearer(price_files):
    tracks = _crossing(demonstrator_waits=False)
    walk = Walk("synth", 1, tracks.t_s[0], tracks.xy_m[0])
    runs = [replace_walker(tracks, walk, price_files[p]) for p in (0.1, 4.0, 40.0)]
    rates = [r.rate for r in runs]
    assert rates[0] > 0 and all(a >= b for a, b in zip(rates, rates[1:]))
    assert all(r.reached for r in runs)
    assert runs[0].time_s <= runs[-1].time_s            # avoiding by timing costs time


def test_match_price_interpolates_in_log_price_and_censors_the_ends():
    prices = np.array([0.1, 1.0, 10.0])
    assert match_price(prices, np.array([0.4, 0.2, 0.0]), 0.1).price == pytest.approx(np.sqrt(10.0))
    # a wiggle up at a dearer price is noise: the curve is made non-increasing first
    assert match_price(prices, np.array([0.4, 0.1, 0.3]), 0.2).price == pytest.approx(10 ** (-1 / 3))
    assert match_price(prices, np.array([0.4, 0.2, 0.1]), 0.05) == match_price(prices, np.array([0.4, 0.2, 0.1]), 0.0)
    assert match_price(prices, np.array([0.4, 0.2, 0.1]), 0.05).censored == "above"
    assert match_price(prices, np.array([0.4, 0.2, 0.1]), 0.5).censored == "below"
    with pytest.raises(ValueError, match="increasing"):
        match_price(prices[::-1], np.array([0.4, 0.2, 0.1]), 0.1)
    with pytest.raises(ValueError, match="one planner feature per price"):
        match_price(prices, np.array([0.4, 0.2]), 0.1)


def test_demonstrations_from_one_scene_only():
    rng = np.random.default_rng(3)
    prices = np.geomspace(0.1, 40.0, 6)
    planner = np.clip(0.3 - 0.05 * np.log(prices) + rng.normal(0, 0.02, (15, 6)), 0, None)
    human = np.full(15, 0.2)
    with pytest.raises(ValueError, match="needs >= 2 scenes"):
        loso_prices(prices, {"biwi_hotel": (planner, human)})
    m = match_price(prices, planner.mean(0), float(human.mean()))          # one scene still gives a price ...
    boot = bootstrap_prices(prices, planner, human, n_boot=200, seed=0)   # ... and a walker bootstrap interval
    assert boot.min() <= m.price <= boot.max() and boot.max() > boot.min()
    two = loso_prices(prices, {"a": (planner[:7], human[:7]), "b": (planner[7:], human[7:])})
    assert set(two) == {"a", "b"}


def test_walkers_whose_tracks_have_gaps():
    t = np.arange(0.0, 12.01, 0.4)
    walker = np.column_stack([t, np.zeros(len(t))])
    seen = (t < 6.0) | (t > 9.0)                     # walker 1 is out of sight for 3 s, then seen again
    other_t = np.array([0.0, 2.0, 8.0, 10.0])        # walker 2 is unseen 2-8 s; a straight line would cross walker 1
    other = np.array([[4.0, -6.0], [4.0, -4.0], [4.0, 8.0], [4.0, 10.0]])   # bridged: at (4, 0) at t = 4 s, as walker 1
    gappy = Tracks("gaps", np.array([1, 2]), (t[seen], other_t), (walker[seen], other), 0.4, 1.0)
    walks = pick_walks(gappy, 5, window_s=10.0, min_len_m=3.0, min_s=3.0)
    w1 = next(w for w in walks if w.pid == 1)
    assert w1.t_s[-1] < 6.0                           # the stretch ends where the walker went out of sight
    assert human_encounters(gappy, w1).rate == 0.0    # nobody is slid through the crowd on a line never walked
    bridged = Tracks("gaps", gappy.ids, gappy.t_s, gappy.xy_m, 0.4)       # the same data, every gap bridged
    assert human_encounters(bridged, Walk("gaps", 1, w1.t_s, w1.xy_m)).rate > 0.0


def test_weights_with_price_says_what_to_do(tmp_path):
    out = weights_with_price(DEFAULT_WEIGHTS, 1.5, tmp_path / "w.json")
    data = json.loads(out.read_text())
    assert data["weights"][data["names"].index("conflict")] == 1.5
    bare = tmp_path / "bare.json"
    bare.write_text(json.dumps({"names": ["density_high"], "weights": [1.0], "step_cost": 1.0}))
    with pytest.raises(ValueError, match="conflict feature"):
        weights_with_price(bare, 1.0, tmp_path / "x.json")
    with pytest.raises(ValueError, match="finite"):
        weights_with_price(DEFAULT_WEIGHTS, -1.0, tmp_path / "x.json")


# --- the reactive crowd (ReactiveCrowd: the others as social-force agents seeded from their tracks) ---

def _line(pid_speed_y: list[tuple[int, float, float]], t_end: float = 12.0, x0: float = 0.0) -> Tracks:
    """Walkers going +x along y = const at constant speeds, sampled every 0.4 s."""
    t = np.arange(0.0, t_end + 1e-9, 0.4)
    ids = np.array([p for p, _, _ in pid_speed_y])
    xy = tuple(np.column_stack([x0 + v * t, np.full(len(t), y)]) for _, v, y in pid_speed_y)
    return Tracks("line", ids, tuple(t for _ in ids), xy, 0.4, 1.0)


def _closest_to(crowd, point, pid, dt=1 / 15, n=150, robot=None):
    out, drift = np.inf, []
    for _ in range(n):
        ids, pos, _ = crowd.state()
        if pid in ids:
            out = min(out, float(np.hypot(*(pos[list(ids).index(pid)] - point))))
        drift.append(crowd.drift())
        crowd.step(dt, robot)
    return out, np.concatenate(drift)


def test_a_reactive_walker_steps_aside_from_a_robot_standing_on_its_path_a_replayed_one_walks_through_it():
    tracks = _line([(7, 1.0, 0.0)])                     # walker 7 walks x = t along y = 0 ...
    robot = (4.0, 0.0, 0.0, 0.0, 0.35)                   # ... where a robot stands at x = 4
    replayed = min(float(np.hypot(*(tracks.state_at(t)[1][0] - robot[:2]))) for t in np.arange(0, 10, 1 / 15))
    assert replayed < 0.05                               # the recording walks through it
    crowd = ReactiveCrowd(tracks, 0.0, 10.0)
    closest, _ = _closest_to(crowd, np.array(robot[:2]), 7, robot=robot)
    assert closest > 0.5                                 # the reactive walker makes way
    nobody, drift = _closest_to(ReactiveCrowd(tracks, 0.0, 10.0), np.array(robot[:2]), 7)
    assert nobody < 0.1 and drift.max() < 0.05          # with nobody there it keeps to its track
    back = ReactiveCrowd(_line([(7, 1.0, 0.0)], t_end=16.0), 0.0, 15.0)
    _closest_to(back, np.array(robot[:2]), 7, n=75, robot=robot)     # held up by the robot until t = 5 s ...
    late = back.drift().max()
    _closest_to(back, np.array(robot[:2]), 7, n=120)
    assert late > 1.0 and back.drift().max() < 0.1      # ... it catches up with its recorded track 8 s later


def test_reactive_walkers_start_as_recorded_leave_when_their_track_ends_and_a_gap_is_two_agents():
    t = np.arange(0.0, 10.01, 0.4)
    a = np.column_stack([1.2 * t, np.zeros(len(t))])
    late = t >= 2.0                                           # walker 2 first seen at 2 s, last at 6 s
    seen = (t >= 2.0) & (t <= 6.0)
    b = np.column_stack([np.zeros(len(t)), 5.0 + 0.8 * t])
    gap = (t < 3.0) | (t > 6.5)                               # walker 3 out of sight 3-6.5 s
    c = np.column_stack([-5.0 + 0.5 * t, np.full(len(t), 10.0)])
    tracks = Tracks("enter", np.array([1, 2, 3]), (t, t[seen], t[gap]), (a, b[seen], c[gap]), 0.4, 1.0)
    crowd = ReactiveCrowd(tracks, 1.0, 8.0)
    ids, pos, vel = crowd.state()
    assert sorted(ids) == [1, 3]
    assert np.allclose(pos[list(ids).index(1)], [1.2, 0.0]) and np.allclose(vel[list(ids).index(1)], [1.2, 0.0])
    seen_at = {}
    for _ in range(int(7.5 * 15)):
        crowd.step(1 / 15)
        ids, pos, vel = crowd.state()
        for i in ids:
            seen_at.setdefault(int(i), []).append(round(crowd.t_s + 1.0, 3))
    assert 1.95 <= min(seen_at[2]) <= 2.1 and 5.9 <= max(seen_at[2]) <= 6.1     # data time, as recorded
    t3 = np.array(seen_at[3])
    assert not np.any((t3 > 3.1) & (t3 < 6.4))                                    # absent in its gap
    assert len(crowd.pids) == 4 and list(crowd.pids).count(3) == 2                # one agent per stretch
    assert late.any()


def test_the_reactive_crowd_is_seeded():
    tracks = _line([(1, 1.0, 0.0), (2, 1.2, 0.7), (3, 0.9, -0.6)])
    runs = []
    for _ in range(2):
        crowd = ReactiveCrowd(tracks, 0.5, 6.0)
        for _ in range(60):
            crowd.step(1 / 15, (3.0, 0.2, 0.0, 0.0, 0.35))
        runs.append(crowd.state()[1])
    assert np.array_equal(runs[0], runs[1])
    with pytest.raises(ValueError, match="must be > 0"):
        ReactiveCrowd(tracks, 0.0, 5.0, lookahead_s=0.0)


def test_a_demonstrator_walking_into_a_reactive_walker_is_avoided_by_it():
    t = np.arange(0.0, 10.01, 0.4)
    demo = np.column_stack([t, np.zeros(len(t))])                # 0 -> 10 m along y = 0
    other = np.column_stack([10.0 - t, np.full(len(t), 0.1)])    # head-on, 0.1 m off his line
    tracks = Tracks("headon", np.array([1, 2]), (t, t), (demo, other), 0.4, 1.0)
    walk = Walk("headon", 1, t, demo)
    recorded = human_encounters(tracks, walk)
    reactive, drift = human_among_reactive(tracks, walk)
    assert recorded.rate > 0 and recorded.closest_m < 0.2
    assert reactive.rate == 0.0 and reactive.closest_m >= ENCOUNTER_M
    assert drift.max() > ENCOUNTER_M
    alone = crowd_drift(tracks, walk)
    assert alone.max() < 0.05                                   # with nobody in his place it walks as recorded


def test_real_reactive_crowd_follows_its_tracks_with_nobody_in_the_walkers_place():
    from sim.pedestrian_data import load_tracks
    try:
        tracks = load_tracks("biwi_hotel")
    except FileNotFoundError:
        pytest.skip("ETH/UCY tracks not in ../shared/data/pedestrians")
    walks = pick_walks(tracks, 6, seed=1)
    drift = np.concatenate([crowd_drift(tracks, w) for w in walks])
    assert len(drift) > 100
    assert np.median(drift) < 0.3 and np.percentile(drift, 90) < 0.8


def test_a_reactive_crosser_keeps_farther_from_the_planner_than_a_replayed_one(price_files):
    tracks = _crossing(demonstrator_waits=False)        # a cheap conflict: the planner drives into the crosser ...
    walk = Walk("synth", 1, tracks.t_s[0], tracks.xy_m[0])
    replayed = replace_walker(tracks, walk, price_files[0.1])
    reactive = replace_walker(tracks, walk, price_files[0.1], reactive={})
    assert replayed.rate > 0 and replayed.closest_m < 0.15
    assert reactive.closest_m > replayed.closest_m + 0.15                 # ... who makes some way
    assert reactive.reached
