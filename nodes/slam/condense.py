"""Condensing a robot's pose graph for its peers (DDF-SAM's condensed graph), and sending it as
changes once a peer holds a version."""
from __future__ import annotations

import math

import numpy as np

from nodes.slam.exchange import Condensed, info_from6
from nodes.slam.pose_graph import PoseGraph2D, adjoint, between, spanning_tree_poses, wrap


def condense_exact(ids: list[int], odometry: list[np.ndarray], odometry_info: list[np.ndarray],
                   intra: list[tuple[int, int, np.ndarray, np.ndarray]], separators: list[int], *,
                   max_run: int = 0) -> tuple[list[int], np.ndarray, np.ndarray, np.ndarray]:
    """Eliminate every keyframe that only sits on the odometry chain: each run of odometry
    edges between kept keyframes becomes one edge (measurements composed, covariance
    propagated, Sigma <- Ad(z_k^-1) Sigma Ad(z_k^-1)^T + Sigma_k -- exact for the linearised
    problem). Kept: the first pose, the separators and the ends of intra-robot closures
    (eliminating those too would fill the graph in densely). Returns (ids, edges (E, 2) rows
    of ids, z (E, 3), info (E, 3, 3)); a chain that runs past the last kept keyframe adds nothing."""
    keep = set(separators) | {a for a, _, _, _ in intra} | {b for _, b, _, _ in intra} | {ids[0]}
    if max_run > 0:                    # also keep every max_run-th keyframe: shorter runs, smaller linearisation error
        keep |= set(ids[::max_run])
    kept = [v for v in ids if v in keep]
    row = {v: k for k, v in enumerate(kept)}
    edges, zs, infos = [], [], []
    n = len(ids)
    if n > 1:
        z_all = np.asarray(odometry[1:], float).reshape(-1, 3)
        cov_all = np.linalg.inv(np.asarray(odometry_info[1:], float).reshape(-1, 3, 3))   # batched: once per call
        adj = adjoint(between(z_all, np.zeros_like(z_all)))                            # Ad(z_k^-1)
        x = y = t = 0.0
        cov_acc, start = np.zeros((3, 3)), 0
        for k in range(1, n):
            dx, dy, dt = z_all[k - 1]
            ct, st = math.cos(t), math.sin(t)
            x, y, t = x + ct * dx - st * dy, y + st * dx + ct * dy, t + dt
            a_k = adj[k - 1]
            cov_acc = a_k @ cov_acc @ a_k.T + cov_all[k - 1]
            if ids[k] in row:
                edges.append((row[ids[start]], row[ids[k]]))
                zs.append((x, y, wrap(t)))
                infos.append(cov_acc)
                x = y = t = 0.0
                cov_acc, start = np.zeros((3, 3)), k
        infos = list(np.linalg.inv(np.array(infos).reshape(-1, 3, 3))) if infos else []
    for a, b, z, w in intra:
        edges.append((row[a], row[b]))
        zs.append(z)
        infos.append(w)
    return (kept, np.array(edges, np.int64).reshape(-1, 2), np.array(zs, float).reshape(-1, 3),
            np.array(infos, float).reshape(-1, 3, 3))


def edge_table(item: Condensed) -> dict[tuple[int, int, int], np.ndarray]:
    """A condensed graph's edges by key (id_a, id_b, n-th of that pair) -> z (3) and info (6)."""
    ids = np.asarray(item.ids).tolist()
    table: dict[tuple[int, int, int], np.ndarray] = {}
    for (a, b), z, v in zip(np.asarray(item.edges).reshape(-1, 2).tolist(), np.asarray(item.z).reshape(-1, 3),
                            np.asarray(item.info).reshape(-1, 6)):
        n = 0
        while (ids[a], ids[b], n) in table:
            n += 1
        table[(ids[a], ids[b], n)] = np.concatenate([z, v])
    return table


def same_table(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def delta(current: Condensed, base_table: dict, base: int, table: dict | None = None) -> Condensed:
    """``current`` as changes on top of the version whose edge table is ``base_table``."""
    table = edge_table(current) if table is None else table
    changed = [k for k, v in table.items() if k not in base_table or not np.array_equal(base_table[k], v)]
    removed = [k for k in base_table if k not in table]
    ids = sorted({k[0] for k in changed} | {k[1] for k in changed})
    row = {v: r for r, v in enumerate(ids)}
    values = np.array([table[k] for k in changed]).reshape(-1, 9)
    return Condensed(robot=current.robot, version=current.version, ids=np.array(ids, np.int64),
                     poses=np.zeros((len(ids), 3)),
                     edges=np.array([(row[k[0]], row[k[1]]) for k in changed], np.int64).reshape(-1, 2),
                     z=values[:, :3], info=values[:, 3:], base=base,
                     removed=np.array(removed, np.int64).reshape(-1, 3),
                     nth=np.array([k[2] for k in changed], np.int64) if any(k[2] for k in changed) else np.zeros(0, np.int64))


def apply_delta(old: Condensed, change: Condensed) -> Condensed:
    """The whole condensed graph from the one held (``old``, version ``change.base``) and a delta."""
    table = edge_table(old)
    for key in np.asarray(change.removed).reshape(-1, 3).tolist():
        table.pop(tuple(key), None)
    ids_c = np.asarray(change.ids).tolist()
    nth = np.asarray(change.nth).reshape(-1).tolist() or [0] * len(change.edges)
    for (a, b), n, z, v in zip(np.asarray(change.edges).reshape(-1, 2).tolist(), nth, np.asarray(change.z).reshape(-1, 3),
                               np.asarray(change.info).reshape(-1, 6)):
        table[(ids_c[a], ids_c[b], int(n))] = np.concatenate([z, v])
    root = int(old.ids[0])
    ids = [root] + sorted({v for k in table for v in k[:2]} - {root})
    row = {v: r for r, v in enumerate(ids)}
    keys = list(table)
    values = np.array([table[k] for k in keys]).reshape(-1, 9)
    edges = np.array([(row[k[0]], row[k[1]]) for k in keys], np.int64).reshape(-1, 2)
    return Condensed(robot=old.robot, version=change.version, ids=np.array(ids, np.int64),
                     poses=condensed_poses(np.array(ids, np.int64), edges, values[:, :3]), edges=edges,
                     z=values[:, :3], info=values[:, 3:])


def condensed_poses(ids: np.ndarray, edges: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(K, 3) poses composed along a condensed graph's edges from its first vertex (its odometry)."""
    g = PoseGraph2D(ids=np.asarray(ids, np.int64), poses=np.zeros((len(ids), 3)), edges=np.asarray(edges, np.int64).reshape(-1, 2),
                    z=np.asarray(z, float).reshape(-1, 3), info=np.tile(np.eye(3), (len(edges), 1, 1)),
                    known=np.zeros(len(ids), bool))
    return spanning_tree_poses(g, root=0) if len(ids) else np.zeros((0, 3))


def condensed_graph(item: Condensed) -> PoseGraph2D:
    """The condensed graph as a pose graph (its own frame)."""
    return PoseGraph2D(ids=np.asarray(item.ids, np.int64), poses=np.asarray(item.poses, float),
                       edges=np.asarray(item.edges, np.int64).reshape(-1, 2), z=np.asarray(item.z, float).reshape(-1, 3),
                       info=info_from6(np.asarray(item.info).reshape(-1, 6)), known=np.ones(len(item.ids), bool))
