"""The OpenCV convexity-defect finger counter on drawn masks (exact ground truth) and its hard
cases: a frame of zeros, the forearm to the border, 0 against 1, fingers held together."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from nodes.vision.hand_convexity import count_fingers, segment_skin


def hand_mask(fingers: int, *, spread_deg: float = 22.0, arm: bool = False, size: int = 160,
              together: bool = False) -> np.ndarray:
    """A palm disc with ``fingers`` capsules fanned upward (and a forearm to the bottom edge)."""
    m = np.zeros((size, size), np.uint8)
    c = np.array([size / 2, size * 0.62])
    r = size * 0.14
    cv2.circle(m, tuple(c.astype(int)), int(r), 255, -1)
    step = 0.0 if together else spread_deg
    for k in range(fingers):
        ang = math.radians((k - (fingers - 1) / 2) * step)
        d = np.array([math.sin(ang), -math.cos(ang)])
        base = c + d * r * 0.6 + (np.array([(k - (fingers - 1) / 2) * r * 0.42, 0]) if together else 0)
        tip = base + d * r * 2.6
        cv2.line(m, tuple(base.astype(int)), tuple(tip.astype(int)), 255, int(r * 0.4))
    if arm:
        cv2.rectangle(m, (int(c[0] - r * 0.8), int(c[1])), (int(c[0] + r * 0.8), size - 1), 255, -1)
    return m


@pytest.mark.parametrize("fingers", [0, 1, 2, 3, 4, 5])
def test_counts_spread_fingers_exactly(fingers):
    assert count_fingers(mask=hand_mask(fingers)).count == fingers


@pytest.mark.parametrize("fingers", [0, 1, 2, 5])
def test_the_forearm_to_the_border_is_not_a_finger(fingers):
    r = count_fingers(mask=hand_mask(fingers, arm=True))
    assert r.count == fingers
    assert r.arm_dir[1] > 0.9                                              # the arm points down


def test_zero_against_one_is_decided_by_reach_not_by_a_defect():
    fist, one = count_fingers(mask=hand_mask(0, arm=True)), count_fingers(mask=hand_mask(1, arm=True))
    assert (fist.count, one.count) == (0, 1)
    assert len(one.valleys_px) == 0 and len(one.tips_px) == 1 and one.tips_px[0][1] < one.palm_px[1]


def test_a_frame_of_zeros_and_a_speck_are_no_hand():
    assert count_fingers(np.zeros((120, 160, 3), np.uint8)) .present is False
    speck = np.zeros((120, 160), np.uint8)
    speck[50:53, 60:63] = 255
    r = count_fingers(mask=speck)
    assert not r.present and r.count == 0 and "too small" in r.reason


def test_fingers_held_together_are_one_blob_a_known_limit():
    assert count_fingers(mask=hand_mask(3, together=True)).count < 3


def test_skin_segmentation_finds_a_skin_disc_and_refuses_mono():
    img = np.full((60, 60, 3), 200, np.uint8)
    cv2.circle(img, (30, 30), 12, (120, 150, 220), -1)                    # BGR skin tone on grey
    m = segment_skin(img)
    assert m[30, 30] == 255 and m[2, 2] == 0
    with pytest.raises(ValueError, match="BGR"):
        segment_skin(np.zeros((10, 10), np.uint8))
    with pytest.raises(ValueError, match="image or a mask"):
        count_fingers()
