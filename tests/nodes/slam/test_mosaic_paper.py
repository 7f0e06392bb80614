"""Seed 08's experiment: one large image cut into eight overlapping sub-images visited
1-2-3-4 / 8-7-6-5; chaining the consecutive registrations drifts, the pose graph with the
loop closures (1-8, 2-7, 3-6 and the diagonals the gate accepts) does not."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from nodes.slam import fourier, mosaic
from nodes.slam.pose_graph import between
from sim.subimages import ORDER, SIZE, seafloor, subimage_scene

def experiment(seed: int, rotate: bool) -> tuple[float, float, float, mosaic.Links]:
    scene = subimage_scene(seed, rotate=rotate)
    links = mosaic.register_all(scene.images, prior=scene.nav, known_angles=not rotate,
                                angle_search=math.radians(3) if rotate else 0.0)
    chained = mosaic.chain(links, len(scene.images), scene.truth[0], prior=scene.nav)
    graph = mosaic.solve(links, len(scene.images), chained).poses

    def rmse(poses: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.sum((poses[:, :2] - scene.truth[:, :2]) ** 2, axis=1))))

    return rmse(scene.nav), rmse(chained), rmse(graph), links


def test_relative_pose_inverts_the_expected_registration():
    rng = np.random.default_rng(0)
    big = seafloor(rng)
    a, b = np.array([300.0, 250.0, 0.2]), np.array([420.0, 300.0, -0.1])
    reg = fourier.register(mosaic.cut(big, a, SIZE), mosaic.cut(big, b, SIZE), angle_hint=-0.3,
                           shift_hint=mosaic.expected_registration(a, b)[1])
    z, cov = mosaic.relative_pose(reg)
    assert np.allclose(z, between(a, b), atol=[0.3, 0.3, 1e-9])
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def test_without_rotations_the_graph_removes_the_chain_drift():
    results = [experiment(seed, rotate=False) for seed in range(3)]
    nav, chained, graph = (np.mean([r[k] for r in results]) for k in range(3))
    assert graph < 1.0 and graph < chained / 3 and graph < nav / 10
    assert all(len(r[3].kept) >= 10 for r in results)                  # the closures were found


@pytest.mark.slow
def test_with_rotations_the_graph_stays_within_two_pixels():
    results = [experiment(seed, rotate=True) for seed in range(3)]
    nav, chained, graph = (np.mean([r[k] for r in results]) for k in range(3))
    assert graph < 2.0 and graph < chained and graph < nav / 5


def test_mosaic_blends_without_seams_where_images_overlap():
    rng = np.random.default_rng(1)
    big = seafloor(rng)
    poses = np.array([[220 + 160 * c, 220 + 160 * r, 0.0] for r, c in ORDER])
    images = [mosaic.cut(big, p, SIZE) for p in poses]
    image, weight, (x0, y0) = mosaic.compose_mosaic(images, poses)
    inner = weight > 0.5
    v, u = np.mgrid[:image.shape[0], :image.shape[1]].astype(np.float32)
    truth = cv2.remap(big, u + np.float32(x0), v + np.float32(y0), cv2.INTER_LINEAR)   # mosaic pixel -> world
    assert np.abs(image[inner] - truth[inner]).mean() < 0.01             # the same picture, no seam
    assert weight[0].max() < 0.2 and weight[:, 0].max() < 0.2               # feathered to the images' edges
    lone, lone_weight, _ = mosaic.compose_mosaic(images[:1] + images[3:4], poses[[0, 3]])
    assert lone_weight.min() == 0.0 and lone[lone_weight == 0].max() == 0.0   # a gap stays empty
