"""Winding numbers of an image's contours on its pixel grid, and the inside mask (the
pure part of the winding node: contours from a mask or an edge map, merged, oriented)."""
from __future__ import annotations

import numpy as np

from nodes.shapes.contours import contours_from_mask, merge_close, orient_by_nesting, polylines_from_edges
from nodes.shapes.winding import winding_numbers

SOURCES = ("mask", "edges")


def pixel_centres(shape: tuple[int, int]) -> np.ndarray:
    """(H*W, 2) (x, y) of every pixel centre, row-major."""
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]]
    return np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)


def winding_image(image: np.ndarray, *, source: str = "mask", merge_px: float = 3.0) -> tuple[np.ndarray, int]:
    """(winding (H, W) float32, number of curves) of the contours of ``image`` (non-zero =
    region for ``mask``, edge pixels for ``edges``)."""
    if source not in SOURCES:
        raise ValueError(f"source must be one of {SOURCES}, got {source!r}")
    img = np.asarray(image)
    if img.ndim != 2 or img.size == 0:
        raise ValueError(f"expected a non-empty 2-D image, got shape {img.shape}")
    if source == "mask":
        curves, closed = contours_from_mask(img), None
    else:
        lines, flags = polylines_from_edges(img)
        lines, flags = merge_close(lines, flags, merge_px)
        curves = orient_by_nesting(lines)
        closed = flags
    if not curves:
        return np.zeros(img.shape, np.float32), 0
    w = winding_numbers(pixel_centres(img.shape), curves, True if closed is None else closed)
    return w.reshape(img.shape).astype(np.float32), len(curves)


def inside_mask(winding: np.ndarray, threshold: float = 0.5) -> np.ndarray:
    """w >= threshold: on a closed outline w = 1/2 (the pixel centres the outline runs through
    count as inside, except at convex corners); near a gap w falls smoothly."""
    return np.asarray(winding) >= threshold
