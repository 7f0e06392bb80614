"""Keypoint net training on arrays: augmentation keeps image and keypoints together, a tiny
seeded run lowers the loss, weights round-trip as msgpack, and the geometry reads gestures."""
from __future__ import annotations

import jax
import numpy as np
import pytest

from nodes.vision.hand_geometry import extended_fingers, finger_scores, gesture_label
from nodes.vision.hand_keypoints import INPUT_PX, KeypointModel, init_params
from nodes.vision.hand_learn import augment, train_keypoints
from sim.hand_render import SceneSpec, render_scene


def test_augmentation_moves_the_keypoints_with_the_pixels():
    rng = np.random.default_rng(0)
    img = np.zeros((1, INPUT_PX, INPUT_PX, 3), np.uint8)
    kp = np.array([[[10.0, 30.0], [70.0, 5.0]]])
    img[0, 30, 10], img[0, 5, 70] = 255, 128
    for _ in range(12):
        a, k = augment(rng, img, kp)
        for j, v in enumerate((255, 128)):
            x, y = np.round(k[0, j]).astype(int)
            assert a[0, y, x, 0] == v


def test_a_tiny_seeded_training_run_lowers_the_loss():
    imgs, kps, pres = [], [], []
    for i in range(24):
        img, t = render_scene(np.random.default_rng(i), SceneSpec(width_px=INPUT_PX, height_px=INPUT_PX,
                                                                  hands=0 if i % 8 == 0 else 1))
        imgs.append(img[..., ::-1])
        kps.append(t.keypoints_px)
        pres.append(t.present)
    args = (np.array(imgs), np.array(kps, np.float32), np.array(pres))
    seen = []
    _, curve = train_keypoints(*args, steps=30, batch=6, lr=3e-3, seed=1, width=4, log_every=15, val_frac=0.0,
                               progress=seen.append)
    assert len(curve) == 2 and seen == curve and curve[-1].loss < curve[0].loss
    with pytest.raises(ValueError, match="keypoints"):
        train_keypoints(args[0], args[1][:, :5], args[2], steps=1)


def test_weights_round_trip_as_msgpack_and_a_wrong_file_is_refused(tmp_path):
    model = KeypointModel(init_params(3, width=4), width=4)
    path = tmp_path / "w.msgpack"
    size = model.save(path)
    assert path.read_bytes()[:1] != b"\x80"                                # not a pickle
    again = KeypointModel.load(path, width=4)
    a, b = jax.tree_util.tree_leaves(model.params), jax.tree_util.tree_leaves(again.params)
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b)) and size > 1000
    with pytest.raises(ValueError, match="do not fit"):
        KeypointModel.load(path, width=8)
    with pytest.raises(ValueError, match="no keypoint weights"):
        KeypointModel.load(tmp_path / "missing.msgpack")


def test_geometry_reads_every_simulated_finger_state_and_is_scale_rotation_and_mirror_free():
    for seed in range(150):
        _, t = render_scene(np.random.default_rng(seed), SceneSpec())
        assert np.array_equal(extended_fingers(t.keypoints_px), t.extended), seed
        c, s = np.cos(1.0), np.sin(1.0)
        moved = (t.keypoints_px @ np.array([[c, -s], [s, c]]).T) * 2.5 * np.array([-1, 1]) + 300
        assert np.array_equal(extended_fingers(moved), t.extended)
    assert gesture_label(np.array([0, 1, 1, 0, 0], bool)) == "victory"
    assert gesture_label(np.array([1, 0, 0, 0, 1], bool)) == "count2"
    with pytest.raises(ValueError, match="21 finite keypoints"):
        finger_scores(np.full((21, 2), np.nan))
