"""Decentralised multi-robot SLAM: the agents against the centralised optimum on a small seeded world,
and the hard cases -- R = 1, robots that never meet, one closure, all closures false, loss and
reordering, a restart, duplicate descriptors -- plus PCM, the exact condensation and the wire."""
from __future__ import annotations

import math

import numpy as np
import pytest

from nodes.slam import dslam, pcm, place
from nodes.slam.dslam import Agent, condense_exact
from nodes.slam.dslam_agent import from_message, to_message, transmit
from nodes.slam.multirobot import (Scenario, assemble, centralised, cost_ratio, feed, feed_all, robot_stream,
                                   run_team, split_graph)
from nodes.slam.pose_graph import PoseGraph2D, between, chi2, edge_chi2, optimize

INFO = np.diag([100.0, 100.0, 400.0])


def loop_world(seed: int = 0, *, laps: int = 3, side: int = 8, noise: float = 0.5) -> PoseGraph2D:
    """A robot driving ``laps`` times round a square of ``side`` steps: odometry plus a closure each time
    it passes a corner it has seen before; measurements with seeded noise."""
    rng = np.random.default_rng(seed)
    truth = []
    for lap in range(laps):
        for edge in range(4):
            for k in range(side):
                heading = edge * math.pi / 2
                c, s = math.cos(heading), math.sin(heading)
                corner = [(0, 0), (side, 0), (side, side), (0, side)][edge]
                truth.append((corner[0] + c * k + 0.05 * lap, corner[1] + s * k + 0.05 * lap, heading))
    truth = np.array(truth)
    sd = noise * np.sqrt(1 / np.diag(INFO))
    per_lap = 4 * side
    rows = []
    for k in range(len(truth) - 1):
        rows.append((k, k + 1, between(truth[k], truth[k + 1]) + sd * rng.normal(size=3), INFO))
    for k in range(per_lap, len(truth)):
        if k % (side // 2) == 0:
            rows.append((k - per_lap, k, between(truth[k - per_lap], truth[k]) + sd * rng.normal(size=3), INFO))
    return PoseGraph2D.from_edges(rows)


def team(scenario: Scenario, **kwargs) -> list[Agent]:
    agents = [Agent(r, scenario.robots, **kwargs) for r in range(scenario.robots)]
    for a in agents:
        feed_all(a, scenario)
    return agents


def final_ratio(scenario: Scenario, agents: list[Agent], rounds: int, **kwargs) -> float:
    ref = centralised(scenario)
    return run_team(scenario, agents, rounds=rounds, transmit=transmit, reference=ref, **kwargs)[-1].cost_ratio


@pytest.mark.parametrize("method,rounds,tol", [("ddf", 4, 1e-6), ("dgs", 60, 0.01), ("block_gs", 60, 0.05)])
def test_team_reaches_the_centralised_optimum(method, rounds, tol):
    s = split_graph(loop_world(1), 3)
    assert s.inter.sum() > 4
    ratio = final_ratio(s, team(s, method=method, max_run=1), rounds)
    assert 1.0 - 1e-9 <= ratio < 1.0 + tol, ratio


def test_one_robot_is_the_centralised_solution_exactly():
    s = split_graph(loop_world(2), 1)
    agents = team(s)
    ref = centralised(s)
    records = run_team(s, agents, rounds=2, transmit=transmit, reference=ref)
    assert records[-1].bytes == 0 and records[-1].packets == 0
    np.testing.assert_allclose(agents[0].estimate, ref.poses, atol=1e-9)


def test_exact_condensation_of_a_chain_keeps_the_optimum():
    g = loop_world(3, laps=1)                                  # a pure chain: no closure of its own
    agent = Agent(0, 2)
    for rec in robot_stream(split_graph(g, 1), 0):
        feed(agent, rec)
    ids, edges, z, info = condense_exact(agent.ids, agent._odometry, agent._odometry_info, agent._intra,
                                         [agent.ids[10], agent.ids[20]])
    assert ids == [agent.ids[0], agent.ids[10], agent.ids[20]] and len(edges) == 2
    # the composed edge equals the composed odometry and its covariance the propagated one
    full = PoseGraph2D.from_edges([(k, k + 1, agent._odometry[k + 1], agent._odometry_info[k + 1]) for k in range(10)])
    p = optimize(full).poses
    np.testing.assert_allclose(z[0], between(p[0], p[10]), atol=1e-9)
    assert np.all(np.linalg.eigvalsh(info) > 0)


def test_robots_that_never_meet_keep_their_own_frames():
    g = loop_world(4)
    s = split_graph(g, 2)
    cut = ~s.inter                                             # cut every inter-robot closure
    s.graph.edges, s.graph.z, s.graph.info, s.outlier = s.graph.edges[cut], s.graph.z[cut], s.graph.info[cut], s.outlier[cut]
    agents = team(s)
    for _ in range(3):
        for a in agents:
            for packet in a.step():
                agents[packet.receiver].receive(packet)
    assert [a.gauge_root for a in agents] == [0, 1] and agents[1].own_frame
    np.testing.assert_allclose(agents[1].estimate[0], 0.0, atol=1e-9)   # its own first pose is its origin


def test_a_single_closure_ties_the_robots_unless_lone_closures_are_refused():
    g = loop_world(5, laps=2)
    s = split_graph(g, 2)
    keep = ~s.inter
    first = int(np.flatnonzero(s.inter)[0])
    keep[first] = True
    s.graph.edges, s.graph.z, s.graph.info, s.outlier = s.graph.edges[keep], s.graph.z[keep], s.graph.info[keep], s.outlier[keep]
    trusting = team(s)
    final_ratio(s, trusting, 3)
    assert trusting[1].gauge_root == 0 and trusting[0].neighbours() == [1]
    index = {int(v): k for k, v in enumerate(s.graph.ids)}
    poses = assemble(s, {a.robot: (np.array([index[v] for v in a.ids]), a.estimate) for a in trusting})
    assert chi2(s.inlier_graph(), poses) < 1e-9               # a tree: one closure ties two chains exactly
    cautious = team(s, trust_lone=False)
    final_ratio(s, cautious, 3)
    assert cautious[1].own_frame and cautious[0].neighbours() == []


def test_all_false_closures_are_rejected():
    s = split_graph(loop_world(6), 3, outlier_rate=1.0, seed=3)
    assert s.outlier.sum() == s.inter.sum() > 3
    agents = team(s)                                           # every pair holds several: PCM can compare them
    run_team(s, agents, rounds=4, transmit=transmit, reference=centralised(split_graph(loop_world(6), 3)))
    used = {(c.a, c.b) for a in agents for c in a.accepted_closures()}
    assert not used                                            # random closures do not agree with each other
    assert all(a.own_frame for a in agents)


def test_thirty_percent_outliers_leave_the_result():
    g = loop_world(7)
    clean = split_graph(g, 3)
    dirty = split_graph(g, 3, outlier_rate=0.3, seed=2)
    ref = centralised(clean)
    r_clean = run_team(clean, team(clean), rounds=4, transmit=transmit, reference=ref)[-1].cost_ratio
    r_dirty = run_team(dirty, team(dirty), rounds=4, transmit=transmit, reference=ref)[-1].cost_ratio
    assert abs(r_dirty - r_clean) / r_clean < 0.01


def test_loss_and_reordering_on_the_link_still_converge():
    s = split_graph(loop_world(8), 3)
    agents = team(s)
    rng = np.random.default_rng(0)
    delayed: list = []

    def lossy(packet, rnd):
        if rng.random() < 0.3:
            return False                                       # lost
        if rng.random() < 0.3:
            delayed.append(packet)                             # arrives later, out of order
            return False
        return True

    def redeliver(rnd, team_):
        while delayed:
            p = delayed.pop(0)
            team_[p.receiver].receive(p)

    ratio = final_ratio(s, agents, 12, deliver=lossy, before_round=redeliver)
    assert ratio < 1.0 + 1e-3


def test_a_restarted_robot_rejoins():
    s = split_graph(loop_world(9), 3)
    agents = team(s)
    ref = centralised(s)

    def restart(rnd, team_):
        if rnd == 3:                                           # robot 1 dies and comes back with nothing
            fresh = Agent(1, 3, epoch=1)
            feed_all(fresh, s)                                 # its own sensing, replayed from its log
            team_[1] = fresh

    rec = run_team(s, agents, rounds=8, transmit=transmit, reference=ref, before_round=restart)
    assert agents[1].epoch == 1 and rec[-1].cost_ratio < 1.0 + 1e-3


def test_a_team_run_is_deterministic():
    """Agents carry no clock (rounds, acks and epochs only; clock offsets between robots cannot enter):
    the same scenario gives the same result, bit for bit."""
    s = split_graph(loop_world(10), 2)
    a = final_ratio(s, team(s), 4)
    b = final_ratio(s, team(s), 4)
    assert a == b


def test_place_recognition_finds_closures_through_one_keeper_each():
    g = loop_world(11)
    s = split_graph(g, 3)
    truth = centralised(s).poses
    describer = place.Describer(scale_m=3.0, noise=0.01)
    centres = describer.train_centres(3)
    agents = [Agent(r, 3, front_end=place.PlaceFrontEnd(r, centres, threshold=0.5, window=2)) for r in range(3)]
    for a in agents:
        feed_all(a, s, truth=truth, describer=describer, given_closures=False)
    ref = centralised(s)
    run_team(s, agents, rounds=10, transmit=transmit, reference=ref)
    found = {(c.a, c.b) for a in agents for found in a._candidates.values() for c in found.values()}
    true = {(int(g.ids[a]), int(g.ids[b])) for a, b in s.graph.edges[s.inter]}
    assert found <= true and len(found) >= len(true) // 2
    sent = sum(a.front_end.sent_queries for a in agents)
    assert sent < 2 * g.n                                      # one keeper per descriptor (and retries), not R - 1


def test_a_keeper_stores_duplicate_descriptors_once():
    index = place.PlaceIndex(threshold=0.5)
    d = place.Describer().describe(np.array([1.0, 2.0]))
    assert index.query(0, 5, d) == []
    assert index.query(0, 5, d) == [] and len(index) == 1     # the same keyframe again: no self match, no copy
    hits = index.query(1, 9, d)
    assert len(hits) == 1 and hits[0][:2] == (0, 5) and hits[0][2] == pytest.approx(0.0, abs=1e-3)
    far = place.Describer().describe(np.array([40.0, -30.0]))
    assert index.query(2, 3, far) == []                         # another place: nothing within the threshold
    both = index.query(2, 4, d)                                 # a third robot at the first place: one match per robot
    assert sorted(h[0] for h in both) == [0, 1]


def test_pcm_keeps_the_consistent_set():
    Side = pcm.Side
    poses_a = np.column_stack([np.arange(6.0), np.zeros(6), np.zeros(6)])
    poses_b = poses_a + np.array([0.0, 2.0, 0.0])
    z = between(poses_a, poses_b)
    info = np.tile(np.diag([100.0, 100.0, 400.0]), (6, 1, 1))
    z[4] = (3.0, -5.0, 2.0)                                    # a false closure
    cov = np.eye(18) * 1e-4
    keep = pcm.select_consistent(z, info, Side(poses_a, cov, np.arange(6)), Side(poses_b, cov, np.arange(6)))
    assert keep.tolist() == [True, True, True, True, False, True]


def test_reversed_closure_information_is_first_order_exact():
    rng = np.random.default_rng(1)
    z = np.array([2.0, -1.0, 0.7])
    a = rng.normal(size=(3, 3))
    info = a @ a.T + np.eye(3)
    xi = np.array([0.3, 0.2, 0.1])
    from nodes.slam.pose_graph import compose
    xj = compose(compose(xi, z), np.array([0.001, -0.002, 0.0015]))
    forward = PoseGraph2D.from_edges([(0, 1, z, info)], {0: xi, 1: xj})
    backward = PoseGraph2D.from_edges([(1, 0, between(z, np.zeros(3)), dslam.inverse_info(z, info))], {0: xi, 1: xj})
    assert edge_chi2(backward, backward.poses)[0] == pytest.approx(edge_chi2(forward, forward.poses)[0], rel=1e-2)


def test_packets_survive_the_wire_and_bad_ones_are_refused():
    s = split_graph(loop_world(12), 2)
    agents = team(s, method="dgs")
    packets = [p for a in agents for p in a.step()] + [p for a in agents for p in a.step()]
    assert packets
    for p in packets:
        nbytes, back = transmit(p)
        assert nbytes > 0 and back.sender == p.sender and len(back.items) == len(p.items)
    with pytest.raises(ValueError):
        agents[0].receive(dslam.Packet(0, 0, 0, []))           # from itself
    with pytest.raises(ValueError):
        agents[0].receive(dslam.Packet(7, 0, 0, []))           # from no robot of the team
    assert to_message(packets[0]).sender == packets[0].sender and from_message(to_message(packets[0])).receiver == packets[0].receiver


def test_scenario_split_and_outlier_rate():
    g = loop_world(13)
    s = split_graph(g, 4, outlier_rate=0.25, seed=0)
    n_in = int((s.inter & ~s.outlier).sum())
    assert s.outlier.sum() == round(0.25 / 0.75 * n_in)
    assert np.all(np.diff(s.owner[np.argsort(g.ids)]) >= 0)     # contiguous blocks
    with pytest.raises(ValueError):
        split_graph(g, 0)
    with pytest.raises(ValueError):
        split_graph(g, 2, outlier_rate=1.5)
    poses = assemble(s, {})
    assert cost_ratio(centralised(s), poses) == math.inf      # nobody said anything: no answer, not a number
    assert chi2(s.inlier_graph(), centralised(s).poses) >= 0
