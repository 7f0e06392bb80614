"""Seed 14's two scenarios for the simple car, as batched simulators: reach a point, exit a maze.

Rewards are the paper's (section 4.1): eq. (5) for the distance,

    rew_dist = (e^{-a x} - e^{-a}) / (1 - e^{-a}) + 10 (e^{-a x / done} - e^{-a}) / (1 - e^{-a})
    rew      = rew_dist - 1                                   (not colliding)
    rew      = rew_dist - 1 - delta (2 min(x, 0.5))^eta       (colliding)

with the constants of gym-gazebo2's reference implementation (``ut_math.computeReward``,
the code the paper ran: a = 5, done = 0.02 m, delta = 3, eta = 0.03). The paper's printed
eq. (5) drops the second ``- e^{-a}`` (the bonus term would then never vanish far away) and
writes ``min(rew_dist, 0.5)`` in the collision term where the code takes the distance:
we follow the code, which is what produced the paper's figures.

Maze: the paper's distance is the straight line to the exit, which in a serpentine rewards
driving toward the wall that separates the car from the exit. ``distance="geodesic"`` measures
it along the corridors instead (a cost-to-go over a grid of the free space). Measured
(bench/rl_car.py): PPO exits 100 % of held-out episodes with either rule here, so the
paper's straight line stays the default. The maze is 3 m across, where the code's alpha = 5 / m
leaves the reward flat (e^-5 at 1 m): the maze takes alpha = 1 / m and done = 0.15 m (its exit
radius), the paper's hyper-parameters set to the scene's scale.
"""
from __future__ import annotations

import logging
from typing import Any

import gymnasium
import numpy as np
from scipy.ndimage import map_coordinates

from nodes.learn.vec_sim import VecSim
from nodes.nav.dijkstra import cost_to_go
from sim.diff_car import RADIUS_M, V_MAX_MPS, W_MAX_RADPS, Walls, box_walls, integrate

log = logging.getLogger(__name__)

ALPHA, DONE_M, DELTA, ETA = 5.0, 0.02, 3.0, 0.03


def reward(dist_m: np.ndarray, collided: np.ndarray | None = None, *, alpha: float = ALPHA,
           done_m: float = DONE_M) -> np.ndarray:
    """Seed 14 eq. (5), with the collision variant where ``collided``; between -1 - delta and 10.

    ``alpha`` (1/m) and ``done_m`` are the paper's hyper-parameters: the reward is flat beyond
    a few ``1/alpha`` (at alpha = 5 it changes by 0.4 % between 1 m and 3 m).
    """
    k = 1.0 - np.exp(-alpha)
    rew = (np.exp(-alpha * dist_m) - np.exp(-alpha)) / k + 10.0 * (np.exp(-alpha * dist_m / done_m) - np.exp(-alpha)) / k
    rew = rew - 1.0
    if collided is not None:
        rew = rew - np.where(collided, DELTA * (2.0 * np.minimum(dist_m, 0.5)) ** ETA, 0.0)
    return rew


ACTIONS = gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)   # (v, w) as fractions of the limits


class _Car(VecSim):
    """The car's state and the common observation: pose, target, target in the body frame, last command."""

    DT_S = 0.1
    action_space = ACTIONS

    def _setup_car(self) -> None:
        self.pose = np.zeros((self.n, 3))
        self.target = np.zeros((self.n, 2))
        self.last = np.zeros((self.n, 2))

    def _car_obs(self) -> np.ndarray:
        x, y, th = self.pose.T
        dx, dy = self.target[:, 0] - x, self.target[:, 1] - y
        c, s = np.cos(th), np.sin(th)
        out = np.empty((self.n, 11))
        out[:, 0], out[:, 1], out[:, 2], out[:, 3] = x, y, c, s
        out[:, 4:6] = self.target
        out[:, 6], out[:, 7], out[:, 8] = c * dx + s * dy, -s * dx + c * dy, np.hypot(dx, dy)
        out[:, 9:11] = self.last
        return out

    def _move(self, actions: np.ndarray) -> np.ndarray:
        v, w = actions[:, 0] * V_MAX_MPS, actions[:, 1] * W_MAX_RADPS
        self.last = actions
        return integrate(self.pose, v, w, self.DT_S)


class ReachCar(_Car):
    """Reach a point: start at the origin with a random heading, target 0.3-1.5 m away in any
    direction, 10 s per episode (no early end: the car must stop on the target and stay)."""

    MAX_STEPS = 100
    metric_names = ("distance_m",)
    observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (11,), np.float32)

    def configure(self, *, min_range_m: float = 0.3, max_range_m: float = 1.5, shaping: float = 0.0,
                  shaping_gamma: float = 0.99, step_cost: float = 1.0) -> None:
        """Training-signal options (the defaults give the paper's reward; the metric is the final
        distance whatever the reward): ``shaping`` (reward per m, 0: off) adds the potential-based
        term F = gamma Phi(s') - Phi(s) with Phi = -shaping x distance (Ng et al. 1999: the optimal
        policy is unchanged when ``shaping_gamma`` is the learner's discount); ``step_cost`` is the
        constant eq. (5) takes off every step (the paper's 1), which changes no policy's ranking here
        (every episode lasts MAX_STEPS steps) but sets the sign of every return."""
        if not 0.0 <= min_range_m <= max_range_m:
            raise ValueError(f"need 0 <= min_range_m <= max_range_m, got {min_range_m}, {max_range_m}")
        if not (np.isfinite(shaping) and shaping >= 0 and 0 < shaping_gamma <= 1):
            raise ValueError(f"need shaping >= 0 (reward per m; 0: off) and 0 < shaping_gamma <= 1 (the learner's "
                             f"discount), got {shaping}, {shaping_gamma}")
        self.ranges_m = (float(min_range_m), float(max_range_m))
        if not np.isfinite(step_cost):
            raise ValueError(f"step_cost must be finite (the paper's 1), got {step_cost}")
        self.shaping, self.shaping_gamma, self.step_cost = float(shaping), float(shaping_gamma), float(step_cost)
        self._setup_car()

    def _reset(self, mask: np.ndarray) -> None:
        for i in np.flatnonzero(mask):
            rng = self.rngs[i]
            r, bearing, yaw = rng.uniform(*self.ranges_m), rng.uniform(-np.pi, np.pi), rng.uniform(-np.pi, np.pi)
            self.pose[i] = (0.0, 0.0, yaw)
            self.target[i] = (r * np.cos(bearing), r * np.sin(bearing))
            self.last[i] = 0.0

    def _observe(self) -> np.ndarray:
        return self._car_obs().astype(np.float32)

    def _advance(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        before = np.hypot(*(self.target - self.pose[:, :2]).T)
        self.pose = self._move(actions)
        dist = np.hypot(*(self.target - self.pose[:, :2]).T)
        rew = reward(dist) + (1.0 - self.step_cost)
        if self.shaping:
            rew = rew + self.shaping * (before - self.shaping_gamma * dist)     # gamma Phi(s') - Phi(s)
        return rew, np.zeros(self.n, bool), dist[:, None]


def serpentine() -> tuple[np.ndarray, tuple[float, float, float], tuple[float, float]]:
    """A 3 m x 3 m maze of three corridors: walls, start pose, exit point.

    The exit is 2 m straight above the start but 6 m away along the corridors.
    """
    walls = np.vstack([box_walls(0.0, 0.0, 3.0, 3.0),
                       [[0.0, 1.0, 2.0, 1.0],      # gap on the right between the first and second corridor
                        [1.0, 2.0, 3.0, 2.0]]])    # gap on the left between the second and third
    return walls, (0.5, 0.5, 0.0), (0.5, 2.5)


class MazeCar(_Car):
    """Exit a maze: start in the first corridor, reach the exit (within ``exit_radius_m``: the episode
    terminates, success) in 30 s. Observation: the car's (11) plus ``n_rays`` range readings over 360 deg."""

    MAX_STEPS = 300
    metric_names = ("distance_m", "collided", "success")

    def configure(self, *, distance: str = "euclidean", n_rays: int = 16, max_range_m: float = 2.0,
                  exit_radius_m: float = 0.15, start_jitter_m: float = 0.15, walls: Any = None,
                  start: Any = None, exit: Any = None, grid_m: float = 0.05, alpha: float = 1.0,
                  done_m: float = 0.15) -> None:
        maze_walls, maze_start, maze_exit = serpentine()
        self.walls = Walls(np.asarray(maze_walls if walls is None else walls, float).reshape(-1, 4))
        self.start = np.asarray(maze_start if start is None else start, float)
        self.exit = np.asarray(maze_exit if exit is None else exit, float)
        if distance not in ("geodesic", "euclidean"):
            raise ValueError(f"distance must be 'geodesic' or 'euclidean', got {distance!r}")
        if n_rays < 0 or max_range_m <= 0 or exit_radius_m <= 0:
            raise ValueError("need n_rays >= 0, max_range_m > 0 and exit_radius_m > 0")
        self.distance, self.max_range_m = distance, float(max_range_m)
        self.alpha, self.done_m = float(alpha), float(done_m)
        self.exit_radius_m, self.jitter_m = float(exit_radius_m), float(start_jitter_m)
        self.ray_angles = np.linspace(-np.pi, np.pi, n_rays, endpoint=False)
        self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (11 + n_rays,), np.float32)
        self._field(grid_m)
        self._setup_car()

    def _field(self, grid_m: float) -> None:
        """Cost-to-go to the exit over the free space (cells a body's width from every wall)."""
        lo = self.walls.segments.reshape(-1, 2).min(0) - grid_m
        hi = self.walls.segments.reshape(-1, 2).max(0) + grid_m
        xs, ys = np.arange(lo[0], hi[0] + grid_m, grid_m), np.arange(lo[1], hi[1] + grid_m, grid_m)
        gx, gy = np.meshgrid(xs, ys)
        free = self.walls.clearance(np.column_stack([gx.ravel(), gy.ravel()])).reshape(gx.shape) > RADIUS_M * 0.5
        cell = lambda p: (int(round((p[1] - lo[1]) / grid_m)), int(round((p[0] - lo[0]) / grid_m)))  # noqa: E731
        value, _ = cost_to_go(np.where(free, 1.0, np.inf), cell(self.exit))
        self.reachable = bool(np.isfinite(value[cell(self.start)]))
        if not self.reachable:
            if self.distance == "geodesic":
                raise ValueError("the maze exit cannot be reached from the start: no corridor joins them "
                                 "(distance='euclidean' runs it anyway; no episode can succeed)")
            log.warning("the maze exit cannot be reached from the start: episodes will all end by the time limit")
        # unreachable cells (inside walls) get the largest finite value: the reward stays finite
        self._value = np.where(np.isfinite(value), value, value[np.isfinite(value)].max()) * grid_m
        self._lo, self._grid_m = lo, grid_m

    def _dist(self, xy: np.ndarray) -> np.ndarray:
        if self.distance == "euclidean":
            return np.hypot(*(self.exit - xy).T)
        rc = np.stack([(xy[:, 1] - self._lo[1]) / self._grid_m, (xy[:, 0] - self._lo[0]) / self._grid_m])
        return map_coordinates(self._value, rc, order=1, mode="nearest")

    def _reset(self, mask: np.ndarray) -> None:
        for i in np.flatnonzero(mask):
            rng = self.rngs[i]
            self.pose[i] = self.start + (*rng.uniform(-self.jitter_m, self.jitter_m, 2), rng.uniform(-np.pi, np.pi))
            self.target[i] = self.exit
            self.last[i] = 0.0

    def _observe(self) -> np.ndarray:
        rays = self.walls.ranges(self.pose, self.ray_angles, self.max_range_m)
        return np.hstack([self._car_obs(), rays]).astype(np.float32)

    def _advance(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        moved = self._move(actions)
        # a move that would bring the body into a wall does not happen (the car is stopped there);
        # a step moves at most 0.1 m, half the 0.2 m it takes to pass through a wall unseen
        collided = self.walls.clearance(moved[:, :2]) < RADIUS_M
        self.pose = np.where(collided[:, None], np.column_stack([self.pose[:, :2], moved[:, 2]]), moved)
        dist = self._dist(self.pose[:, :2])
        success = np.hypot(*(self.exit - self.pose[:, :2]).T) < self.exit_radius_m
        return reward(dist, collided, alpha=self.alpha, done_m=self.done_m), success, np.column_stack([dist, collided, success])
