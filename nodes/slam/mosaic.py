"""Image mosaics from Fourier registration and a pose graph (seed 08, sections IV-V).

Poses of images are in *pixel* units of a common mosaic plane: ``(x, y, theta)`` with x
along columns, y along rows (down) and theta a rotation in those coordinates (clockwise
as displayed, since y points down). An image with pose ``(x, y, theta)`` shows the world
point ``(x, y) + R(theta) (p - c)`` at its pixel ``p``, ``c`` being its centre.

* :func:`relative_pose` turns a :class:`nodes.slam.fourier.Registration` of image j
  against image i into the pose of j in i's frame (the pose graph's measurement, eq. 4);
* :func:`register_all` registers the consecutive pairs (chaining) and every other pair
  that passes the peak-to-noise gate (loop closures), as the seed does;
* :func:`chain` composes the consecutive measurements; :func:`solve` optimises the graph;
* :func:`compose_mosaic` blends the images at their poses with feathered weights, so the
  edge of one image leaves no seam on another.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import cv2
import numpy as np

from nodes.slam import fourier
from nodes.slam.pose_graph import OptimizeResult, PoseGraph2D, between, compose, optimize

#: Floors added to a registration's covariance: its own estimate is optimistic when the
#: images differ by more than noise (partial overlap, occlusion, the fan's edges,
#: interpolation); the angle's is one bin of the polar spectrum (0.25 degree).
COV_FLOOR_PX2 = 0.3 ** 2
COV_FLOOR_RAD2 = math.radians(0.25) ** 2


def rot(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def relative_pose(reg: fourier.Registration) -> tuple[np.ndarray, np.ndarray]:
    """(z, covariance) of image j in image i's frame from ``register(image_i, image_j)``.

    With ``fourier.warp``'s convention (cv2's rotation, A(a) = R(-a) in pixel coordinates),
    image j = warp(image i, a, t) when theta_j - theta_i = a and t = -R(-theta_j)(c_j - c_i),
    so in i's frame the translation is -R(a) t.
    """
    a = reg.angle
    t = np.array([reg.dx, reg.dy])
    z = np.array([*(-rot(a) @ t), a])
    var_a = reg.covariance[2, 2] + COV_FLOOR_RAD2
    # z_t = -R(a) t: the angle's error moves the translation by -R'(a) t (a lever of |t|).
    lever = -np.array([[-math.sin(a), -math.cos(a)], [math.cos(a), -math.sin(a)]]) @ t
    jac = np.zeros((3, 3))
    jac[:2, :2], jac[:2, 2], jac[2, 2] = -rot(a), lever, 1.0
    source = np.zeros((3, 3))
    source[:2, :2] = reg.covariance[:2, :2] + COV_FLOOR_PX2 * np.eye(2)
    source[2, 2] = var_a
    return z, jac @ source @ jac.T


@dataclass
class Link:
    i: int
    j: int
    z: np.ndarray
    covariance: np.ndarray
    pnr: float
    sequential: bool


@dataclass
class Links:
    """Every registration tried: kept constraints, and the pairs the gate refused (with their PNR)."""

    kept: list[Link] = field(default_factory=list)
    refused: list[tuple[int, int, float]] = field(default_factory=list)


def register_all(images: Sequence[np.ndarray], masks: Sequence[np.ndarray | None] | None = None, *,
                 prior: np.ndarray | None = None, candidates: Sequence[tuple[int, int]] | None = None,
                 min_pnr: float = 8.0, min_shared: float = 0.25, known_angles: bool = False,
                 angle_search: float = 0.0, progress: Callable[[int, int], None] | None = None) -> Links:
    """Register consecutive images and the ``candidates`` pairs (default: every other pair
    that ``prior`` poses say overlap by at least ``min_shared`` of the image), keeping those
    that pass :func:`fourier.is_reliable`. ``prior`` (N, 3) poses in pixel units give each
    registration its hints; ``known_angles``: trust the prior's angles and estimate the
    translation only; ``angle_search`` (rad): refine each prior angle within +- this
    (a compass-grade prior; see :func:`fourier.register`)."""
    n = len(images)
    masks = list(masks) if masks is not None else [None] * n
    pairs = [(k, k + 1) for k in range(n - 1)]
    if candidates is None:
        candidates = [(i, j) for i in range(n) for j in range(i + 2, n)]
        if prior is not None:
            candidates = [(i, j) for i, j in candidates
                          if shared_fraction(images[i].shape, prior[i], prior[j]) >= min_shared]
    pairs += [p for p in candidates if p not in pairs]
    out = Links()
    for done, (i, j) in enumerate(pairs):
        angle_hint = shift_hint = None
        if prior is not None:
            angle, shift_hint = expected_registration(prior[i], prior[j])
            angle_hint = angle if known_angles or angle_search > 0 else None
        reg = fourier.register(images[i], images[j], fixed_mask=masks[i], moving_mask=masks[j],
                               angle_hint=angle_hint, shift_hint=shift_hint, angle_search=angle_search)
        if fourier.is_reliable(reg, min_pnr=min_pnr):
            z, cov = relative_pose(reg)
            out.kept.append(Link(i, j, z, cov, reg.pnr, sequential=(j == i + 1)))
        else:
            out.refused.append((i, j, reg.pnr))
        if progress is not None:
            progress(done + 1, len(pairs))
    return out


def chain(links: Links, n: int, start: np.ndarray, *, prior: np.ndarray | None = None) -> np.ndarray:
    """Poses by composing consecutive measurements from ``start``; where a consecutive pair
    was refused, the step of ``prior`` poses (navigation) is used, else the chain stops (NaN)."""
    poses = np.full((n, 3), np.nan)
    poses[0] = start
    step = {(l.i, l.j): l.z for l in links.kept if l.sequential}
    for k in range(n - 1):
        z = step.get((k, k + 1))
        if z is None and prior is not None:
            z = between(prior[k], prior[k + 1])
        if z is None:
            break
        poses[k + 1] = compose(poses[k], z)
    return poses


def expected_registration(pose_i: np.ndarray, pose_j: np.ndarray) -> tuple[float, tuple[float, float]]:
    """The (angle, (dx, dy)) :func:`fourier.register` should find between images at these poses:
    the inverse of :func:`relative_pose` (a hint from navigation or the current estimate)."""
    z = between(pose_i, pose_j)
    t = -rot(z[2]).T @ z[:2]
    return float(z[2]), (float(t[0]), float(t[1]))


def shared_fraction(shape: tuple[int, ...], pose_i: np.ndarray, pose_j: np.ndarray) -> float:
    """Rough fraction of an image two poses share (axis-aligned, from the centre distance)."""
    h, w = shape[:2]
    d = np.abs(rot(-pose_i[2]) @ (pose_j[:2] - pose_i[:2]))
    return float(max(0.0, 1 - d[0] / w) * max(0.0, 1 - d[1] / h))


def graph_of(links: Links, n: int, initial: np.ndarray) -> PoseGraph2D:
    edges = [(l.i, l.j, tuple(l.z), np.linalg.inv(l.covariance)) for l in links.kept]
    graph = PoseGraph2D.from_edges(edges, {k: tuple(initial[k]) for k in range(n)})
    return graph


def solve(links: Links, n: int, initial: np.ndarray, *, robust: str | None = "gnc") -> OptimizeResult:
    """Optimise the poses (image 0 anchored at ``initial[0]``), false closures rejected by GNC."""
    graph = graph_of(links, n, initial)
    return optimize(graph, initial=graph.poses, robust=robust if any(not l.sequential for l in links.kept) else None)


def compose_mosaic(images: Sequence[np.ndarray], poses: np.ndarray, *, masks: Sequence[np.ndarray | None] | None = None,
                   scale: float = 1.0, feather_px: float = 16.0) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """Blend ``images`` at ``poses`` on one canvas: (mosaic, weight, (x0, y0) of the canvas origin in pose units).

    Each image's weight falls to zero at its (mask's) edge over ``feather_px``, so seams
    do not show; pixels no image covers have weight 0 (and value 0).
    """
    masks = list(masks) if masks is not None else [None] * len(images)
    corners = []
    for img, pose in zip(images, poses):
        h, w = img.shape
        c = np.array([(w - 1) / 2, (h - 1) / 2])
        for p in ((0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)):
            corners.append(pose[:2] + rot(pose[2]) @ (np.array(p, float) - c))
    corners = np.array(corners)
    x0, y0 = corners.min(axis=0)
    width, height = (np.ceil((corners.max(axis=0) - corners.min(axis=0)) * scale) + 1).astype(int)
    acc = np.zeros((height, width), np.float64)
    wsum = np.zeros((height, width), np.float64)
    for img, pose, mask in zip(images, poses, masks):
        h, w = img.shape
        valid = np.ones((h, w), np.uint8) if mask is None else np.asarray(mask, np.uint8)
        border = np.pad(valid, 1)                                       # the image's own edge counts as an edge
        dist = cv2.distanceTransform(border, cv2.DIST_L2, 5)[1:-1, 1:-1]
        weight = np.clip(dist / feather_px, 0.0, 1.0).astype(np.float32)
        c = np.array([(w - 1) / 2, (h - 1) / 2])
        r = rot(pose[2]) * scale
        offset = (pose[:2] - np.array([x0, y0])) * scale - r @ c
        m = np.hstack([r, offset[:, None]]).astype(np.float32)
        acc += cv2.warpAffine(np.asarray(img, np.float32) * weight, m, (width, height), flags=cv2.INTER_LINEAR)
        wsum += cv2.warpAffine(weight, m, (width, height), flags=cv2.INTER_LINEAR)
    mosaic = np.where(wsum > 1e-6, acc / np.maximum(wsum, 1e-6), 0.0)
    return mosaic.astype(np.float32), wsum.astype(np.float32), (float(x0), float(y0))


def cut(big: np.ndarray, pose: np.ndarray, size: int) -> np.ndarray:
    """The ``size`` x ``size`` image an image at ``pose`` sees of ``big`` (the inverse of
    :func:`compose_mosaic`): seed 08's experiment cuts one large image this way."""
    c = np.array([(size - 1) / 2, (size - 1) / 2])
    r = rot(pose[2])
    m = np.hstack([r, (np.asarray(pose[:2], float) - r @ c)[:, None]]).astype(np.float32)
    return cv2.warpAffine(np.asarray(big, np.float32), m, (size, size), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP)
