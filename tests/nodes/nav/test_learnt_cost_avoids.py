"""Hard case: person_cost 0 (the default) with a pedestrian standing on the global path. The shipped
learnt weights alone (CrowdFeatures -> IrlCost -> DijkstraPlanner, no person floor) must take the
local plan around them."""
from __future__ import annotations

import numpy as np

from msgs.geometry import Odometry2D, Pose2D, Twist2D
from msgs.nav import FlowPoints, Goal2D
from nodes.nav.crowd_features import CrowdFeatures
from nodes.nav.demos import FEATURE_PARAMS
from nodes.nav.dijkstra_planner import DijkstraPlanner
from nodes.nav.irl_cost import IrlCost, load_weights
from nodes.nav.social_planner import PlannerParams
from tether.testing import Harness


def person(x: float, y: float, vx: float = 0.0, vy: float = 0.0, n: int = 60, seed: int = 0) -> FlowPoints:
    """A body's flow points (robot frame): a 0.3 m-radius column 0.2-1.7 m high."""
    rng = np.random.default_rng(seed)
    a, r, z = rng.uniform(0, 2 * np.pi, n), 0.3 * np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0.2, 1.7, n)
    pts = np.column_stack([x + r * np.cos(a), y + r * np.sin(a), z]).astype(np.float32)
    vel = np.tile([vx, vy, 0.0], (n, 1)).astype(np.float32)
    return FlowPoints(stamp_ns=int(0.1e9), frame_id="base", points_m=pts, velocity_mps=vel)


def plan_through(flow: FlowPoints, goal=(8.0, 0.0)):
    odom = Odometry2D(stamp_ns=int(0.1e9), frame_id="world", pose=Pose2D(x_m=0.0, y_m=0.0, yaw_rad=0.0), twist=Twist2D())
    feats = Harness(CrowdFeatures, params=FEATURE_PARAMS)
    feats.feed([(0.0, "goal", Goal2D(x_m=goal[0], y_m=goal[1], frame_id="world")), (0.05, "odom", odom)])
    grid = [o.msg for o in feats.feed([(0.1, "flow", flow)]) if o.output == "features"][-1]
    costs = [o.msg for o in Harness(IrlCost).feed([(0.1, "features", grid)])]
    planner = Harness(DijkstraPlanner, params={"predict_s": 0.0})
    planner.feed([(0.0, "goal", Goal2D(x_m=goal[0], y_m=goal[1], frame_id="world")), (0.05, "odom", odom),
                  (0.1, "features", grid), (0.1, "costs", costs[-1]), (0.12, "odom", odom)])
    return planner, grid, costs[-1]


def test_the_default_planner_has_no_person_floor_and_the_shipped_weights_price_conflicts():
    assert PlannerParams().person_cost == 0.0
    w = load_weights()
    assert "conflict" in w.names
    assert w.weights[w.names.index("conflict")] > 0.5 * w.step_cost           # a person's cell well above a free one


def test_a_pedestrian_standing_on_the_global_path_is_passed_at_a_distance_by_the_learnt_cost_alone():
    planner, grid, costs = plan_through(person(2.5, 0.0))
    assert grid.names[-1] == "conflict" and grid.features[..., 12].any()
    status = planner.of("status")[-1]
    assert "local" in status.reason
    path = planner.of("path")[-1].poses[:, :2]
    gap = np.hypot(path[:, 0] - 2.5, path[:, 1]).min()
    assert gap >= 0.65                          # clear of the body (0.3 m) by more than the robot's radius (0.35 m)
    c = np.asarray(costs.cost)
    assert np.isfinite(c).all() and c.min() > 0


def test_someone_walking_away_ahead_is_not_an_obstacle_to_the_learnt_cost():
    """The follower case real walkers teach: the cells of a person walking away are empty by the time one gets there."""
    _, grid, _ = plan_through(person(2.0, 0.0, vx=1.2))
    assert grid.features[..., 0].any() and not grid.features[..., 12].any()
