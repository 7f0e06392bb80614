"""The planner decides when to go (path-velocity decomposition, ``plan_geometry.speed_profile``): along the path it
chose, it slows or waits for people it predicts, so the collision guard rarely has to.

Hard cases in a small closed loop (a unicycle with the simulator's 0.8 m/s^2, people given as flow points with
seeded noise, the cost grid uniform so that the path alone would lead through them): a walker crossing, a person
standing on the path, a goal that cannot be reached without walking through a row of people, a walled-off goal.
Each is also run with the speed profile off (``conflict_price`` 0, the planner before it): that robot drives in.
"""
from __future__ import annotations

import numpy as np
import pytest

from nodes.nav.grid_frame import GridFrame, to_robot
from nodes.nav.plan_geometry import people_motion, speed_profile
from nodes.nav.social_planner import PlannerParams, SocialPlanner

FRAME = GridFrame((25, 25), 0.25, -0.5, -3.0)          # robot frame: x -0.5..5.5 m, y -3..3 m
PRICE = 4.0                                            # the shipped weights' conflict price (step cost 2)
STRAIGHT = np.array([[0.0, 0.0], [6.0, 0.0]])


def _choice(people_xy, people_v, v_now=1.0, **kw):
    return speed_profile(STRAIGHT, np.asarray(people_xy, float).reshape(-1, 2), np.asarray(people_v, float).reshape(-1, 2),
                         v_now_mps=v_now, v_max_mps=1.0, conflict_price=PRICE, progress_price=2.0, cell_m=0.25,
                         clear_m=0.65, **kw)


def test_nobody_near_the_path_full_speed():
    c = _choice([[2.0, 2.5]], [[0.0, 0.0]])
    assert c.v_mps == 1.0 and not c.limited and c.conflict_s.max() == 0


def test_a_walker_about_to_cross_ahead_slows_the_robot():
    # at full speed the robot would be 2 m along when the walker (1.2 m/s, from 1.5 m to the right) crosses there
    c = _choice([[2.0, -1.5]], [[0.0, 1.2]])
    assert c.conflict_s[-1] > 0 and c.v_mps < 1.0
    assert c.conflict_s[list(c.candidates_mps).index(c.v_mps)] < c.conflict_s[-1]


def test_someone_standing_on_the_path_stops_the_robot_short_of_them():
    c = _choice([[1.2, 0.0]], [[0.0, 0.0]], v_now=0.5)
    assert c.v_mps == 0.0


def test_a_faster_walker_ahead_going_the_same_way_does_not_hold_it():
    c = _choice([[2.5, 0.0]], [[1.6, 0.0]])
    assert c.v_mps == 1.0


def test_bad_arguments_say_what_to_do():
    with pytest.raises(ValueError, match="n_speeds"):
        speed_profile(STRAIGHT, np.zeros((0, 2)), np.zeros((0, 2)), v_now_mps=0, v_max_mps=1.0, conflict_price=PRICE,
                      progress_price=2.0, cell_m=0.25, clear_m=0.65, n_speeds=1)


def test_people_motion_moves_a_body_with_its_cells_median_and_keeps_a_standing_one_still():
    rng = np.random.default_rng(3)
    walker = np.column_stack([rng.normal(2.0, 0.08, 200), rng.normal(0.0, 0.08, 200), rng.uniform(0.3, 1.7, 200)])
    vel = np.tile([0.0, 1.0, 0.0], (200, 1))
    vel[:10] = [2.5, -2.5, 0.0]                              # a few wrong flow vectors
    xy, v = people_motion(walker, vel)
    assert len(xy) and np.allclose(np.median(v, axis=0), [0.0, 1.0], atol=1e-6)
    xy, v = people_motion(walker, np.zeros_like(walker))
    assert np.all(v == 0)


# -- closed loop --------------------------------------------------------------------------------------
def _body(rng, centre, n=60, radius=0.22):
    a, r = rng.uniform(0, 2 * np.pi, n), radius * np.sqrt(rng.uniform(0, 1, n))
    return centre + np.column_stack([r * np.cos(a), r * np.sin(a)])


def _drive(people, goal, *, price=PRICE, seconds=12.0, dt=0.1, seed=0, occupancy=None):
    """Run the planner against ``people(t) -> (centres (k, 2), velocities (k, 2))`` (world); returns per tick the
    robot pose, speed, and the distance from the robot centre to the nearest person centre, and the planner."""
    rng = np.random.default_rng(seed)
    planner = SocialPlanner(PlannerParams(memory_s=0.0, conflict_price=price))
    if occupancy is not None:
        planner.set_map(*occupancy)
    planner.set_goal(goal)
    pose, v_now = np.zeros(3), 0.0
    rows = []
    rc = np.argwhere(np.ones(FRAME.shape, bool))
    cell_xy = FRAME.xy_of(rc)
    for k in range(int(seconds / dt)):
        t = k * dt
        centres, vels = people(t)
        pts_w = np.vstack([_body(rng, c) for c in centres])
        vel_w = np.repeat(vels, len(pts_w) // len(centres), axis=0) + rng.normal(0, 0.05, (len(pts_w), 2))
        c, s = np.cos(pose[2]), np.sin(pose[2])
        rel = to_robot(tuple(pose), pts_w)
        vrel = np.column_stack([c * vel_w[:, 0] + s * vel_w[:, 1], -s * vel_w[:, 0] + c * vel_w[:, 1]])
        z = rng.uniform(0.3, 1.7, len(rel))
        planner.set_people(tuple(pose), np.column_stack([rel, z]), np.column_stack([vrel, np.zeros(len(rel))]), t)
        # the learnt cost's view: a uniform floor, people's cells a little dearer (density_high ~1 on a step of 2)
        near = np.hypot(*(cell_xy[:, None, :] - to_robot(tuple(pose), centres)[None]).transpose(2, 0, 1)).min(axis=1)
        high = (near <= 0.3).reshape(FRAME.shape)
        cost = np.where(high, 3.0, 2.0)
        planner.update(tuple(pose), cost, FRAME, high, t)
        v, w = planner.command(tuple(pose), t, v_now)
        v_now = float(np.clip(v, v_now - 0.8 * dt, v_now + 0.8 * dt))
        pose = pose + [v_now * np.cos(pose[2]) * dt, v_now * np.sin(pose[2]) * dt, w * dt]
        rows.append((pose.copy(), v_now, float(np.hypot(*(centres - pose[:2]).T).min())))
        if planner.mode == "reached":
            break
    return rows, planner


def _crossing(t):
    """A walker from 3 m to the right of the robot's line, crossing it 3 m ahead at t = 3 s (1 m/s)."""
    return np.array([[3.0, -3.0 + 1.0 * t]]), np.array([[0.0, 1.0]])


def test_a_crossing_walker_the_robot_slows_and_passes_behind():
    rows, _ = _drive(_crossing, (6.0, 0.0))
    poses = np.array([r[0] for r in rows])
    closest = min(r[2] for r in rows)
    k = int(np.argmax(poses[:, 0] >= 3.0))                 # the robot reaches the walker's track
    assert poses[k, 0] >= 3.0
    assert _crossing(k * 0.1)[0][0, 1] > 0.65              # ... after the walker has crossed it: behind them
    assert min(r[1] for r in rows[10:40]) < 0.7            # it slowed to let them pass
    assert closest >= 0.65, closest


def test_a_crossing_walker_without_the_speed_profile_is_driven_into():
    rows, _ = _drive(_crossing, (6.0, 0.0), price=0.0)
    assert min(r[2] for r in rows) < 0.4                   # the old planner: bodies touch


def _standing(t):
    return np.array([[3.0, 0.0]]), np.zeros((1, 2))


def _corridor() -> tuple[np.ndarray, GridFrame]:
    """A 2 m corridor along x (walls at y = +-1 m) on a 0.1 m map: no way round someone standing in its middle."""
    occ = np.zeros((40, 120))
    occ[9, :] = occ[30, :] = 1.0
    return occ, GridFrame(occ.shape, 0.1, -2.0, -1.9)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_person_standing_on_the_path_the_robot_goes_round(seed):
    rows, planner = _drive(_standing, (6.0, 0.0), seed=seed)
    assert min(r[2] for r in rows) >= 0.65 and planner.mode == "reached"


@pytest.mark.parametrize("seed", [0, 1])
def test_a_person_standing_in_a_corridor_the_robot_waits_never_drives_in(seed):
    rows, planner = _drive(_standing, (6.0, 0.0), seed=seed, occupancy=_corridor())
    assert min(r[2] for r in rows) >= 0.65
    assert planner.mode != "reached" and rows[-1][1] == 0.0


def test_a_person_standing_in_a_corridor_without_the_speed_profile_is_driven_into():
    rows, _ = _drive(_standing, (6.0, 0.0), price=0.0, occupancy=_corridor())
    assert min(r[2] for r in rows) < 0.4


def _row(t):
    """A row of people across the whole view, 3 m ahead: the goal behind them cannot be reached without passing
    through someone."""
    ys = np.arange(-3.0, 3.01, 0.5)
    return np.column_stack([np.full(len(ys), 3.0), ys]), np.zeros((len(ys), 2))


def test_a_goal_behind_a_row_of_people_the_robot_waits_in_front():
    rows, planner = _drive(_row, (6.0, 0.0), seconds=15.0)
    assert planner.mode != "reached"
    assert min(r[2] for r in rows) >= 0.65
    assert rows[-1][1] == 0.0                              # standing, waiting


def test_a_goal_behind_a_row_of_people_without_the_speed_profile_is_driven_into():
    rows, _ = _drive(_row, (6.0, 0.0), price=0.0, seconds=15.0)
    assert min(r[2] for r in rows) < 0.4


def test_a_walled_off_goal_is_unreachable_and_the_robot_stays():
    occ = np.zeros((60, 100))
    occ[20:41, 55] = occ[20:41, 75] = 1.0
    occ[20, 55:76] = occ[40, 55:76] = 1.0                  # a closed box around (3.5, 0) on a 0.1 m map
    frame = GridFrame(occ.shape, 0.1, -3.0, -3.0)
    rows, planner = _drive(_crossing, (3.5, 0.0), seconds=2.0, occupancy=(occ, frame))
    assert planner.mode == "unreachable"
    assert all(r[1] == 0.0 for r in rows)


@pytest.mark.parametrize("memory_s, waits", [(1.5, True), (0.0, False)])
def test_someone_who_stepped_into_the_cameras_blind_zone_is_still_there(memory_s, waits):
    """Seen standing 0.65 m ahead, then nearer than the depth camera measures (0.4 m from it, 0.3 m ahead of the
    centre): the flow has no points of them any more; the planner remembers them and does not drive on."""
    rng = np.random.default_rng(5)
    planner = SocialPlanner(PlannerParams(memory_s=memory_s, conflict_price=PRICE))
    planner.set_goal((6.0, 0.0))
    pose = (0.0, 0.0, 0.0)
    body = np.column_stack([_body(rng, np.array([0.65, 0.0])), rng.uniform(0.3, 1.7, 60)])
    planner.set_people(pose, body, np.zeros_like(body), 0.0)
    planner.set_people(pose, np.zeros((0, 3)), np.zeros((0, 3)), 0.2)
    planner.update(pose, np.full(FRAME.shape, 2.0), FRAME, np.zeros(FRAME.shape, bool), 0.2)
    v, _ = planner.command(pose, 0.2, 0.0)
    assert (v == 0.0) == waits


def test_the_planner_node_prices_conflicts_with_the_weights_files_conflict_weight(tmp_path):
    import json

    from nodes.nav.dijkstra_planner import DijkstraPlanner
    from nodes.nav.irl_cost import load_weights
    from tether.testing import Harness

    w = load_weights("")
    shipped = float(w.weights[list(w.names).index("conflict")])
    with Harness(DijkstraPlanner) as h:
        assert h.node.planner.p.conflict_price == shipped
    other = json.loads(w.to_json())
    other["weights"][other["names"].index("conflict")] = 1.5
    path = tmp_path / "w.json"
    path.write_text(json.dumps(other))
    with Harness(DijkstraPlanner, params={"weights_path": str(path)}) as h:
        assert h.node.planner.p.conflict_price == 1.5
    with Harness(DijkstraPlanner, params={"conflict_price": 0.0}) as h:     # the speed profile off
        assert h.node.planner.p.conflict_price == 0.0
