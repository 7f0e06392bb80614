"""Decentralised place recognition (Cieslewski & Scaramuzza, "Efficient decentralized visual place
recognition from full-image descriptors", MRS 2017): the descriptor space is cut into R
clusters by k-means on training data and robot r keeps cluster r. A robot sends each
keyframe's descriptor to the *one* robot whose cluster centre is nearest; that robot stores
it and answers with the nearest stored descriptor of each other robot within ``threshold``
(eq. 3 of seed 10). Data association then costs one descriptor per keyframe, not R - 1.

In simulation the descriptor stands in for NetVLAD: random Fourier features of the
keyframe's true position (a place), plus noise, so places a few metres apart look alike
and far ones do not. The cluster centres are trained on a separate seeded random walk,
never on the evaluation graph.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.cluster.vq import kmeans2


@dataclass(frozen=True)
class Describer:
    """Random Fourier features of a 2-D position: ``dim`` values, length scale ``scale_m``."""

    dim: int = 32
    scale_m: float = 3.0
    noise: float = 0.05
    seed: int = 7

    def _basis(self) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng(self.seed)
        return rng.normal(0.0, 1.0 / self.scale_m, (self.dim, 2)), rng.uniform(0, 2 * np.pi, self.dim)

    def describe(self, xy: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """(..., dim) unit-norm float16 descriptors of (..., 2) positions in metres."""
        w, b = self._basis()
        v = np.cos(np.asarray(xy, float) @ w.T + b)
        if rng is not None and self.noise > 0:
            v = v + rng.normal(0.0, self.noise, v.shape)
        v /= np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)
        return v.astype(np.float16)

    def train_centres(self, clusters: int, *, samples: int = 4000, extent_m: float = 100.0) -> np.ndarray:
        """(clusters, dim) k-means centres from descriptors of a seeded random walk (not the evaluation data)."""
        rng = np.random.default_rng(self.seed + 1)
        walk = np.cumsum(rng.normal(0.0, 1.0, (samples, 2)), axis=0)
        walk = (walk - walk.min(0)) / np.maximum(np.ptp(walk, axis=0), 1e-9) * extent_m
        data = self.describe(walk, rng).astype(np.float64)
        if clusters == 1:
            return data.mean(0, keepdims=True)
        centres, _ = kmeans2(data, clusters, seed=np.random.default_rng(self.seed + 2), minit="++")
        return centres


def keeper_of(descriptor: np.ndarray, centres: np.ndarray) -> int:
    """The robot that keeps the cluster nearest ``descriptor``."""
    d = np.asarray(descriptor, float)
    return int(np.argmin(((centres - d) ** 2).sum(axis=1)))


class PlaceIndex:
    """What a cluster's keeper stores: every descriptor it was sent, shelved by robot (each shelf a
    buffer that doubles when full, so storing is amortised O(1) and a query reads arrays, not lists)."""

    def __init__(self, threshold: float = 0.5) -> None:
        self.threshold = threshold
        self._vertices: dict[int, list[int]] = {}
        self._rows: dict[int, np.ndarray] = {}
        self._seen: set[tuple[int, int]] = set()

    def query(self, robot: int, vertex: int, descriptor: np.ndarray) -> list[tuple[int, int, float]]:
        """Store the descriptor; return, for each *other* robot, its nearest stored keyframe within the
        threshold as (robot, vertex, distance), nearest first. (Cieslewski's keeper answers with the
        single best match; a place a third robot also saw would then be found with one of them only.)
        A keyframe sent twice is stored once."""
        d = np.asarray(descriptor, np.float32)
        found: list[tuple[int, int, float]] = []
        for other, vertices in self._vertices.items():
            if other == robot:
                continue
            dist = np.linalg.norm(self._rows[other][:len(vertices)] - d, axis=1)
            k = int(np.argmin(dist))
            if dist[k] < self.threshold:
                found.append((other, vertices[k], float(dist[k])))
        if (robot, vertex) not in self._seen:
            self._seen.add((robot, vertex))
            vertices = self._vertices.setdefault(robot, [])
            rows = self._rows.get(robot)
            if rows is None or len(rows) == len(vertices):
                grown = np.zeros((max(16, 2 * len(vertices)), d.size), np.float32)
                if rows is not None:
                    grown[:len(vertices)] = rows
                self._rows[robot] = rows = grown
            rows[len(vertices)] = d
            vertices.append(vertex)
        return sorted(found, key=lambda f: f[2])

    def __len__(self) -> int:
        return len(self._seen)


# -- the exchange: what each robot sends and answers ----------------------------------------------------
@dataclass
class PlaceQueryItem:
    robot: int
    vertex: int
    descriptor: np.ndarray


@dataclass
class PlaceMatchItem:
    """The keeper's answer; ``match_robot`` -1 acknowledges a query with no match."""

    robot: int
    vertex: int
    match_robot: int
    match_vertex: int
    distance: float


@dataclass
class RelPoseRequestItem:
    vertex: int
    match_vertex: int


@dataclass
class RelPoseReply:
    """Closures a registration produced (possibly none), answering ``request`` (vertex, match_vertex)."""

    request: tuple[int, int]
    closures: list[tuple[int, int, np.ndarray, np.ndarray]]


@dataclass
class Registration:
    """What registering own keyframe ``vertex`` against ``peer_vertex`` of robot ``peer`` gives (the
    simulated sensor): closure (a, b, z, info) as measured."""

    peer: int
    peer_vertex: int
    closure: tuple[int, int, np.ndarray, np.ndarray]


class PlaceFrontEnd:
    """One robot's side of decentralised place recognition and relative-pose estimation.

    Queries and relative-pose requests are sent again every ``retry_rounds`` rounds until
    answered, so a robot out of range catches up when it is back. Registering keyframe i
    of the asker against keyframe j tries the receiver's keyframes j +- ``window`` (the
    matched frame's neighbours, as a visual front end would).
    """

    def __init__(self, robot: int, centres: np.ndarray, *, threshold: float = 0.5, window: int = 2,
                 retry_rounds: int = 3) -> None:
        self.robot, self.centres = robot, np.asarray(centres, float)
        self.window, self.retry_rounds = window, retry_rounds
        self.index = PlaceIndex(threshold=threshold)
        self._descriptors: dict[int, np.ndarray] = {}
        self._registrations: dict[int, list[Registration]] = {}
        self._unanswered: dict[int, int] = {}                         # own vertex -> rounds since sent
        self._requests: dict[tuple[int, int, int], int] = {}          # (robot, vertex, match_vertex) -> age
        self._outbox: dict[int, list] = {}
        self.sent_queries = 0
        self.matches = 0

    def add(self, vertex: int, descriptor: np.ndarray, registrations: list[Registration] = ()) -> None:
        self._descriptors[vertex] = np.asarray(descriptor, np.float16)
        self._registrations.setdefault(vertex, []).extend(registrations)
        self._unanswered[vertex] = self.retry_rounds                  # due now

    def receive(self, sender: int, item) -> list[tuple[int, int, np.ndarray, np.ndarray, int]]:
        """Handle one item; returns closures learnt (a, b, z, info, peer robot)."""
        if isinstance(item, PlaceQueryItem):
            self._answer_query(item)
        elif isinstance(item, PlaceMatchItem):
            self._unanswered.pop(item.vertex, None)
            if item.match_robot >= 0 and item.match_robot != self.robot:
                self.matches += 1
                self._requests.setdefault((item.match_robot, item.vertex, item.match_vertex), self.retry_rounds)
        elif isinstance(item, RelPoseRequestItem):
            reply = self._register(sender, item)
            self._send(sender, reply)
            return [(a, b, z, w, sender) for a, b, z, w in reply.closures]
        elif isinstance(item, RelPoseReply):
            self._requests.pop((sender, *item.request), None)
            return [(a, b, z, w, sender) for a, b, z, w in item.closures]
        return []

    def _answer_query(self, item: PlaceQueryItem) -> None:
        found = self.index.query(item.robot, item.vertex, item.descriptor)
        answers = [PlaceMatchItem(item.robot, item.vertex, r, v, d) for r, v, d in found] or \
            [PlaceMatchItem(item.robot, item.vertex, -1, -1, -1.0)]          # an acknowledgement: no match
        for answer in answers:
            if item.robot == self.robot:
                self.receive(self.robot, answer)
            else:
                self._send(item.robot, answer)

    def _register(self, asker: int, item: RelPoseRequestItem) -> RelPoseReply:
        lo, hi = item.vertex - self.window, item.vertex + self.window
        found = []
        for v in range(item.match_vertex - self.window, item.match_vertex + self.window + 1):
            for reg in self._registrations.get(v, ()):
                if reg.peer == asker and lo <= reg.peer_vertex <= hi:
                    found.append(reg.closure)
        return RelPoseReply((item.vertex, item.match_vertex), found)

    def _send(self, robot: int, item) -> None:
        self._outbox.setdefault(robot, []).append(item)

    def tick(self) -> dict[int, list]:
        """Queries and requests due this round (new or unanswered for ``retry_rounds``), and answers."""
        for vertex, age in list(self._unanswered.items()):
            if age >= self.retry_rounds:
                keeper = keeper_of(self._descriptors[vertex], self.centres)
                query = PlaceQueryItem(self.robot, vertex, self._descriptors[vertex])
                self._unanswered[vertex] = 0                 # before answering ourselves, which clears it
                if keeper == self.robot:
                    self._answer_query(query)
                else:
                    self.sent_queries += 1
                    self._send(keeper, query)
            else:
                self._unanswered[vertex] = age + 1
        for key, age in list(self._requests.items()):
            if age >= self.retry_rounds:
                self._send(key[0], RelPoseRequestItem(key[1], key[2]))
                self._requests[key] = 0
            else:
                self._requests[key] = age + 1
        out, self._outbox = self._outbox, {}
        return out
