"""Captcha synthesiser and the seed's line removal: shapes, seeding, lines gone / strokes kept, flat images, the real set's split."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from sim.captcha import PLAIN, SPLIT, CaptchaStyle, load_real_captchas, remove_lines, shared_captcha_dir, synthesize_captchas


def test_synthesised_captchas_are_labelled_seeded_and_varied():
    a, la = synthesize_captchas(6, seed=3)
    b, lb = synthesize_captchas(6, seed=3)
    c, _ = synthesize_captchas(6, seed=4)
    assert a.shape == (6, 30, 70, 3) and a.dtype == np.uint8
    assert la.shape == (6, 4) and la.min() >= 0 and la.max() <= 9
    assert np.array_equal(a, b) and np.array_equal(la, lb)
    assert not np.array_equal(a, c)
    # ink is darker than the pastel background: the centre band holds the darkest pixels
    grey = a.mean(-1)
    assert grey[:, 8:22, 5:65].min() < 120 and np.median(grey) > 170
    # the real set's near-black 1-px frame on every side
    assert max(grey[:, 0].mean(), grey[:, -1].mean(), grey[:, :, 0].mean(), grey[:, :, -1].mean()) < 40


def test_hershey_fallback_and_plain_style_render_digits():
    images, labels = synthesize_captchas(3, seed=0, style=PLAIN, fonts=())
    assert images.shape == (3, 30, 70, 3)
    ink = images.mean(-1) < 128
    assert ink.sum() > 40                              # digits were drawn
    assert images[:, 0, :].min() >= 250                # plain: white edge, no border line


def test_remove_lines_drops_thin_lines_and_keeps_thick_strokes():
    img = np.full((30, 70), 230, np.uint8)
    cv2.rectangle(img, (20, 6), (22, 24), 40, -1)       # a 3-px stroke
    cv2.line(img, (35, 3), (65, 27), 60, 1)             # a 1-px noise line
    out = remove_lines(img)
    assert out.dtype == np.uint8 and out.shape == (30, 70)
    assert (out[6:25, 20:23] > 0).mean() > 0.9
    assert (out[:, 33:] > 0).sum() <= 2


@pytest.mark.parametrize("value", [0, 255])
def test_flat_images_give_no_ink(value):
    out = remove_lines(np.full((30, 70, 3), value, np.uint8))
    assert out.shape == (30, 70) and not out.any()


def test_remove_lines_refuses_bad_input():
    with pytest.raises(ValueError, match="image"):
        remove_lines(np.zeros((4,), np.uint8))
    with pytest.raises(ValueError, match="odd"):
        remove_lines(np.zeros((30, 70), np.uint8), block_px=4)
    with pytest.raises(ValueError, match=">= 0"):
        synthesize_captchas(-1)


def test_missing_real_set_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="TETHER_SHARED_DATA"):
        load_real_captchas(tmp_path)


@pytest.mark.skipif(not (shared_captcha_dir() / "labels.csv").exists(), reason="../shared/data/captcha is absent")
def test_real_split_is_fixed_by_file_and_disjoint():
    parts = {k: load_real_captchas(split=k) for k in SPLIT}
    assert {k: len(v[2]) for k, v in parts.items()} == {"train": 600, "validation": 100, "test": 300}
    files = [set(v[2]) for v in parts.values()]
    assert not (files[0] & files[1] or files[0] & files[2] or files[1] & files[2])
    images, labels, _ = parts["test"]
    assert images.shape[1:] == (30, 70, 3) and labels.shape == (300, 4)
    # the synthesiser imitates the real look: similar mean brightness (within 25 grey levels)
    syn, _ = synthesize_captchas(50, seed=0, style=CaptchaStyle())
    assert abs(syn.mean() - images.mean()) < 25
