"""Swept-path clearance: free travel along straight and curved paths, braking speed, what the camera cannot see."""
from __future__ import annotations

import numpy as np
import pytest

from nodes.nav.clearance import arc_samples, braking_speed_mps, free_distance_m, unseen_mask


def test_point_straight_ahead_limits_the_free_travel_to_its_distance_minus_the_disc():
    free, near = free_distance_m(np.array([[1.0, 0.0]]), 0.8, 0.0, radius_m=0.45)
    assert 0.45 <= free <= 0.55 and near == pytest.approx(1.0)


def test_a_point_the_path_moves_away_from_or_passes_wide_of_does_not_block():
    beside = np.array([[0.0, 0.4], [-0.5, 0.0], [1.5, 0.7]])        # abreast, behind, and wide of the lane
    assert free_distance_m(beside, 0.8, 0.0, radius_m=0.45) == (float("inf"), float("inf"))
    assert free_distance_m(np.zeros((0, 2)), 0.8, 0.0, radius_m=0.45)[0] == float("inf")
    assert free_distance_m(np.array([[np.nan, 0.0]]), 0.8, 0.0, radius_m=0.45)[0] == float("inf")


def test_curving_into_a_point_blocks_where_going_straight_would_not():
    point = np.array([[0.8, 0.8]])
    assert free_distance_m(point, 0.8, 0.0, radius_m=0.45)[0] == float("inf")
    free, _ = free_distance_m(point, 0.8, 1.0, radius_m=0.45)           # radius 0.8 m arc to the left
    assert free < 1.0
    xy, s = arc_samples(0.8, 1.0, 1.0)
    np.testing.assert_allclose(np.hypot(xy[:, 0], xy[:, 1] - 0.8), 0.8, atol=1e-12)   # an exact circle
    assert s[0] == 0.0 and s[-1] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="finite"):
        arc_samples(float("nan"), 0.0, 1.0)


def test_braking_speed_stops_exactly_within_the_free_distance():
    v = braking_speed_mps(0.7, decel_mps2=0.8, latency_s=0.15)
    assert v * 0.15 + v * v / 1.6 == pytest.approx(0.7)
    assert braking_speed_mps(0.0, decel_mps2=0.8, latency_s=0.15) == 0.0
    assert braking_speed_mps(float("inf"), decel_mps2=0.8, latency_s=0.15) == float("inf")
    assert braking_speed_mps(0.7, decel_mps2=0.8, latency_s=0.0) == pytest.approx(np.sqrt(2 * 0.8 * 0.7))


def test_unseen_is_behind_beside_or_too_near_the_camera():
    pts = np.array([[3.0, 0.0], [-1.0, 0.0], [0.3, 1.0], [0.5, 0.0], [2.0, 1.5]])
    assert unseen_mask(pts, camera_x_m=0.3, half_fov_rad=np.radians(65), min_range_m=0.4).tolist() == \
        [False, True, True, True, False]


def _floor_view(hole_cols: slice | None = None, w: int = 64, h: int = 48, f: float = 52.5, cam_z: float = 1.0) -> np.ndarray:
    """Depth (h, w) of a level camera ``cam_z`` above a floor, a wall 5 m ahead above the horizon."""
    rows = (np.arange(h) - (h - 1) / 2.0) / f                    # downward slope of each row's ray
    z = np.where(rows > 0, np.minimum(cam_z / np.maximum(rows, 1e-9), 5.0), 5.0)
    depth = np.repeat(z[:, None], w, axis=1).astype(np.float32)
    if hole_cols is not None:
        depth[:, hole_cols] = 0.0                                # something nearer than the camera can measure
    return depth


def test_depth_rays_reaching_the_floor_clear_a_remembered_point_in_the_near_blind_zone():
    from nodes.nav.clearance import cleared_by_depth
    kw = dict(mount_xyz_m=(0.3, 0.0, 1.0), z_min_m=0.1, z_max_m=2.0, max_range_m=8.0)
    pts = np.array([[0.5, 0.0], [0.5, 2.0], [0.1, 0.0]])        # in the near zone ahead; beside (out of view); behind the camera
    wide = (20.0, 20.0, 31.5, 23.5)                              # fx 20 px: 116 degrees across
    free = cleared_by_depth(pts, _floor_view(f=20.0), *wide, **kw)
    assert free.tolist() == [True, False, False]
    for cols in (slice(30, 34), slice(50, 54)):                  # something in its column, or 0.2 m beside it
        assert not cleared_by_depth(pts[:1], _floor_view(cols, f=20.0), *wide, **kw)[0]
    assert cleared_by_depth(pts[:1], _floor_view(slice(58, 62), f=20.0), *wide, **kw)[0]     # farther beside it
    assert not cleared_by_depth(pts[:1], _floor_view(), 52.5, 52.5, 31.5, 23.5, **kw)[0]     # 0.2 m beside it is out of view
    assert not cleared_by_depth(np.zeros((0, 2)), _floor_view(), *wide, **kw).any()
