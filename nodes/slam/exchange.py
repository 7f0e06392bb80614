"""What decentralised SLAM agents exchange, as plain data (the node maps each one to one onto
msgs.slam), and the closure record every agent keeps."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nodes.slam.pose_graph import adjoint, between

_IU = np.triu_indices(3)


def info_to6(info: np.ndarray) -> np.ndarray:
    """(..., 3, 3) symmetric information -> (..., 6) upper triangle, row by row (g2o's order)."""
    return np.asarray(info)[..., _IU[0], _IU[1]]


def info_from6(v: np.ndarray) -> np.ndarray:
    """(..., 6) upper triangle -> (..., 3, 3) symmetric."""
    v = np.asarray(v, float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., _IU[0], _IU[1]] = v
    out[..., _IU[1], _IU[0]] = v
    return out


# -- what travels (the node maps these one to one onto msgs.slam) ----------------------------------
@dataclass
class Closures:
    """Inter-robot closures: ``ids`` (C, 2) vertex ids (from, to), ``z`` (C, 3), ``info`` (C, 6).
    ``accepted`` (C,) is the PCM decision of the pair's lower-numbered robot (all True when
    the closures are only reported)."""

    ids: np.ndarray
    z: np.ndarray
    info: np.ndarray
    accepted: np.ndarray
    decision: bool = False
    third_party: bool = False         # the sender's whole current set of closures between it and others


@dataclass
class Condensed:
    """A robot's condensed graph: vertex ``ids`` (K,) -- its first pose first, then in trajectory
    order -- with ``edges`` (E, 2) as rows of ``ids``, measurements ``z`` (E, 3) and ``info``
    (E, 6). ``poses`` (K, 3), a starting point in the robot's frame, stays home: the receiver
    composes its own from the edges (:func:`condensed_poses`). A robot's graph grows while it
    drives; once a peer holds a version, the next one travels as a delta (``base``)."""

    robot: int
    version: int
    ids: np.ndarray
    poses: np.ndarray
    edges: np.ndarray
    z: np.ndarray
    info: np.ndarray
    base: int = -1                    # >= 0: only what changed since version ``base`` (edges added or changed,
    removed: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))   # and (a, b, n) keys gone)
    nth: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))   # delta: n of each edge's key (empty: 0)


@dataclass
class Separators:
    """Current estimates of the sender's separators the receiver needs: ``values`` (K, 2)
    rotation vectors in phase 1, translations in phase 2, poses (K, 3) in phase 3."""

    phase: int
    ids: np.ndarray
    values: np.ndarray
    converged: bool


@dataclass
class Packet:
    """One round's items from ``sender`` to ``receiver``."""

    sender: int
    receiver: int
    gauge_root: int
    items: list = field(default_factory=list)
    epoch: int = 0
    ack: tuple[int, int, int] = (0, 0, 0)   # what the sender holds from the receiver: decided closures,
    #                                         its condensed graph's version, closures it decided with others


@dataclass
class Candidate:
    """An edge as measured (pose of ``b`` in ``a``'s frame); for an inter-robot closure, which end is ours.

    Both robots keep a closure in its measured direction, so both minimise the same cost
    (reversing it would change its information to first order only, and two robots
    optimising slightly different costs drift)."""

    a: int
    b: int
    z: np.ndarray
    info: np.ndarray  # (3, 3)
    own: int = -1
    peer_id: int = -1

    def from_own(self) -> tuple[np.ndarray, np.ndarray]:
        """(z, info) read from our end to the peer's."""
        if self.own == self.a:
            return self.z, self.info
        return between(self.z, np.zeros(3)), inverse_info(self.z, self.info)


def inverse_info(z: np.ndarray, info: np.ndarray) -> np.ndarray:
    """Information of the same closure read backwards (measurement z^-1).

    The residual of the reversed edge is e' = -Ad(z) e to first order (Ad(z) = [[R, (y, -x)^T], [0, 1]],
    SE(2)'s adjoint), so its information is Ad^-T info Ad^-1."""
    inv = np.linalg.inv(adjoint(z))
    return inv.T @ info @ inv
