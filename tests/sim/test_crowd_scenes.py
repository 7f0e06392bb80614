"""Crowd scenes: bundled files load and are sane, the map rasterises them, pedestrians behave."""
from __future__ import annotations

import numpy as np
import pytest

from sim.crowd_scenes import Walkers, load_scene, occupancy_grid, scene_names, segment_distances

ROOM = [{"points": [[-5, -5], [5, -5], [5, 5], [-5, 5], [-5, -5]], "height_m": 2.5}]


def scene(**kw):
    data = {"name": "t", "bounds_m": [-5, -5, 5, 5], "walls": ROOM, "pedestrian_model": "social_force"}
    data.update(kw)
    return load_scene(data)


def test_the_paper_scenarios_and_the_hallway_are_bundled_and_sane():
    names = scene_names()
    assert {"toward", "crossing", "group", "hallway"} <= set(names)
    for name in ("toward", "crossing", "group", "hallway"):
        sc = load_scene(name)
        x0, y0, x1, y1 = sc.bounds_m
        assert x0 < sc.goal[0] < x1 and y0 < sc.goal[1] < y1
        start = np.array([sc.robot_start[:2]])
        assert segment_distances(start, sc.segments).min() > 0.5        # the robot starts clear of walls
        assert len(sc.pedestrians) >= 1
    assert len(load_scene("group").pedestrians) == 4
    hall = load_scene("hallway")
    assert len(hall.polygons) >= 2 and len(hall.cylinders) >= 2 and len(hall.pedestrians) >= 10


def test_occupancy_grid_marks_walls_and_fills_boxes_but_not_free_space():
    sc = scene(obstacles=[{"box": {"x_m": 1.0, "y_m": 1.0, "length_m": 1.0, "width_m": 1.0}, "height_m": 1.0},
                          {"cylinder": {"x_m": -2.0, "y_m": -2.0, "radius_m": 0.5}, "height_m": 2.0}])
    grid = occupancy_grid(sc, 0.1)
    assert grid.data.shape == (100, 100)

    def at(x, y):
        c = int(round((x - grid.origin_x_m) / grid.resolution_m))
        r = int(round((y - grid.origin_y_m) / grid.resolution_m))
        return grid.data[r, c]

    assert at(-4.95, 0.0) == 1 and at(0.0, 4.95) == 1          # boundary walls
    assert at(1.0, 1.0) == 1 and at(1.4, 0.6) == 1             # inside the box
    assert at(-2.0, -2.0) == 1 and at(-2.35, -2.0) == 1        # inside the pillar
    assert at(0.0, -2.5) == 0 and at(3.0, 3.0) == 0


def test_bad_scenes_say_what_to_fix():
    with pytest.raises(ValueError, match="bundled scenes"):
        load_scene("no_such_scene")
    with pytest.raises(ValueError, match="at_goal"):
        scene(pedestrians=[{"id": 1, "waypoints": [[0, 0], [1, 0]], "at_goal": "vanish"}])
    with pytest.raises(ValueError, match="unique"):
        scene(pedestrians=[{"id": 1, "waypoints": [[0, 0]]}, {"id": 1, "waypoints": [[1, 0]]}])
    with pytest.raises(ValueError, match="box"):
        scene(obstacles=[{"cone": {}}])


def run(walkers, seconds, dt=0.05, robot=None):
    track = []
    for k in range(int(round(seconds / dt))):
        walkers.step(k * dt, dt, robot)
        track.append(walkers.state())
    return track


def test_two_pedestrians_head_on_pass_each_other_without_contact():
    sc = scene(pedestrians=[{"id": 1, "waypoints": [[-4, 0.0], [4, 0.0]], "speed_mps": 1.2},
                            {"id": 2, "waypoints": [[4, 0.05], [-4, 0.05]], "speed_mps": 1.2}])
    track = run(Walkers(sc), 10.0)
    gaps = [np.linalg.norm(s[1][0] - s[1][1]) for s in track]
    assert min(gaps) > 0.45                 # they swerve (radii sum 0.6; some squeezing allowed)
    final = track[-1][1]
    assert final[0, 0] > 3.0 and final[1, 0] < -3.0       # and still get where they were going


def test_nobody_makes_way_for_an_unseen_pedestrian_who_still_avoids_them():
    a = {"id": 1, "waypoints": [[-4, 0.0], [4, 0.0]], "speed_mps": 1.2}
    b = {"id": 2, "waypoints": [[4, 0.05], [-4, 0.05]], "speed_mps": 1.2, "unseen": True}
    alone = run(Walkers(scene(pedestrians=[a])), 6.0)
    both = run(Walkers(scene(pedestrians=[a, b])), 6.0)
    # pedestrian 1 walks exactly as if 2 were not there; 2 swerves around 1 and gets past
    np.testing.assert_allclose([s[1][0] for s in both], [s[1][0] for s in alone], atol=1e-12)
    assert max(abs(s[1][1, 1] - 0.05) for s in both) > 0.2
    assert min(np.linalg.norm(s[1][0] - s[1][1]) for s in both) > 0.4
    assert both[-1][1][1, 0] < -2.0


def test_pedestrian_does_not_walk_through_a_wall_and_a_standing_one_never_moves():
    sc = scene(pedestrians=[{"id": 1, "waypoints": [[0, 0], [0, 8]], "speed_mps": 1.2},
                            {"id": 2, "waypoints": [[2, 2]], "speed_mps": 0}])
    track = run(Walkers(sc), 12.0)
    ys = [s[1][0, 1] for s in track]
    assert max(ys) < 5.0 - 0.2
    assert all(np.array_equal(s[1][1], [2.0, 2.0]) for s in track)
    assert all(np.array_equal(s[2][1], [0.0, 0.0]) for s in track)


def test_linear_model_is_exact_and_start_time_respawn_and_loop_work():
    sc = scene(pedestrian_model="linear", pedestrians=[
        {"id": 1, "waypoints": [[-4, 0], [0, 0]], "speed_mps": 1.0, "start_s": 1.0, "at_goal": "respawn"},
        {"id": 2, "waypoints": [[0, -4], [0, -2]], "speed_mps": 1.0, "at_goal": "loop"}])
    w = Walkers(sc)
    assert list(w.state()[0]) == [2]                    # pedestrian 1 appears at t = 1 s
    run(w, 3.0, dt=0.1)
    ids, xy, vel = w.state()[:3]
    np.testing.assert_allclose(xy[ids == 1][0], [-2.0, 0.0], atol=0.11)
    np.testing.assert_allclose(vel[ids == 1][0], [1.0, 0.0], atol=1e-9)
    assert xy[ids == 2][0, 1] < -2.5                     # reached (0, -2) at t = 2 s, now walking back
    w2 = Walkers(sc)
    for k in range(60):
        w2.step(k * 0.1, 0.1, None)
    assert w2.state()[1][w2.state()[0] == 1][0, 0] < -1.0   # respawned at the start after reaching (0, 0)


def test_pedestrians_that_see_the_robot_keep_away_from_it():
    sc = scene(pedestrians=[{"id": 1, "waypoints": [[-4, 0.0], [4, 0.0]], "speed_mps": 1.0}])
    blind = run(Walkers(sc), 8.0)
    seeing = run(Walkers(sc), 8.0, robot=(0.0, 0.0, 0.0, 0.0, 0.35))
    gap = lambda track: min(np.linalg.norm(s[1][0]) for s in track)   # noqa: E731
    assert gap(blind) < 0.1 and gap(seeing) > 0.6
