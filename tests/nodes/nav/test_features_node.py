"""CrowdFeatures node: FlowPoints + goal + odometry in, FeatureGrid out (names, frame, goal transform)."""
from __future__ import annotations

import numpy as np

from msgs.geometry import Odometry2D, Pose2D
from msgs.nav import FlowPoints, Goal2D
from nodes.nav.crowd_features import CrowdFeatures
from nodes.nav.features import FEATURE_NAMES
from tether.testing import Harness


def flow(n=40, x=2.0, y=0.0, vx=-1.0):
    pts = np.tile(np.array([x, y, 1.0], np.float32), (n, 1))
    vel = np.tile(np.array([vx, 0.0, 0.0], np.float32), (n, 1))
    return FlowPoints(stamp_ns=5, frame_id="base_link", points_m=pts, velocity_mps=vel)


def goal_levels(grid):
    return grid.features[..., 9:12].argmax(axis=2)          # 0 high, 1 medium, 2 low


def test_feature_grid_message_carries_layout_frame_and_origin():
    with Harness(CrowdFeatures) as h:
        out = h.feed([(0.0, "flow", flow(n=200))])
    grid = out[0].msg
    assert grid.features.shape == (24, 24, 13) and grid.names == FEATURE_NAMES + ["conflict"]
    assert grid.frame_id == "base_link" and grid.stamp_ns == 5
    assert (grid.origin_x_m, grid.origin_y_m, grid.resolution_m) == (-0.375, -2.875, 0.25)
    c, r = int((2.0 + 0.5) / 0.25), int((0.0 + 3.0) / 0.25)
    assert grid.features[r, c, 0] == 1 and grid.features[r, c, 3] == 1       # dense, fast
    assert grid.features[r, c - 1, 6] == 1                                    # in-flow toward the robot
    assert np.all(goal_levels(grid) == 1)                                     # no goal yet: medium


def test_world_goal_is_moved_into_the_robot_frame_with_odometry():
    # robot at (10, 5) facing +y; the world goal (10, 25) is straight ahead of it, beyond the grid
    odom = Odometry2D(frame_id="world", pose=Pose2D(x_m=10.0, y_m=5.0, yaw_rad=np.pi / 2))
    with Harness(CrowdFeatures) as h:
        h.feed([(0.0, "odom", odom), (0.0, "goal", Goal2D(frame_id="world", x_m=10.0, y_m=25.0)),
                (0.1, "flow", flow(n=0))])
        levels = goal_levels(h.of("features")[-1])
        assert np.all(levels[:, -1] == 2) and np.all(levels[:, 0] == 0)       # near goal ahead (large x)
        # a goal given in the robot frame is used as is: to the robot's left
        h.feed([(0.2, "goal", Goal2D(frame_id="base_link", x_m=0.0, y_m=30.0)), (0.3, "flow", flow(n=0))])
        levels = goal_levels(h.of("features")[-1])
        assert np.all(levels[-1, :] == 2) and np.all(levels[0, :] == 0)


def test_non_finite_goal_is_dropped():
    with Harness(CrowdFeatures) as h:
        h.feed([(0.0, "goal", Goal2D(frame_id="base_link", x_m=float("nan"))), (0.1, "flow", flow())])
        assert np.all(goal_levels(h.of("features")[-1]) == 1)


def test_the_conflict_feature_can_be_left_out_and_marks_a_standing_person():
    with Harness(CrowdFeatures, params={"conflict": False}) as h:
        plain = h.feed([(0.0, "flow", flow(n=200))])[0].msg
    assert plain.features.shape[2] == 12 and plain.names == FEATURE_NAMES
    with Harness(CrowdFeatures) as h:
        grid = h.feed([(0.0, "flow", flow(n=200, vx=0.0))])[0].msg
    conflict = grid.features[..., 12]
    assert conflict.any() and np.array_equal(conflict > 0, grid.features[..., 0] > 0)   # standing: where they are
