"""Pairwise consistency maximisation (PCM, Mangelson et al., ICRA 2018) for inter-robot loop closures.

Two closures k, l between robots a and b are consistent when the cycle they close with
the robots' own trajectories returns to the start:

    e_kl = t2v( z_k^-1 (+) (x^a_ik^-1 x^a_il) (+) z_l (+) (x^b_jl^-1 x^b_jk) )  ~ 0,

tested as e^T Sigma^-1 e < gate, Sigma the first-order covariance of the cycle: the two
closures' and each robot's relative pose (from its own joint marginals), each carried into
the cycle's frame by SE(2) adjoints (summing them unrotated, a common shortcut, rejected
true closures on a square loop with 90-degree turns). The accepted
set is the largest clique of the consistency graph: false closures, drawn from perceptual
aliasing, disagree with the true ones and with each other.

The clique is found by Pattabiraman's greedy heuristic (grow from each vertex by the
candidate with most neighbours among the candidates, prune vertices whose degree cannot
beat the best). Several closures are accepted only as a clique of at least ``min_clique``
(default 2): when the largest consistent set is a single closure, they contradict each
other and none is trusted. A lone closure cannot be checked against anything: it is
accepted when ``trust_lone`` (the default -- two robots that met once are tied by it, and
the team's optimiser can still reject it with GNC when it closes a cycle) and refused
otherwise.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nodes.slam.pose_graph import CHI2_3DOF_99, adjoint, between, compose, wrap


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


def right_perturbation(rel: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Covariance of additive (dx, dy, dtheta) errors of ``rel`` as a right perturbation (its own frame)."""
    c, s_ = np.cos(rel[:, 2]), np.sin(rel[:, 2])
    m = np.zeros((len(rel), 3, 3))
    m[:, 0, 0], m[:, 0, 1], m[:, 1, 0], m[:, 1, 1], m[:, 2, 2] = c, s_, -s_, c, 1.0
    return m @ cov @ m.transpose(0, 2, 1)


def consistency(z: np.ndarray, info: np.ndarray, own: Side, peer: Side) -> np.ndarray:
    """(m, m) squared Mahalanobis cycle errors of every pair of closures (z (m, 3) from own to peer).

    The cycle T = z_k^-1 (+) rel_a (+) z_l (+) rel_b; each factor's covariance is taken as a
    right perturbation and carried to T's frame by the adjoint of what follows it:
    dT = Ad((BCD)^-1) dA + Ad((CD)^-1) dB + Ad(D^-1) dC + dD.
    """
    m = len(z)
    k, l = np.triu_indices(m, 1)
    rel_a, cov_a = relative(own, k, l)
    rel_b, cov_b = relative(peer, l, k)
    zero = np.zeros((len(k), 3))
    a_, b_, c_, d_ = between(z[k], zero), rel_a, z[l], rel_b
    cycle = compose(compose(compose(a_, b_), c_), d_)
    cycle[:, 2] = wrap(cycle[:, 2])
    cov_z = np.linalg.inv(info)
    ad_zk = adjoint(z[k])
    sig_a = ad_zk @ cov_z[k] @ ad_zk.transpose(0, 2, 1)            # (Z E)^-1 = Z^-1 (Z E^-1 Z^-1)
    terms = [(compose(compose(b_, c_), d_), sig_a), (compose(c_, d_), right_perturbation(b_, cov_a)),
             (d_, cov_z[l]), (None, right_perturbation(d_, cov_b))]
    sigma = np.zeros((len(k), 3, 3))
    for after, cov in terms:
        if after is None:
            sigma += cov
            continue
        ad = adjoint(between(after, zero))
        sigma += ad @ cov @ ad.transpose(0, 2, 1)
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
                      gate: float = CHI2_3DOF_99, min_clique: int = 2, trust_lone: bool = True) -> np.ndarray:
    """(m,) bool: the closures PCM accepts (the largest consistent set; see the module's rule for one)."""
    m = len(z)
    keep = np.zeros(m, bool)
    if m == 1:
        keep[0] = trust_lone
        return keep
    if m == 0:
        return keep
    clique = max_clique(consistency(z, info, own, peer) < gate)
    if len(clique) >= max(min_clique, 1):
        keep[clique] = True
    return keep
