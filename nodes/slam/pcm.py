"""Pairwise consistency maximisation (PCM, Mangelson et al., ICRA 2018) for inter-robot loop closures.

Two closures k, l between robots a and b are consistent when the cycle they close with
the robots' own trajectories returns to the start:

    e_kl = t2v( z_k^-1 (+) (x^a_ik^-1 x^a_il) (+) z_l (+) (x^b_jl^-1 x^b_jk) )  ~ 0,

tested as e^T Sigma^-1 e < gate with Sigma = Sigma_zk + Sigma_zl + Sigma^a_(ik,il) + Sigma^b_(jl,jk)
(each robot's relative covariance from its own joint marginals; the four are summed
without rotating them into one frame, PCM's usual first-order shortcut). The accepted
set is the largest clique of the consistency graph: false closures, drawn from perceptual
aliasing, disagree with the true ones and with each other.

The clique is found by Pattabiraman's greedy heuristic (grow from each vertex by the
candidate with most neighbours among the candidates, prune vertices whose degree cannot
beat the best). A set is accepted only when it holds at least ``min_clique`` mutually
consistent closures (default 2): a lone closure cannot be checked against anything, and
perceptual aliasing makes lone false closures common (with 30 % outliers spread over the
robot pairs, pairs that never met get exactly one, false, closure). ``min_clique=1``
trusts lone closures.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nodes.slam.pose_graph import CHI2_3DOF_99, between, compose, wrap


@dataclass
class Side:
    """One robot's view of its closure ends: poses (K, 3) of the ends in its own frame and
    their joint covariance (3K, 3K); ``end`` maps each closure to its row in ``poses``."""

    poses: np.ndarray
    covariance: np.ndarray
    end: np.ndarray


def relative(side: Side, k: np.ndarray, l: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Relative poses x_k^-1 x_l (P, 3) and their covariances (P, 3, 3) for closure pairs."""
    a, b = side.end[k], side.end[l]
    xa, xb = side.poses[a], side.poses[b]
    rel = between(xa, xb)
    # d rel / d x_a and d rel / d x_b (rel = R_a^T (t_b - t_a), theta_b - theta_a)
    c, s = np.cos(xa[:, 2]), np.sin(xa[:, 2])
    p = len(a)
    ja, jb = np.zeros((p, 3, 3)), np.zeros((p, 3, 3))
    ja[:, 0, 0], ja[:, 0, 1], ja[:, 1, 0], ja[:, 1, 1] = -c, -s, s, -c
    ja[:, 0, 2], ja[:, 1, 2], ja[:, 2, 2] = rel[:, 1], -rel[:, 0], -1.0
    jb[:, 0, 0], jb[:, 0, 1], jb[:, 1, 0], jb[:, 1, 1] = c, s, -s, c
    jb[:, 2, 2] = 1.0
    cov = side.covariance
    blk = lambda u, v: cov[(3 * u)[:, None, None] + np.arange(3)[None, :, None],   # noqa: E731
                           (3 * v)[:, None, None] + np.arange(3)[None, None, :]]
    jat, jbt = ja.transpose(0, 2, 1), jb.transpose(0, 2, 1)
    sigma = ja @ blk(a, a) @ jat + ja @ blk(a, b) @ jbt + jb @ blk(b, a) @ jat + jb @ blk(b, b) @ jbt
    return rel, sigma


def consistency(z: np.ndarray, info: np.ndarray, own: Side, peer: Side) -> np.ndarray:
    """(m, m) squared Mahalanobis cycle errors of every pair of closures (z (m, 3) from own to peer)."""
    m = len(z)
    k, l = np.triu_indices(m, 1)
    rel_a, cov_a = relative(own, k, l)
    rel_b, cov_b = relative(peer, l, k)
    zk_inv = between(z[k], np.zeros_like(z[k]))
    cycle = compose(compose(compose(zk_inv, rel_a), z[l]), rel_b)
    cycle[:, 2] = wrap(cycle[:, 2])
    cov_z = np.linalg.inv(info)
    sigma = cov_z[k] + cov_z[l] + cov_a + cov_b
    d2 = np.einsum("pi,pij,pj->p", cycle, np.linalg.inv(sigma), cycle)
    out = np.zeros((m, m))
    out[k, l] = out[l, k] = d2
    return out


def max_clique(adjacency: np.ndarray) -> np.ndarray:
    """Indices of a large clique of an undirected graph (boolean (m, m), no self loops needed)."""
    a = np.asarray(adjacency, bool).copy()
    m = len(a)
    if m == 0:
        return np.zeros(0, np.int64)
    np.fill_diagonal(a, False)
    ai = a.astype(np.int32)
    degree = ai.sum(1)
    best = np.array([int(np.argmax(degree))])
    tried = np.zeros(m, bool)
    for v in np.argsort(-degree, kind="stable"):
        if degree[v] + 1 <= len(best):
            break                                   # sorted: nobody after can do better
        if tried[v]:
            continue
        clique = [v]
        cand = a[v].copy()
        while cand.any():
            score = np.where(cand, ai @ cand, -1)
            u = int(np.argmax(score))
            clique.append(u)
            cand &= a[u]
            cand[u] = False
            if len(clique) + int(cand.sum()) <= len(best):
                break
        if len(clique) > len(best):
            best = np.array(sorted(clique))
        tried[clique] = True                        # a member of a found clique would regrow it
    return best


def select_consistent(z: np.ndarray, info: np.ndarray, own: Side, peer: Side, *,
                      gate: float = CHI2_3DOF_99, min_clique: int = 2) -> np.ndarray:
    """(m,) bool: the closures PCM accepts (the largest consistent set, if it has ``min_clique``)."""
    m = len(z)
    keep = np.zeros(m, bool)
    if m == 0:
        return keep
    clique = max_clique(consistency(z, info, own, peer) < gate) if m > 1 else np.zeros(1, np.int64)
    if len(clique) >= max(min_clique, 1):
        keep[clique] = True
    return keep
