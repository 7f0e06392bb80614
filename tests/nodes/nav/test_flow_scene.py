"""RGB-D scene flow: optical flow presets, ego-motion removal, depth holes, hard cases (synthetic ground truth)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from nodes.nav.flow import (PRESETS, DenseFlow, Intrinsics, Mount, OpticalFlow, depth_usable, ego_flow_prior,
                            relative_motion, scene_flow)
from sim.crowd import CrowdWorld
from sim.crowd_render import CameraModel

CAM = CameraModel(width_px=320, height_px=240, fx_px=262.5, fy_px=262.5, cx_px=159.5, cy_px=119.5)
INTR = Intrinsics(CAM.fx_px, CAM.fy_px, CAM.cx_px, CAM.cy_px)
MOUNT = Mount(CAM.x_m, CAM.y_m, CAM.z_m)
ROOM = [{"points": [[-6, -6], [6, -6], [6, 6], [-6, 6], [-6, -6]], "height_m": 2.5}]
DT = 1 / 15


def texture(seed: int = 0, shape=(240, 320)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur((rng.random(shape) * 255).astype(np.uint8), (0, 0), 2.0)


def frames(scene: dict, cmd: tuple[float, float], *, warmup: int = 4, preset: str = "dis_fast", prior: bool = True):
    """Two consecutive rendered frames and the scene flow between them, plus the world."""
    world = CrowdWorld(scene, camera=CAM)
    for _ in range(warmup):
        world.step(*cmd, DT)
    rgb0, d0 = world.render()
    pose0 = world.pose
    world.step(*cmd, DT)
    rgb1, d1 = world.render()
    motion = relative_motion(pose0, world.pose)
    est = OpticalFlow(preset)
    init = ego_flow_prior(d1, motion, INTR, MOUNT, est.processing_shape(d1.shape)) if prior else None
    flow = est(rgb1, rgb0, prior=init)
    return scene_flow(flow, d0, d1, motion, DT, INTR, MOUNT), world


def in_robot_frame(world, xy):
    x, y, yaw = world.pose
    c, s = np.cos(yaw), np.sin(yaw)
    d = np.asarray(xy) - (x, y)
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])


def test_relative_motion():
    assert relative_motion((1.0, 2.0, 0.0), (3.0, 2.0, 0.0)) == pytest.approx((2.0, 0.0, 0.0))
    dx, dy, dyaw = relative_motion((0.0, 0.0, np.pi / 2), (0.0, 1.0, np.pi))
    assert (dx, dy, dyaw) == pytest.approx((1.0, 0.0, np.pi / 2))
    assert relative_motion((0, 0, 3.1), (0, 0, -3.1))[2] == pytest.approx(2 * np.pi - 6.2)   # wraps


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_identical_images_give_zero_flow_and_a_known_shift_is_recovered(preset):
    est = OpticalFlow(preset)
    img = texture()
    assert np.abs(est(img, img).full()[20:-20, 20:-20]).max() < 0.05
    shifted = np.roll(img, (2, 3), axis=(0, 1))          # img(y, x) = shifted(y + 2, x + 3)
    f = est(img, shifted).full()[30:-30, 30:-30]
    np.testing.assert_allclose(np.median(f.reshape(-1, 2), axis=0), [3.0, 2.0], atol=0.15)


def test_half_scale_flow_is_reported_in_full_resolution_pixels():
    img = texture()
    shifted = np.roll(img, 4, axis=1)
    flow = OpticalFlow("dis_medium", scale=0.5)(img, shifted)
    assert flow.field.shape == (120, 160, 2)
    np.testing.assert_allclose(np.median(flow.at(np.array([100, 160]), np.array([100, 120]))[:, 0]), 4.0, atol=0.3)
    assert flow.full().shape == (240, 320, 2)


def test_bad_arguments_say_what_to_do():
    with pytest.raises(ValueError, match="choose one of"):
        OpticalFlow("lucas_kanade")
    with pytest.raises(ValueError, match="scale"):
        OpticalFlow("dis_fast", scale=2.0)
    with pytest.raises(ValueError, match="differ in size"):
        OpticalFlow()(texture(), texture(shape=(100, 100)))
    with pytest.raises(ValueError, match="CameraInfo"):
        Intrinsics(0.0, 0.0, 1.0, 1.0)
    flow = DenseFlow(np.zeros((240, 320, 2), np.float32), 1.0, (240, 320))
    with pytest.raises(ValueError, match="dt_s"):
        scene_flow(flow, np.ones((240, 320)), np.ones((240, 320)), (0, 0, 0), 0.0, INTR)


@pytest.mark.parametrize("cmd", [(0.0, 0.9), (0.7, 0.0), (0.5, -0.6)])
def test_static_world_gives_near_zero_velocity_whatever_the_robot_does(cmd):
    sf, _ = frames({"name": "s", "walls": ROOM, "obstacles": [
        {"cylinder": {"x_m": 3.0, "y_m": 0.6, "radius_m": 0.3}, "height_m": 2.0},
        {"box": {"x_m": 4.0, "y_m": -1.5, "length_m": 1.0, "width_m": 1.0}, "height_m": 1.2}]}, cmd)
    speed = np.linalg.norm(sf.velocity_mps, axis=1)
    assert len(speed) > 1000
    # not removing the turn would leave ~w * range = 3 m/s here; flow noise at 320x240 is ~0.05 m/s
    assert np.median(speed) < 0.1 and np.percentile(speed, 90) < 0.35


def test_pure_rotation_needs_the_ego_prior_for_farneback_but_not_for_dis():
    scene = {"name": "s", "walls": ROOM}
    fast_turn = (0.0, 1.2)
    with_prior, _ = frames(scene, fast_turn, warmup=10, preset="farneback")
    dis, _ = frames(scene, fast_turn, warmup=10, preset="dis_medium", prior=False)
    for sf in (with_prior, dis):
        assert len(sf.points_m) > 1000
        assert np.median(np.linalg.norm(sf.velocity_mps, axis=1)) < 0.08
    # without the prior Farneback cannot follow a ~20 px turn: its points are dropped as outliers or wrong
    without, _ = frames(scene, fast_turn, warmup=10, preset="farneback", prior=False)
    assert (len(without.points_m) < 0.2 * len(with_prior.points_m)
            or np.median(np.linalg.norm(without.velocity_mps, axis=1)) > 0.5)


def test_moving_and_standing_pedestrians_get_their_own_velocities_in_the_robot_frame():
    scene = {"name": "p", "walls": ROOM, "pedestrian_model": "linear", "pedestrians": [
        {"id": 1, "waypoints": [[3.5, -1.5], [3.5, 3.0]], "speed_mps": 1.0},
        {"id": 2, "waypoints": [[2.5, 0.9]], "speed_mps": 0}]}
    sf, world = frames(scene, (0.4, 0.3), warmup=6)
    peds = world.pedestrians()
    yaw = world.pose[2]
    for k, pid in enumerate(peds.ids):
        centre = in_robot_frame(world, peds.xy_m[k])
        near = np.linalg.norm(sf.points_m[:, :2] - centre, axis=1) < 0.45
        assert near.sum() > 100, pid
        truth = np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]]) @ peds.vel_mps[k]
        np.testing.assert_allclose(np.median(sf.velocity_mps[near, :2], axis=0), truth, atol=0.1)
        assert np.all(sf.points_m[near, 0] > 0)                               # ahead of the robot


def test_depth_holes_zeros_nan_inf_and_negative_are_dropped_and_outputs_stay_finite():
    world = CrowdWorld({"name": "h", "walls": ROOM}, camera=CAM)
    rgb, depth = world.render()
    bad = depth.copy()
    rng = np.random.default_rng(1)
    holes = rng.random(bad.shape)
    bad[holes < 0.1] = 0.0
    bad[(holes >= 0.1) & (holes < 0.2)] = np.nan
    bad[(holes >= 0.2) & (holes < 0.25)] = np.inf
    bad[(holes >= 0.25) & (holes < 0.3)] = -1.0
    flow = OpticalFlow()(rgb, rgb)
    sf = scene_flow(flow, bad, bad, (0.0, 0.0, 0.0), DT, INTR, MOUNT, edge_rel=0.0)
    assert len(sf.points_m) > 100
    assert np.all(np.isfinite(sf.points_m)) and np.all(np.isfinite(sf.velocity_mps))
    u, v = sf.pixels[:, 0], sf.pixels[:, 1]
    assert np.all(np.isfinite(bad[v, u]) & (bad[v, u] > 0))
    assert np.abs(sf.velocity_mps).max() < 1e-3
    everything_missing = np.full_like(depth, np.nan)
    empty = scene_flow(flow, everything_missing, everything_missing, (0, 0, 0), DT, INTR, MOUNT)
    assert empty.points_m.shape == (0, 3) and empty.velocity_mps.shape == (0, 3)


def test_depth_edges_are_not_usable():
    depth = np.full((50, 50), 5.0, np.float32)
    depth[:, 25:] = 2.0
    ok = depth_usable(depth, min_m=0.4, max_m=8.0, edge_rel=0.1, edge_px=2)
    assert not ok[:, 23:27].any() and ok[:, :22].all() and ok[:, 28:].all()


def test_ego_prior_is_the_true_flow_of_a_static_scene():
    world = CrowdWorld({"name": "s", "walls": ROOM}, camera=CAM)
    world.step(0.5, 0.5, 0.5)
    rgb0, d0 = world.render()
    pose0 = world.pose
    world.step(0.5, 0.5, DT)
    _, d1 = world.render()
    motion = relative_motion(pose0, world.pose)
    prior = ego_flow_prior(d1, motion, INTR, MOUNT, d1.shape)
    sf = scene_flow(DenseFlow(prior, 1.0, d1.shape), d0, d1, motion, DT, INTR, MOUNT)
    assert len(sf.points_m) > 1000
    assert np.median(np.linalg.norm(sf.velocity_mps, axis=1)) < 0.02


def test_flow_tracker_keeps_state_between_frames_and_restarts_after_a_gap():
    from nodes.nav.flow import FlowTracker
    world = CrowdWorld({"name": "s", "walls": ROOM}, camera=CAM)
    tracker = FlowTracker(MOUNT)
    rgb, depth = world.render()
    assert tracker.update(0.0, rgb, depth, INTR, world.pose) is None            # first frame
    world.step(0.5, 0.4, DT)
    rgb, depth = world.render()
    sf = tracker.update(DT, rgb, depth, INTR, world.pose)
    assert sf is not None and len(sf.points_m) > 500
    assert sf.points_m[:, 2].min() >= 0.15 and np.median(np.linalg.norm(sf.velocity_mps, axis=1)) < 0.1
    assert tracker.update(DT + 2.0, rgb, depth, INTR, world.pose) is None      # 2 s later: restart
    with pytest.raises(ValueError, match="differ in size"):
        tracker.update(3.0, rgb[:10], depth, INTR)


def _static_pair():
    world = CrowdWorld({"name": "s", "walls": ROOM}, camera=CAM)
    world.step(0.5, 0.5, 0.5)
    _, d0 = world.render()
    pose0 = world.pose
    world.step(0.5, 0.5, DT)
    _, d1 = world.render()
    motion = relative_motion(pose0, world.pose)
    return d0, d1, motion, ego_flow_prior(d1, motion, INTR, MOUNT, d1.shape)


def test_points_at_the_image_border_are_dropped_where_the_flow_patches_are_cut():
    d0, d1, motion, prior = _static_pair()
    bad = prior.copy()
    bad[:, :12] += (3.0, 0.0)             # a wrong match at the left edge (students003: a head at u = 7 px)
    flow = DenseFlow(bad, 1.0, d1.shape)
    loose = scene_flow(flow, d0, d1, motion, DT, INTR, MOUNT)
    assert (np.linalg.norm(loose.velocity_mps, axis=1)[loose.pixels[:, 0] < 12] > 0.3).any()
    sf = scene_flow(flow, d0, d1, motion, DT, INTR, MOUNT, border_px=16)
    assert sf.pixels[:, 0].min() >= 16 and sf.pixels[:, 0].max() < CAM.width_px - 16
    clean = scene_flow(DenseFlow(prior, 1.0, d1.shape), d0, d1, motion, DT, INTR, MOUNT, border_px=16)
    np.testing.assert_array_equal(sf.pixels, clean.pixels)          # the wrong matches are all gone
    np.testing.assert_allclose(sf.velocity_mps, clean.velocity_mps)
    # a match that lands within the border of the previous frame is dropped too
    out = prior.copy()
    out[:, 40:60, 0] = -45.0 - np.arange(40, 60)[None, :].astype(np.float32)   # previous pixel u < 0
    sf = scene_flow(DenseFlow(out, 1.0, d1.shape), d0, d1, motion, DT, INTR, MOUNT, border_px=16)
    assert not ((sf.pixels[:, 0] >= 40) & (sf.pixels[:, 0] < 60)).any()


def test_points_rising_or_falling_fast_are_flow_outliers():
    d0, d1, motion, prior = _static_pair()
    wrong = prior.copy()
    wrong[100:140, 100:200, 1] += 6.0     # a vertical mismatch: the static wall seems to sink
    flow = DenseFlow(wrong, 1.0, d1.shape)
    loose = scene_flow(flow, d0, d1, motion, DT, INTR, MOUNT)
    band = (loose.pixels[:, 1] >= 100) & (loose.pixels[:, 1] < 140) & (loose.pixels[:, 0] >= 100) & (loose.pixels[:, 0] < 200)
    assert np.abs(loose.velocity_mps[band, 2]).min() > 0.5
    sf = scene_flow(flow, d0, d1, motion, DT, INTR, MOUNT, max_vertical_mps=0.5)
    assert np.abs(sf.velocity_mps[:, 2]).max() <= 0.5
    assert len(sf.points_m) == len(loose.points_m) - band.sum()


def test_borders_with_depth_holes_are_edges_but_sensor_dropouts_are_not():
    depth = np.zeros((50, 50), np.float32)          # no return (sky, beyond range) ...
    depth[10:40, 10:30] = 2.0                       # ... around a person-sized object
    depth[25, 20] = 0.0                             # one dropout pixel inside it
    ok = depth_usable(depth, min_m=0.4, max_m=8.0, edge_rel=0.1, edge_px=2, hole_edges=True)
    inner = ok[12:38, 12:28].copy()
    assert not inner[13, 8]                         # the dropout itself has no depth ...
    inner[13, 8] = True
    assert inner.all()                              # ... but its neighbours and the rest of the interior are fine
    assert not ok[10:12].any() and not ok[:, 28:30].any()    # its border against the holes
    old = depth_usable(depth, min_m=0.4, max_m=8.0, edge_rel=0.1, edge_px=2, hole_edges=False)
    assert old[10, 10:30].all()                     # the range test alone cannot see that border


def test_forward_backward_check_drops_matches_the_two_flows_disagree_on():
    d0, d1, motion, prior = _static_pair()
    back = DenseFlow(prior, 1.0, d1.shape)
    # the forward flow: minus the backward one, sampled where each current pixel lands
    h, w = d1.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    fwd_field = np.zeros_like(prior)
    fwd_field[..., 0], fwd_field[..., 1] = -prior[..., 0], -prior[..., 1]
    fwd_field = cv2.remap(fwd_field, u - prior[..., 0], v - prior[..., 1], cv2.INTER_LINEAR)   # approx. inverse
    fwd = DenseFlow(fwd_field, 1.0, d1.shape)
    clean = scene_flow(back, d0, d1, motion, DT, INTR, MOUNT)
    agreed = scene_flow(back, d0, d1, motion, DT, INTR, MOUNT, flow_fwd=fwd, fb_max_px=1.0)
    assert len(agreed.points_m) > 0.9 * len(clean.points_m)
    wrong = prior.copy()
    wrong[100:140, 100:200, 0] += 4.0                # a wrong backward match the forward flow does not share
    bad = DenseFlow(wrong, 1.0, d1.shape)
    loose = scene_flow(bad, d0, d1, motion, DT, INTR, MOUNT)
    band = (loose.pixels[:, 1] >= 100) & (loose.pixels[:, 1] < 140) & (loose.pixels[:, 0] >= 100) & (loose.pixels[:, 0] < 200)
    assert np.linalg.norm(loose.velocity_mps[band], axis=1).min() > 0.3
    sf = scene_flow(bad, d0, d1, motion, DT, INTR, MOUNT, flow_fwd=fwd, fb_max_px=1.0)
    kept = (sf.pixels[:, 1] >= 100) & (sf.pixels[:, 1] < 140) & (sf.pixels[:, 0] >= 100) & (sf.pixels[:, 0] < 200)
    assert not kept.any()
    assert np.percentile(np.linalg.norm(sf.velocity_mps, axis=1), 99) < 0.1
