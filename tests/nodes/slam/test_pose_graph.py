"""SE(2) pose graph: solver against ground truth and against the published optima, file formats,
and the hard cases (angle wrap, gauge, pieces, bad information, a false loop closure)."""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from nodes.slam import pose_graph as pg
from nodes.slam.graph_io import detect_format, read_graph, write_graph
from nodes.slam.pose_graph import GraphError, PoseGraph2D, between, chi2, optimize

REPO = Path(__file__).resolve().parents[3]
INFO = np.diag([100.0, 100.0, 400.0])


def grid_world(rng: np.random.Generator, *, rows: int = 4, cols: int = 6, noise: float = 0.0,
               closure_every: int = 1) -> tuple[PoseGraph2D, np.ndarray]:
    """A robot snaking over a grid (turns of +-90 deg), odometry plus closures between neighbouring rows."""
    truth = []
    for r in range(rows):
        for c in range(cols):
            x = c if r % 2 == 0 else cols - 1 - c
            truth.append((float(x), float(r), 0.0 if r % 2 == 0 else math.pi))
    truth = np.array(truth)
    cov_sd = np.sqrt(1 / np.diag(INFO))
    edges = []

    def measure(i: int, j: int) -> None:
        z = between(truth[i], truth[j]) + noise * cov_sd * rng.normal(size=3)
        edges.append((i, j, tuple(z), INFO))

    for k in range(len(truth) - 1):
        measure(k, k + 1)
    for i in range(len(truth)):
        for j in range(i + 2, len(truth)):
            if np.hypot(*(truth[i, :2] - truth[j, :2])) < 1.01 and (i + j) % closure_every == 0:
                measure(i, j)
    return PoseGraph2D.from_edges(edges), truth


def aligned_error(poses: np.ndarray, truth: np.ndarray) -> float:
    """Max position error after expressing both in the frame of pose 0 (the anchor's gauge)."""
    a = between(np.repeat(poses[:1], len(poses), 0), poses)
    b = between(np.repeat(truth[:1], len(truth), 0), truth)
    return float(np.abs(a[:, :2] - b[:, :2]).max())


def test_noise_free_graph_converges_to_the_truth_from_a_bad_start():
    rng = np.random.default_rng(0)
    graph, truth = grid_world(rng)
    start = truth + rng.normal(scale=[0.3, 0.3, 0.3], size=truth.shape)
    start[0] = truth[0]
    result = optimize(graph, initial=start)
    assert result.converged and result.chi2 < 1e-12 < result.chi2_initial
    assert aligned_error(result.poses, truth) < 1e-6
    assert np.allclose(result.poses[0], truth[0])                       # the anchor does not move


def test_noisy_graph_reaches_the_least_squares_optimum_with_gn_and_lm_alike():
    rng = np.random.default_rng(1)
    graph, truth = grid_world(rng, noise=1.0)
    lm, gn = optimize(graph, initial="odometry"), optimize(graph, initial="odometry", method="gn")
    assert abs(lm.chi2 - gn.chi2) < 1e-8 * lm.chi2 and np.abs(lm.poses - gn.poses).max() < 1e-6
    # At the optimum the gradient vanishes: no small move lowers chi2.
    for k in (3, 10, 17):
        for d in range(3):
            moved = lm.poses.copy()
            moved[k, d] += 1e-4
            assert chi2(graph, moved) > lm.chi2
    dof = 3 * len(graph.edges) - 3 * (graph.n - 1)
    assert 0.3 * dof < lm.chi2 < 3 * dof                                  # consistent with unit-variance noise
    assert aligned_error(lm.poses, truth) < 0.35


def test_angles_wrap_in_residuals_and_in_chained_odometry():
    # Four left turns of 100 deg: headings run past +pi in the chain, and the loop closes across it.
    truth = [np.zeros(3)]
    for _ in range(8):
        truth.append(pg.compose(truth[-1], np.array([1.0, 0.0, math.radians(100)])))
    truth = np.array(truth)
    edges = [(k, k + 1, tuple(between(truth[k], truth[k + 1])), INFO) for k in range(8)]
    edges.append((0, 8, tuple(between(truth[0], truth[8])), INFO))
    graph = PoseGraph2D.from_edges(edges)
    odo = pg.initial_poses(graph, "odometry")
    assert np.allclose(odo, truth, atol=1e-12) and np.all(np.abs(odo[:, 2]) <= math.pi)
    start = truth.copy()
    start[1:, 2] += 0.2                                                  # pushes headings over +-pi
    result = optimize(graph, initial=pg.wrap(start))
    assert result.chi2 < 1e-12 and aligned_error(result.poses, truth) < 1e-8
    e = pg.residuals(graph, truth + np.array([0, 0, 2 * math.pi]))     # a full turn is no error
    assert np.abs(e).max() < 1e-9


def test_anchor_choice_fixes_the_gauge_and_changes_nothing_else():
    rng = np.random.default_rng(2)
    graph, truth = grid_world(rng, noise=1.0)
    first = optimize(graph, initial="odometry")
    other = optimize(graph, initial=first.poses, anchor=int(graph.ids[7]))
    assert np.allclose(other.poses[7], first.poses[7])
    assert abs(first.chi2 - other.chi2) < 1e-9 * first.chi2


def test_disconnected_graph_names_its_components():
    graph = PoseGraph2D.from_edges([(0, 1, (1, 0, 0)), (1, 2, (1, 0, 0)), (10, 11, (1, 0, 0))])
    with pytest.raises(GraphError, match=r"2 disconnected components \(3 vertices from id 0, 2 vertices from id 10\)"):
        optimize(graph)


@pytest.mark.parametrize("info, why", [
    (np.zeros((3, 3)), "not positive definite"),
    (np.diag([1.0, 1.0, -1.0]), "not positive definite"),
    (np.array([[1.0, 2.0, 0], [0, 1, 0], [0, 0, 1]]), "not symmetric"),
    (np.diag([1.0, np.nan, 1.0]), "non-finite"),
])
def test_bad_information_is_a_clear_error_naming_the_edge(info, why):
    graph = PoseGraph2D.from_edges([(0, 1, (1, 0, 0)), (1, 2, (1, 0, 0), info)])
    with pytest.raises(GraphError, match=f"edge 1 \\(1 -> 2\\).*{why}"):
        optimize(graph)


def test_self_edge_is_refused_and_duplicates_are_counted_and_kept():
    with pytest.raises(GraphError, match="joins a vertex to itself"):
        optimize(PoseGraph2D.from_edges([(0, 1, (1, 0, 0)), (1, 1, (0, 0, 0))]))
    dup = PoseGraph2D.from_edges([(0, 1, (1.0, 0, 0)), (0, 1, (1.2, 0, 0)), (1, 0, (-1.1, 0, 0))])
    assert pg.check_graph(dup).duplicates == 2
    result = optimize(dup)
    assert result.poses[1, 0] == pytest.approx(1.1, abs=1e-9)           # the mean of three equal-weight measurements


def test_gnc_rejects_a_loop_closure_180_degrees_off_that_least_squares_follows():
    rng = np.random.default_rng(3)
    graph, truth = grid_world(rng, noise=1.0)
    closures = np.flatnonzero(~graph.odometry_mask())
    bad = int(closures[len(closures) // 2])
    clean = aligned_error(optimize(graph, initial="odometry").poses, truth)   # noise alone, before the lie
    graph.z[bad] = pg.compose(graph.z[bad], np.array([0.0, 0.0, math.pi]))
    graph.z[bad, :2] += 1.5
    plain = optimize(graph, initial="odometry")
    robust = optimize(graph, initial="odometry", robust="gnc")
    assert bad in robust.outliers and len(robust.outliers) <= 2        # at most one good closure lost with it
    assert aligned_error(robust.poses, truth) < clean + 0.05
    assert aligned_error(plain.poses, truth) > 2 * clean
    huber = optimize(graph, initial="odometry", robust="huber")
    assert huber.weights[bad] < 0.2 and np.median(huber.weights) == 1.0


def test_chordal_start_rescues_a_badly_rotated_odometry():
    rng = np.random.default_rng(4)
    graph, truth = grid_world(rng, rows=6, cols=8, noise=1.0)
    odo = graph.odometry_mask()
    graph.z[odo, 2] += rng.normal(scale=0.2, size=int(odo.sum()))         # odometry rotations far off
    graph.info[odo] = np.diag([100.0, 100.0, 1.0])                       # ... and known to be poor
    start_odo, start_chordal = pg.initial_poses(graph, "odometry"), pg.initial_poses(graph, "chordal")
    assert chi2(graph, start_chordal) < 0.05 * chi2(graph, start_odo)
    assert aligned_error(start_chordal, truth) < aligned_error(start_odo, truth)
    assert optimize(graph, initial="chordal").chi2 <= optimize(graph, initial="odometry").chi2 * (1 + 1e-9)


def test_marginal_covariances_are_the_blocks_of_the_inverse_normal_matrix():
    rng = np.random.default_rng(5)
    graph, _ = grid_world(rng, rows=2, cols=4, noise=1.0)
    result = optimize(graph, initial="odometry")
    covs = pg.marginal_covariances(graph, result.poses, [0, 1, 3])
    e, ji, jj = pg._jacobians(graph, result.poses)
    m, n = len(graph.edges), graph.n
    jac, w = np.zeros((3 * m, 3 * n)), np.zeros((3 * m, 3 * m))
    for k, (i, j) in enumerate(graph.edges):
        jac[3 * k:3 * k + 3, 3 * i:3 * i + 3], jac[3 * k:3 * k + 3, 3 * j:3 * j + 3] = ji[k], jj[k]
        w[3 * k:3 * k + 3, 3 * k:3 * k + 3] = graph.info[k]
    inverse = np.linalg.inv((jac.T @ w @ jac)[3:, 3:])
    assert np.allclose(covs[0], 0) and np.allclose(covs[1], inverse[0:3, 0:3]) and np.allclose(covs[2], inverse[6:9, 6:9])
    assert np.trace(covs[2]) > np.trace(covs[1]) > 0                     # uncertainty grows away from the anchor


def test_lu_and_ldl_linear_solvers_agree():
    rng = np.random.default_rng(6)
    graph, _ = grid_world(rng, noise=1.0)
    a, b = optimize(graph, initial="odometry"), optimize(graph, initial="odometry", linear_solver="lu")
    assert np.abs(a.poses - b.poses).max() < 1e-9


# -- files ------------------------------------------------------------------------------------------
def test_g2o_and_toro_round_trip_with_their_information_orders(tmp_path):
    rng = np.random.default_rng(7)
    a = rng.normal(size=(3, 3))
    info = a @ a.T + np.eye(3)
    graph = PoseGraph2D.from_edges([(0, 1, (1.0, 0.2, 0.1), info), (1, 2, (1.0, -0.2, 0.3), info)],
                                   {0: (0, 0, 0), 1: (1, 0, 0), 2: (2, 0, 0.1)})
    for name in ("g.g2o", "g.graph"):
        write_graph(tmp_path / name, graph)
        back = read_graph(tmp_path / name)
        assert np.allclose(back.info, graph.info, rtol=1e-8) and np.allclose(back.z, graph.z)
        assert np.allclose(back.poses, graph.poses) and back.known.all()
    assert detect_format(tmp_path / "g.graph") == "toro" and detect_format(tmp_path / "g.g2o") == "g2o"
    toro = (tmp_path / "g.graph").read_text().split("\n")[3].split()
    assert toro[0] == "EDGE2" and float(toro[9]) == pytest.approx(info[2, 2])   # I33 is fourth
    with pytest.raises(GraphError, match="holds toro records.*silently give a wrong problem"):
        read_graph(tmp_path / "g.graph", fmt="g2o")


@pytest.mark.parametrize("text, why", [
    ("EDGE_SE2 0 1 1 0 0 1 0 0 1 0\n", r":1: EDGE_SE2 has i j dx dy dtheta and 6 information"),
    ("VERTEX_SE2 0 0 0 nan\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n", r":1: non-finite"),
    ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 0 1 0 0\n", r":2: vertex 0 is defined twice"),
    ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE2 0 0 0 0\n", r":1: VERTEX_SE3:QUAT records are not SE\(2\)"),
    ("VERTEX2 0 0 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n", "holds both g2o and TORO"),
    ("", "no VERTEX_SE2"),
])
def test_malformed_files_name_the_line(tmp_path, text, why):
    path = tmp_path / "bad.g2o"
    path.write_text(text)
    with pytest.raises(GraphError, match=why):
        read_graph(path)


def test_edges_only_file_starts_from_the_odometry_chain(tmp_path):
    path = tmp_path / "edges.g2o"
    path.write_text("EDGE_SE2 0 1 1 0 1.5707963 1 0 0 1 0 1\nEDGE_SE2 1 2 1 0 0 1 0 0 1 0 1\n")
    graph = read_graph(path)
    assert not graph.known.any()
    result = optimize(graph)
    assert np.allclose(result.poses, [[0, 0, 0], [1, 0, math.pi / 2], [1, 1, math.pi / 2]], atol=1e-6)


# -- the published graphs (../shared/data/posegraphs): the optima of ../shared/specs/pose-graphs.md
@pytest.mark.parametrize("name, expected", [("input_M3500_g2o.g2o", 137.913), ("sesync_intel.g2o", 45.005),
                                            ("FR079_P_toro.graph", 37.599)])
def test_published_graphs_reach_the_reference_chi2_from_odometry(shared_data, name, expected):
    graph = read_graph(shared_data / "posegraphs" / name)
    result = optimize(graph, initial="odometry")
    assert result.converged and result.chi2 == pytest.approx(expected, abs=1.5e-3)
    assert result.chi2_initial > 100 * result.chi2


def test_cli_optimize_prints_chi2_and_writes_a_graph_that_reads_back(tmp_path, shared_data):
    out = tmp_path / "fr079.g2o"
    res = subprocess.run([sys.executable, "-m", "tether.cli", "slam", "optimize",
                          str(shared_data / "posegraphs" / "FR079_P_toro.graph"), "-o", str(out),
                          "--initial", "odometry"], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert "989 poses, 1217 edges" in res.stdout and "-> 37.599" in res.stdout and "iteration   1" in res.stderr
    again = read_graph(out)
    assert chi2(again, again.poses) == pytest.approx(37.599, abs=1e-3)
    bad = tmp_path / "pieces.g2o"
    bad.write_text("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 5 6 1 0 0 1 0 0 1 0 1\n")
    res = subprocess.run([sys.executable, "-m", "tether.cli", "slam", "optimize", str(bad)], cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "disconnected components" in res.stderr and "Traceback" not in res.stderr


def test_sparse_pattern_assembly_matches_a_dense_normal_matrix():
    rng = np.random.default_rng(8)
    graph, _ = grid_world(rng, rows=2, cols=3, noise=1.0)
    a = rng.normal(size=(len(graph.edges), 3, 3))
    graph.info = a @ a.transpose(0, 2, 1) + np.eye(3)
    poses = rng.normal(size=(graph.n, 3))
    system = pg._System(graph, {0})
    e, ji, jj = pg._jacobians(graph, poses)
    data, b = system.assemble(e, ji, jj, graph.info)
    h = sp.csc_matrix((data, system.indices, system.indptr), shape=(system.size, system.size)).toarray()
    m = len(graph.edges)
    jac, w = np.zeros((3 * m, 3 * graph.n)), np.zeros((3 * m, 3 * m))
    for k, (i, j) in enumerate(graph.edges):
        jac[3 * k:3 * k + 3, 3 * i:3 * i + 3], jac[3 * k:3 * k + 3, 3 * j:3 * j + 3] = ji[k], jj[k]
        w[3 * k:3 * k + 3, 3 * k:3 * k + 3] = graph.info[k]
    assert np.allclose(h, (jac.T @ w @ jac)[3:, 3:]) and np.allclose(b, (jac.T @ w @ e.reshape(-1))[3:])
    for k in range(m):                                                    # and the Jacobians themselves
        for var in range(3):
            moved = poses.copy()
            moved[graph.edges[k, 0], var] += 1e-7
            assert np.allclose((pg.residuals(graph, moved)[k] - e[k]) / 1e-7, ji[k][:, var], atol=1e-5)
