"""Seed 08 section VII: interval boxes of the image centres from the phase-correlation links."""
from __future__ import annotations

import numpy as np

from nodes.sets.mosaic_boxes import contract_mosaic, link_bounds
from nodes.slam import mosaic
from sim.subimages import subimage_scene


def _links(seed):
    sc = subimage_scene(seed, rotate=False)
    links = mosaic.register_all(sc.images, prior=sc.nav, known_angles=True)
    i, j = np.array([lk.i for lk in links.kept]), np.array([lk.j for lk in links.kept])
    z = np.array([lk.z[:2] for lk in links.kept])
    e = link_bounds(np.array([lk.covariance for lk in links.kept]))
    return sc, i, j, z, e


def test_boxes_hold_the_true_centres_and_closures_shrink_them():
    sc, i, j, z, e = _links(0)
    boxes = contract_mosaic(len(sc.images), i, j, z, e, sc.truth[0, :2])
    assert boxes.consistent and np.all(boxes.contains(sc.truth[:, :2]))
    seq = j == i + 1
    chain = contract_mosaic(len(sc.images), i[seq], j[seq], z[seq], e[seq], sc.truth[0, :2])
    w, w_chain = (boxes.hi - boxes.lo)[1:].mean(), (chain.hi - chain.lo)[1:].mean()
    assert np.all(chain.contains(sc.truth[:, :2])) and w < 0.7 * w_chain
    assert np.all(e >= 1.0)


def test_a_wrong_closure_empties_the_boxes():
    sc, i, j, z, e = _links(0)
    z = z.copy()
    z[-1] += 15.0                                                   # a closure 15 px off its bound
    boxes = contract_mosaic(len(sc.images), i, j, z, e, sc.truth[0, :2])
    assert not boxes.consistent
