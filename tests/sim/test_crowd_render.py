"""Crowd renderer: depth geometry against closed-form projections, occlusion, texture, hard cases."""
from __future__ import annotations

import numpy as np
import pytest

from sim.crowd_render import CameraModel, Renderer

CAM = CameraModel(width_px=160, height_px=120, fx_px=131.25, fy_px=131.25, cx_px=79.5, cy_px=59.5,
                  x_m=0.3, z_m=1.0, max_range_m=8.0)


def wall_at(x: float, height: float = 2.5) -> tuple[np.ndarray, np.ndarray]:
    return np.array([[[x, -20.0], [x, 20.0]]]), np.array([height])


def renderer(segs=None, heights=None, cyl=None, cyl_h=None, obstacle=None, camera=CAM) -> Renderer:
    segs = np.zeros((0, 2, 2)) if segs is None else segs
    heights = np.zeros(0) if heights is None else heights
    cyl = np.zeros((0, 3)) if cyl is None else cyl
    cyl_h = np.zeros(0) if cyl_h is None else cyl_h
    return Renderer(segs, heights, cyl, cyl_h, obstacle=obstacle, camera=camera)


def test_wall_depth_is_forward_distance_on_every_row_and_floor_follows_projection():
    segs, h = wall_at(5.0)
    rgb, depth = renderer(segs, h).render((0.0, 0.0, 0.0))
    assert rgb.shape == (120, 160, 3) and rgb.dtype == np.uint8 and depth.dtype == np.float32
    # rows whose floor point is farther than the wall see the wall: depth 4.7 m on every column (planar wall)
    floor_row_at_wall = CAM.cy_px + CAM.fy_px * CAM.z_m / 4.7
    wall_rows = np.arange(int(CAM.cy_px - CAM.fy_px * 1.5 / 4.7) + 1, int(floor_row_at_wall))
    np.testing.assert_allclose(depth[wall_rows], 4.7, atol=1e-4)
    # floor rows: depth = z_cam * fy / (v - cy)
    for v in (100, 119):
        np.testing.assert_allclose(depth[v], CAM.z_m * CAM.fy_px / (v - CAM.cy_px), rtol=1e-5)
    # above the wall top: sky, no return
    assert np.all(depth[0] == 0)


def test_yaw_turns_the_view():
    segs, h = wall_at(5.0)
    r = renderer(segs, h)
    _, straight = r.render((0.0, 0.0, 0.0))
    _, turned = r.render((0.0, 0.0, np.pi))       # looking away: wall behind, nothing in front
    assert straight[50, 80] == pytest.approx(4.7, abs=1e-4)
    assert turned[50, 80] == 0.0


def test_pedestrian_cylinder_depth_extent_and_occlusion_of_the_wall_behind():
    segs, h = wall_at(6.0, height=3.0)
    r = renderer(segs, h)
    _, depth = r.render((0.0, 0.0, 0.0), np.array([[3.0, 0.0]]), np.array([7]), 0.3, 1.75)
    s = 3.0 - 0.3 - 0.3                                   # camera 0.3 m ahead of the robot, radius 0.3
    assert depth[60, 80] == pytest.approx(s, abs=1e-3)
    top = CAM.cy_px - CAM.fy_px * (1.75 - CAM.z_m) / s
    assert depth[int(np.ceil(top)) + 1, 80] == pytest.approx(s, abs=1e-3)
    assert depth[int(np.floor(top)) - 1, 80] == pytest.approx(5.7, abs=1e-3)   # wall above the head
    # horizontal extent: tangent rays from the camera to the circle
    half = np.arcsin(0.3 / 2.7)
    edge = CAM.fx_px * np.tan(half)
    assert depth[60, int(80 + edge) + 2] == pytest.approx(5.7, abs=1e-3)
    assert depth[60, int(80 + edge) - 2] < 3.0


def test_short_box_below_camera_height_shows_its_inner_back_face_then_the_wall_above():
    corners = np.array([[2.0, 1.0], [2.0, -1.0], [3.0, -1.0], [3.0, 1.0]])     # counter-clockwise
    box = np.stack([corners, np.roll(corners, -1, axis=0)], axis=1)
    wall, wh = wall_at(6.0)
    r = renderer(np.concatenate([wall, box]), np.concatenate([wh, np.full(4, 0.5)]),
                 obstacle=np.array([False, True, True, True, True]))
    _, depth = r.render((0.0, 0.0, 0.0))
    front = 2.0 - 0.3
    box_top = CAM.cy_px + CAM.fy_px * (CAM.z_m - 0.5) / front
    assert depth[int(box_top) + 3, 80] == pytest.approx(front, abs=1e-3)
    back_top = CAM.cy_px + CAM.fy_px * (CAM.z_m - 0.5) / (front + 1.0)
    assert depth[int(back_top) + 2, 80] == pytest.approx(front + 1.0, abs=1e-3)     # no lid: inner back face
    assert depth[int(back_top) - 2, 80] > front + 1.0                               # floor, then the wall
    assert depth[40, 80] == pytest.approx(5.7, abs=1e-3)


def test_range_limits_give_no_return():
    segs, h = wall_at(12.0)
    _, depth = renderer(segs, h).render((0.0, 0.0, 0.0))
    assert np.all(depth[40:60] == 0.0)                     # wall at 11.7 m > max_range 8 m
    assert np.all(np.isfinite(depth)) and depth.min() >= 0


def test_empty_scene_renders_floor_and_sky_and_camera_inside_a_pedestrian_is_finite():
    r = renderer()
    rgb, depth = r.render((1.0, 2.0, 0.3))
    assert np.all(depth[:59] == 0) and np.all(depth[80:] > 0)     # floor beyond 8 m: no return
    rgb2, depth2 = r.render((0.0, 0.0, 0.0), np.array([[0.3, 0.0]]), np.array([1]))   # camera inside it
    assert np.all(np.isfinite(depth2)) and rgb2.shape == rgb.shape


def test_pedestrian_texture_is_stable_per_id_and_has_contrast():
    cam = CameraModel(width_px=320, height_px=240, fx_px=262.5, fy_px=262.5, cx_px=159.5, cy_px=119.5)
    r = renderer(camera=cam)
    a, _ = r.render((0.0, 0.0, 0.0), np.array([[2.5, 0.0]]), np.array([3]))
    b, _ = r.render((0.0, 0.0, 0.0), np.array([[2.5, 0.0]]), np.array([3]))
    c, _ = r.render((0.0, 0.0, 0.0), np.array([[2.5, 0.0]]), np.array([4]))
    patch = (slice(90, 140), slice(140, 180))
    np.testing.assert_array_equal(a, b)
    assert np.abs(a[patch].astype(int) - c[patch].astype(int)).mean() > 5      # another id looks different
    assert a[patch].astype(float).std(axis=(0, 1)).max() > 8                  # texture for optical flow
