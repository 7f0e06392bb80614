"""Multi-robot SLAM messages: what decentralised agents say to each other, and what they publish.

One :class:`PeerPacket` per round and per receiver carries a list of items, each a small
tagged struct (not a message: no header of its own). Vertex ids are int32 and numbers
float32 on the wire -- ample for poses (1e-5 m at 100 m) and information matrices -- and
every baseline in ``bench/dslam.py`` is encoded the same way.
"""
from __future__ import annotations

from typing import Union

import msgspec
import numpy as np

from tether.message import Message, const


class _Item(msgspec.Struct, frozen=True, kw_only=True, tag_field="kind", array_like=True):
    pass


class ClosureSet(_Item, tag="closures"):
    """Inter-robot closures as measured (pose of ``ids[:, 1]`` in ``ids[:, 0]``'s frame);
    ``accepted`` is the PCM decision when ``decision`` is set."""

    ids: np.ndarray               # (C, 2) int32
    z: np.ndarray                 # (C, 3) float32: dx_m, dy_m, dtheta_rad
    info: np.ndarray              # (C, 6) float32: information upper triangle, g2o order
    accepted: np.ndarray          # (C,) bool
    decision: bool = False
    request: list[int] = []       # answering a RelPoseRequest: [vertex, match_vertex] (empty otherwise)
    third_party: bool = False     # the sender's whole current set of the closures it decided with others


class CondensedGraph(_Item, tag="condensed"):
    """A robot's condensed graph in its own frame (see nodes.slam.dslam.Condensed)."""

    robot: int
    version: int
    ids: np.ndarray               # (K,) int32: the robot's first pose first
    edges: np.ndarray             # (E, 2) int32 rows of ids
    z: np.ndarray                 # (E, 3) float32
    info: np.ndarray              # (E, 6) float32
    base: int = -1                # >= 0: a delta on version ``base``: edges added or changed, and
    removed: np.ndarray = const(np.zeros((0, 3), np.int32))   # (R, 3) keys (id_a, id_b, n) of edges gone
    nth: np.ndarray = const(np.zeros(0, np.int32))            # delta: the n of each edge's key (empty: all 0)


class SeparatorValues(_Item, tag="separators"):
    """Estimates of the sender's separators: rotation vectors (phase 1), translations (2) or poses (3)."""

    phase: int
    ids: np.ndarray               # (K,) int32
    values: np.ndarray            # (K, 2 or 3) float32
    converged: bool = False


class PlaceQuery(_Item, tag="place_query"):
    """A keyframe's place descriptor, sent to the one robot whose cluster centre is nearest."""

    robot: int
    vertex: int
    descriptor: np.ndarray        # (D,) float16


class PlaceMatch(_Item, tag="place_match"):
    """The cluster's keeper found a stored descriptor of another robot close to a query."""

    robot: int                    # who asked
    vertex: int
    match_robot: int
    match_vertex: int
    distance: float


class RelPoseRequest(_Item, tag="relpose_request"):
    """Asks the matched robot for the relative pose between its keyframe and ours."""

    vertex: int                   # the asker's keyframe
    match_vertex: int             # the receiver's keyframe


PeerItem = Union[ClosureSet, CondensedGraph, SeparatorValues, PlaceQuery, PlaceMatch, RelPoseRequest]


class PeerPacket(Message, tag="slam.PeerPacket"):
    """What one agent sends one peer in a round."""

    sender: int = 0
    receiver: int = 0
    gauge_root: int = 0
    epoch: int = 0                # the sender's start count: a new epoch means it restarted and lost what it was told
    ack: list[int] = []           # what the sender holds from the receiver: [its decided closures with us,
    #                               its condensed graph's version, the closures of other pairs it told us of]
    items: list[PeerItem] = []


class RobotTrajectory(Message, tag="slam.RobotTrajectory"):
    """A robot's keyframe poses in the team frame (that of robot ``gauge_root``'s first pose)."""

    robot: int = 0
    gauge_root: int = 0           # == robot: it is tied to no lower-numbered robot (its own frame)
    ids: np.ndarray = const(np.zeros(0, np.int64))
    poses: np.ndarray = const(np.zeros((0, 3)))          # (N, 3) x_m, y_m, theta_rad
    closures_accepted: int = 0
    closures_rejected: int = 0
    rounds: int = 0
    accepted: np.ndarray = const(np.zeros((0, 2), np.int64))   # (C, 2) inter-robot closures in use (vertex ids)
    rejected: np.ndarray = const(np.zeros((0, 2), np.int64))   # (C, 2) candidates turned down (PCM or GNC)
