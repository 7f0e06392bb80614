"""The social_nav bench's scenarios and human references, shared by bench/social_nav.py and
bench/guard_on_walkers.py: the scenario list, the control tick, when an episode may start (the robot's
start clear of everyone), and the human reference of each scenario (a social-force walker on the paper's
scenes, the recorded walker the robot replaces on the real crowds)."""
from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from sim.crowd import CrowdWorld  # noqa: E402
from sim.crowd_scenes import PedestrianSpec  # noqa: E402
from sim.irl_demos import sim_camera  # noqa: E402
from social_nav_episode import Episode, contact_onsets  # noqa: E402

DT = 1.0 / 15.0
SCENES = ["toward", "crossing", "group", "hallway", "students003", "zara03"]    # sim/scenes/crowd_<name>.yaml
CLEAR_START_S = 2.0       # an episode starts once the robot's start stays clear of everyone for this long
CLEAR_M = 0.75            # ... clear: no pedestrian centre nearer (bodies 0.35 + 0.3 m, and 0.1 m)


def clear_start_s(scene, window_s: float = CLEAR_START_S, clear_m: float = CLEAR_M, max_shift_s: float = 15.0) -> float:
    """How long the crowd must walk before the robot's start stays clear of every pedestrian for ``window_s``.

    Replayed companions of the walker the robot replaces, or a group heading for the start,
    walked into a robot that had not moved yet (issue 22): instead of excusing those contacts the
    episode starts later, when nobody would reach the standing robot within ``window_s``.
    The crowd is probed without the robot (nobody sees it)."""
    far = (scene.bounds_m[0] - 100.0, scene.bounds_m[1] - 100.0, 0.0)
    probe = CrowdWorld(dataclasses.replace(scene, robot_start=far), camera=sim_camera())
    (sx, sy, _) = scene.robot_start
    near = []
    while probe.t_s <= max_shift_s + window_s:
        p = probe.pedestrians()
        near.append(bool(len(p.ids)) and float(np.hypot(p.xy_m[:, 0] - sx, p.xy_m[:, 1] - sy).min()) < clear_m)
        probe.advance_crowd(DT)
    near = np.array(near)
    w = int(round(window_s / DT))
    for k in range(0, int(round(max_shift_s / DT)) + 1, 3):
        if not near[k:k + w + 1].any():
            return k * DT
    return max_shift_s


def _yaw_rate(xy: np.ndarray, dt: float) -> np.ndarray:
    v = np.gradient(xy, dt, axis=0)
    heading = np.unwrap(np.arctan2(v[:, 1], v[:, 0]))
    rate = np.gradient(heading, dt)
    rate[np.hypot(v[:, 0], v[:, 1]) < 0.2] = 0.0          # standing still: no heading
    return np.convolve(rate, np.ones(3) / 3, mode="same")


def human_walker(scene, max_s: float, shift_s: float = 0.0) -> Episode:
    """A social-force pedestrian sent from the robot's start to its goal at the robot's top speed.

    It heads for the goal, then for a point 1 m beyond it (a walker halts short of a 'stop' goal); it has
    arrived when it passes within the goal tolerance. The crowd treats it as it treats the
    robot: where the scene's pedestrians do not see the robot they do not make way for the
    reference either (it still avoids them), or the reference would be given a path the robot
    never is.
    """
    (sx, sy, _), (gx, gy, tol) = scene.robot_start, scene.goal
    direction = np.array([gx - sx, gy - sy]) / max(np.hypot(gx - sx, gy - sy), 1e-9)
    beyond = np.array([gx, gy]) + direction
    walker = PedestrianSpec(id=999, waypoints=np.array([[sx, sy], [gx, gy], beyond]), speed_mps=1.0,
                            unseen=not scene.pedestrians_see_robot, start_s=max(shift_s - 1e-6, 0.0))
    # (a hair early: the crowd's clock after stepping shift_s may read a rounding below it, and the walker
    # would not be there yet)
    far = (scene.bounds_m[0] - 100.0, scene.bounds_m[1] - 100.0, 0.0)
    world = CrowdWorld(dataclasses.replace(scene, pedestrians=scene.pedestrians + (walker,), robot_start=far),
                       camera=sim_camera())
    ts, xy, peds, goal_t = [], [], [], None
    if shift_s > 0:
        world.step(0.0, 0.0, shift_s)
    while world.t_s - shift_s <= max_s:
        p = world.pedestrians()
        me = p.ids == 999
        ts.append(world.t_s - shift_s), xy.append(p.xy_m[me][0]), peds.append((p.ids[~me], p.xy_m[~me]))
        if np.hypot(xy[-1][0] - gx, xy[-1][1] - gy) <= tol:
            goal_t = ts[-1]
            break
        world.step(0.0, 0.0, DT)
    xy_a = np.array(xy)
    onsets = contact_onsets(np.array(ts), xy_a, np.gradient(xy_a, DT, axis=0), peds)
    return Episode(np.array(ts), np.column_stack([xy_a, np.zeros(len(xy_a))]), _yaw_rate(xy_a, DT), peds, goal_t,
                   len(onsets), by_robot=sum(b for *_, b in onsets))


def pick_reference(tracks, max_mean_mps: float = 1.0, min_len_m: float = 8.0) -> int:
    """The pedestrian (index) at wheelchair pace that walks far through the most company.

    How the real-crowd scenes (``sim/scenes/crowd_students003.yaml``, ``crowd_zara03.yaml``)
    chose the walker whose place the robot takes (their ``replay.exclude_ids``).
    """
    best, best_n = -1, -1
    for i, (t, xy) in enumerate(zip(tracks.t_s, tracks.xy_m)):
        if len(t) < 5:
            continue
        length = float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))
        mean = length / (t[-1] - t[0])
        if np.hypot(*(xy[-1] - xy[0])) < min_len_m or not 0.6 <= mean <= max_mean_mps:
            continue
        n = 0
        for tk, p in zip(t, xy):
            ids, pos, _ = tracks.state_at(tk)
            n += int(np.sum((np.hypot(*(pos - p).T) < 3.0) & (ids != tracks.ids[i])))
        if n > best_n:
            best, best_n = i, n
    if best < 0:
        raise ValueError(f"{tracks.name}: no pedestrian walks {min_len_m} m at 0.6-{max_mean_mps} m/s")
    return best


def replay_reference(scene) -> Episode:
    """The human reference of a real-crowd scene: the recorded walk of the pedestrian the robot replaces
    (``replay.exclude_ids[0]``) among the others. Contacts at 0.6 m (two people's radii)."""
    from sim.pedestrian_data import load_tracks

    rep = scene.replay
    if rep is None or not rep.exclude_ids:
        raise ValueError(f"scene {scene.name!r} replays no crowd with a left-out walker (replay.exclude_ids)")
    tracks = load_tracks(rep.dataset)
    i = int(np.flatnonzero(tracks.ids == rep.exclude_ids[0])[0])
    t, xy = tracks.t_s[i] - rep.t0_s, rep.to_world(tracks.xy_m[i])
    tt = np.arange(max(t[0], 0.0), t[-1] + 1e-9, DT)
    hx = np.column_stack([np.interp(tt, t, xy[:, 0]), np.interp(tt, t, xy[:, 1])])
    world = CrowdWorld(scene, tracks=tracks, camera=sim_camera())
    peds = []
    for tk in tt:
        world.walkers.t_s = tk
        ids, pos, *_ = world.walkers.replayed()
        peds.append((ids, pos))
    gx, gy, tol = scene.goal
    goal_k = int(np.argmax(np.hypot(hx[:, 0] - gx, hx[:, 1] - gy) <= tol))
    n = goal_k + 1
    onsets = contact_onsets(tt[:n], hx[:n], np.gradient(hx, DT, axis=0)[:n], peds[:n], radius_m=0.6)
    return Episode(tt[:n], np.column_stack([hx, np.zeros(len(tt))])[:n], _yaw_rate(hx, DT)[:n], peds[:n], float(tt[goal_k]),
                   len(onsets), by_robot=sum(b for *_, b in onsets))


def human_reference(scene, shift_s: float = 0.0) -> Episode:
    """The recorded walker on a real crowd (its own walk, from its own start), a social-force walker on a
    synthetic scene (sent when the robot is: ``shift_s``)."""
    return replay_reference(scene) if scene.replay is not None else human_walker(scene, scene.duration_s, shift_s)
