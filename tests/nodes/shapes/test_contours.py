"""Contours from masks and edge maps, and the winding node."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from msgs.sensor import Image
from nodes.shapes.contours import contours_from_mask, merge_close, orient_by_nesting, polylines_from_edges, signed_area
from nodes.shapes.inside_outside import inside_mask, winding_image
from nodes.shapes.winding_node import WindingNode
from tether.errors import ConfigError
from tether.testing import Harness


def _ring_and_box():
    m = np.zeros((200, 300), np.uint8)
    cv2.circle(m, (100, 100), 60, 255, -1)
    cv2.circle(m, (100, 100), 25, 0, -1)
    cv2.rectangle(m, (200, 50), (280, 150), 255, -1)
    return m


def test_mask_contours_are_oriented_by_nesting():
    cs = contours_from_mask(_ring_and_box())
    areas = sorted(signed_area(c) for c in cs)
    assert len(cs) == 3 and areas[0] < 0 < areas[1] < areas[2]         # the hole winds the other way


def test_mask_round_trip_differs_only_on_the_outline():
    m = _ring_and_box()
    w, n = winding_image(m)
    assert n == 3 and set(np.unique(w[m == 0][::7])) <= {0.0, 0.25, 0.375, 0.5, 0.625, 0.75}
    wrong = inside_mask(w) != (m > 0)
    outline = cv2.morphologyEx(m, cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
    assert wrong.sum() < 0.02 * (m > 0).sum() and np.all(outline[wrong])


@pytest.mark.parametrize("gap", [0, 10, 20])
def test_edges_with_gaps_still_give_the_regions(gap):
    m = _ring_and_box()
    e = cv2.Canny(m, 50, 150)
    if gap:
        e[100 - gap // 2:100 + gap // 2, :] = 0
    w, _ = winding_image(e, source="edges", merge_px=3)
    wrong = inside_mask(w) != (m > 0)
    assert wrong.sum() < 0.03 * (m > 0).sum()
    assert w[100, 100] < 0.5 and w[100, 50] > 0.5 and w[100, 240] > 0.5   # the hole, the ring, the box


def test_thin_open_edge_unfolds_to_one_polyline_and_merges():
    e = np.zeros((50, 50), np.uint8)
    cv2.line(e, (5, 10), (40, 10), 255, 1)
    cv2.line(e, (42, 12), (42, 40), 255, 1)
    lines, closed = polylines_from_edges(e)
    assert len(lines) == 2 and not any(closed)
    merged, flags = merge_close(lines, closed, tol=3.0)
    assert len(merged) == 1 and len(merged[0]) >= len(lines[0]) + len(lines[1]) - 2 and not flags[0]


def test_nesting_flips_the_inner_curve():
    t = np.linspace(0, 2 * np.pi, 100, endpoint=False)
    outer = np.stack([np.cos(t), np.sin(t)], 1) * 10
    inner = outer[::-1] * 0.3
    out = orient_by_nesting([outer, inner])
    assert signed_area(out[0]) > 0 > signed_area(out[1])


def test_winding_node_outputs_grid_and_mask_and_skips_bad_images():
    with Harness(WindingNode, params=dict(source="mask")) as h:
        h.feed([(0.1, "image", Image(data=_ring_and_box())), (0.2, "image", Image(data=np.zeros((0, 0), np.uint8)))])
    (grid,), (mask,) = h.of("winding"), h.of("inside")
    assert grid.data.shape == (200, 300) and grid.data.dtype == np.float32 and grid.data[100, 50] == 1.0
    assert mask.data[100, 100] == 0 and mask.data[100, 240] == 255
    with pytest.raises(ConfigError):
        WindingNode.make_config({"source": "lidar"})
