"""The hand simulator: kinematics (limits, lengths, mirror), scenes and their hard cases."""
from __future__ import annotations

import numpy as np
import pytest

from sim.hand import GESTURES, HandPose, count_of, forward_kinematics, gesture_of, project, sample_pose
from sim.hand_render import SceneSpec, render_scene


def test_a_straight_finger_reaches_its_length_and_a_curled_one_folds_onto_the_palm():
    kp = forward_kinematics(HandPose())
    assert kp.shape == (21, 3)
    assert np.linalg.norm(kp[12] - kp[9]) == pytest.approx(0.47 + 0.29 + 0.21)
    curled = forward_kinematics(HandPose(flex=np.tile([1.5, 1.8, 1.0], (5, 1))))
    assert np.linalg.norm(curled[12, :2] - curled[9, :2]) < 0.35          # projected onto the palm
    assert curled[12, 2] > 0                                               # toward the camera


def test_joint_limits_are_enforced():
    wild = HandPose(flex=np.full((5, 3), 9.0), splay=np.full(5, 3.0))
    c = wild.clipped()
    assert c.flex[1:, 0].max() == 1.6 and c.flex[1:, 1].max() == 1.9 and c.splay.max() == 0.45
    assert np.allclose(forward_kinematics(wild), forward_kinematics(c))


def test_mirror_flips_the_hand_and_roll_turns_it_on_screen():
    kp = forward_kinematics(HandPose())
    px, _ = project(kp, HandPose(), centre_px=(50, 50), scale_px=10)
    pm, _ = project(kp, HandPose(mirror=True), centre_px=(50, 50), scale_px=10)
    assert np.allclose(pm[:, 0] - 50, -(px[:, 0] - 50)) and np.allclose(pm[:, 1], px[:, 1])
    pr, _ = project(kp, HandPose(roll_rad=np.pi / 2), centre_px=(50, 50), scale_px=10)
    assert pr[12, 0] < 40 and abs(pr[12, 1] - 50) < 3                     # fingers point left on screen
    assert px[12, 1] < 40                                                  # unrolled: fingers up


def test_every_gesture_samples_with_its_own_finger_set():
    rng = np.random.default_rng(0)
    for name, sets in GESTURES.items():
        for _ in range(5):
            pose = sample_pose(rng, name)
            assert tuple(pose.extended.astype(int)) in sets
            assert gesture_of(pose.extended) == name
    assert gesture_of(np.array([0, 0, 0, 0, 1], bool)) == "count1" and count_of(np.ones(5, bool)) == 5
    with pytest.raises(ValueError, match="unknown gesture"):
        sample_pose(rng, "wave")


def test_scenes_are_reproducible_and_mono_on_request():
    a, ta = render_scene(np.random.default_rng(7), SceneSpec(gesture="open"))
    b, tb = render_scene(np.random.default_rng(7), SceneSpec(gesture="open"))
    assert np.array_equal(a, b) and np.array_equal(ta.keypoints_px, tb.keypoints_px)
    m, _ = render_scene(np.random.default_rng(7), SceneSpec(mono=True, width_px=80, height_px=60))
    assert m.shape == (60, 80) and m.dtype == np.uint8


def test_no_hand_has_no_keypoints_and_counts_zero():
    img, t = render_scene(np.random.default_rng(1), SceneSpec(hands=0))
    assert not t.present and t.count == 0 and t.gesture == "none" and np.all(np.isnan(t.keypoints_px))
    assert img.shape == (128, 128, 3)


def test_two_hands_truth_is_the_larger_front_hand():
    for seed in range(5):
        img, t = render_scene(np.random.default_rng(seed), SceneSpec(hands=2, gesture="open", background="plain"))
        one, t1 = render_scene(np.random.default_rng(seed), SceneSpec(hands=1, gesture="open", background="plain"))
        assert t.present and t.count == 5 and t.palm_px > 5
        assert not np.array_equal(img, one)                                # a second hand was drawn


def test_border_framing_touches_the_edge_and_inside_does_not():
    for seed in range(10):
        _, t = render_scene(np.random.default_rng(seed), SceneSpec(framing="border"))
        kp = t.keypoints_px
        margin = min(kp.min(), (127 - kp).min())
        assert margin < 0.2 * t.palm_px                                    # a keypoint at or past an edge
        _, ti = render_scene(np.random.default_rng(seed), SceneSpec(framing="inside"))
        assert ti.keypoints_px.min() > -1 and ti.keypoints_px.max() < 128


def test_arm_in_view_adds_skin_below_the_wrist_but_no_finger():
    rng_a, rng_b = np.random.default_rng(3), np.random.default_rng(3)
    spec = SceneSpec(gesture="fist", background="plain", framing="inside")
    with_arm, ta = render_scene(rng_a, SceneSpec(**{**spec.__dict__, "arm": True}))
    without, tb = render_scene(rng_b, SceneSpec(**{**spec.__dict__, "arm": False}))
    assert ta.count == tb.count == 0
    assert np.abs(with_arm.astype(int) - without.astype(int)).sum() > 1000   # the forearm is drawn


def test_spread_v_fans_the_two_fingers_apart():
    gaps = {}
    for spread in (True, False):
        g = []
        for seed in range(20):
            _, t = render_scene(np.random.default_rng(seed), SceneSpec(gesture="victory", spread=spread))
            g.append(np.linalg.norm(t.keypoints_px[8] - t.keypoints_px[12]) / t.palm_px)
        gaps[spread] = np.median(g)
    assert gaps[True] > 1.5 * gaps[False]


def test_skin_background_is_close_to_the_hand_colour():
    img, t = render_scene(np.random.default_rng(4), SceneSpec(background="skin", gesture="open", arm=False))
    palm = np.round((t.keypoints_px[0] + t.keypoints_px[9]) / 2).astype(int)
    corner = img[:6, :6].reshape(-1, 3).mean(0)
    hand = img[palm[1], palm[0]].astype(float)
    assert np.linalg.norm(corner - hand) < 80


def test_hand_camera_node_follows_its_script_and_drops_frames_in_the_blackout():
    from sim.hand_node import HandCamera, parse_script
    from tether.testing import Harness

    h = Harness(HandCamera, params={"script": "fist:1,none:1", "rate_hz": 10, "width_px": 64, "height_px": 48,
                                    "blackout_start_s": 2.5, "blackout_end_s": 3.0})
    h.advance_to(3.95)
    truths = [(m.stamp_ns / 1e9, m.gesture, m.present) for m in h.of("truth")]
    images = h.of("image")
    assert images[0].data.shape == (48, 64, 3) and images[0].encoding == "bgr8"
    assert all(g == "fist" and p for t, g, p in truths if t < 0.95 or 2.0 <= t < 2.5)
    assert all(g == "none" and not p for t, g, p in truths if 1.0 <= t < 1.95)
    assert not any(2.5 <= t < 3.0 for t, _, _ in truths) and len(images) == len(truths) == 35
    with pytest.raises(ValueError, match="gesture must be"):
        parse_script("wave:2")
    with pytest.raises(ValueError, match="seconds must be"):
        parse_script("fist:0")
