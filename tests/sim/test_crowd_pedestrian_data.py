"""Real pedestrian tracks: parsing, interpolation, the biwi_eth frame period (SOURCES.md)."""
from __future__ import annotations

import numpy as np
import pytest

from sim.crowd import CrowdWorld
from sim.pedestrian_data import ROW_PERIOD_S, Tracks, load_tracks, parse_tracks


def test_parse_and_interpolate_a_synthetic_table():
    table = np.array([[0, 1, 0.0, 0.0], [10, 1, 1.0, 0.0], [20, 1, 2.0, 0.0], [10, 2, 5.0, 5.0]], float)
    tr = parse_tracks(table, name="x", row_period_s=0.4)
    assert list(tr.ids) == [1, 2] and tr.duration_s == pytest.approx(0.8)
    ids, xy, vel = tr.state_at(0.6)
    assert list(ids) == [1]
    np.testing.assert_allclose(xy[0], [1.5, 0.0])
    np.testing.assert_allclose(vel[0], [2.5, 0.0])
    ids, xy, vel = tr.state_at(0.4)                       # a single-sample track is present at its instant
    assert list(ids) == [1, 2] and np.all(vel[1] == 0)
    assert len(tr.state_at(5.0)[0]) == 0
    with pytest.raises(ValueError, match="frame ped_id x y"):
        parse_tracks(np.zeros((3, 3)), name="x", row_period_s=0.4)


def test_unknown_data_set_and_missing_data_are_clear_errors(tmp_path):
    with pytest.raises(ValueError, match="students003"):
        load_tracks("nope")
    with pytest.raises(FileNotFoundError, match="TETHER_SHARED_DATA"):
        load_tracks("biwi_eth", root=tmp_path)


def test_biwi_eth_uses_its_own_frame_period(shared_data):
    root = shared_data / "pedestrians"
    assert ROW_PERIOD_S["biwi_eth"] == pytest.approx(0.6667, abs=1e-3)
    eth = load_tracks("biwi_eth", root=root)
    assert np.median(eth.speeds_mps()) == pytest.approx(1.47, abs=0.05)      # not the false 2.45 m/s
    students = load_tracks("students003", root=root)
    assert 0.5 < np.median(students.speeds_mps()) < 1.5
    ids, xy, _ = students.state_at(40.0)
    assert len(ids) > 20 and np.all(np.isfinite(xy))


def test_replay_scene_moves_real_pedestrians_through_the_world(shared_data):
    tracks = load_tracks("students003", root=shared_data / "pedestrians")
    world = CrowdWorld("students", tracks=tracks)
    first = world.pedestrians()
    world.step(0.0, 0.0, 1.0)
    second = world.pedestrians()
    assert len(first.ids) > 20 and np.all(first.ids >= 10000)
    common = np.intersect1d(first.ids, second.ids)
    moved = [np.linalg.norm(second.xy_m[second.ids == i] - first.xy_m[first.ids == i]) for i in common]
    assert 0.3 < np.median(moved) < 2.0                   # about walking speed over 1 s


def test_replay_with_synthetic_tracks_applies_the_scene_transform():
    tr = Tracks("synthetic", np.array([7]), (np.array([0.0, 10.0]),), (np.array([[0.0, 0.0], [10.0, 0.0]]),), 0.4)
    scene = {"name": "r", "bounds_m": [-20, -20, 20, 20], "replay": {"dataset": "biwi_eth", "t0_s": 2.0,
                                                                     "x_m": 1.0, "y_m": 0.0, "yaw_rad": 1.5707963}}
    world = CrowdWorld(scene, tracks=tr)
    peds = world.pedestrians()
    np.testing.assert_allclose(peds.xy_m, [[1.0, 2.0]], atol=1e-6)          # (2, 0) rotated 90 deg, shifted
    np.testing.assert_allclose(peds.vel_mps, [[0.0, 1.0]], atol=1e-6)
    assert list(peds.ids) == [10007]


def test_a_walker_out_of_sight_is_absent_and_demonstrates_each_gapless_piece_alone():
    """Hard case: real walkers whose tracks have gaps (an annotator lost them for seconds)."""
    from sim.irl_demos import _expert_tracks

    rows = [[f, 1, 0.1 * f, 0.0] for f in range(0, 130, 10)]                  # 0 .. 4.8 s, 1.2 m/s ...
    rows += [[f, 1, 0.1 * f, 3.0] for f in range(230, 400, 10)]               # ... 4 s unseen, then 8.8 .. 15.6 s
    rows += [[f, 2, 5.0, 0.0] for f in range(0, 400, 20)]                      # a skipped row (0.8 s) is bridged
    tr = parse_tracks(np.array(rows, float), name="x", row_period_s=0.4)
    assert tr.max_gap_s == pytest.approx(1.0)
    assert 1 not in tr.state_at(6.0)[0]                  # inside the gap: not slid along a line never walked
    assert 2 in tr.state_at(6.2)[0]                      # between two samples 0.8 s apart: still there
    ids, xy, _ = tr.state_at(10.0)
    np.testing.assert_allclose(xy[list(ids).index(1)], [25.0, 3.0])
    pieces = tr.segments(0)
    assert [len(t) for t, _ in pieces] == [13, 17] and pieces[1][0][0] == pytest.approx(9.2)
    assert len(tr.segments(1)) == 1
    walks = _expert_tracks(tr, 4.0, 4.0)
    assert (0, 0) in walks and (0, 1) in walks            # each piece a walk of its own, none across the gap
