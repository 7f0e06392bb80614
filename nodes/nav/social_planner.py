"""Three-layer social planning (Kim & Pineau 2016, Algorithm 2), the pure part: arrays in, decisions out.

Layer 1, global: Dijkstra over the known occupancy map (inflated by the robot radius),
re-planned when the goal or map changes or the robot strays from the path. Layer 2,
local (Algorithm 2, run on every cost grid): once the robot is inside the safe zone
(``safe_zone_m``, 0.25 m) of its current waypoint it decides again — if no cell within
``obstacle_radius_m`` (4 m) has high crowd density it follows the global path; otherwise it
runs Dijkstra over the learnt cost grid from its cell to a sub-goal (the farthest global
path point within reach) and extracts the next waypoint ``waypoint_m`` along that path.
Outside the safe zone it keeps its waypoint, except on re-plan events: the waypoint's cell
turned high-density (a pedestrian stepped onto it), the waypoint fell behind the robot,
or it has been held longer than ``waypoint_timeout_s``. A re-plan because the path became blocked keeps passing
each person beside the path on the side the path passes them unless the other side is cheaper by ``side_hold_m`` of
floor (:meth:`SocialPlanner._hold_sides`). When to go along the path is the planner's
too (path-velocity decomposition, Kant & Zucker 1986): :meth:`SocialPlanner.command` drives no
faster than :func:`nodes.nav.plan_geometry.speed_profile` chooses against the people it predicts
(:meth:`SocialPlanner.set_people`), a second in conflict priced at the learnt cost's conflict weight
(``conflict_price``) against the progress given up, priced as the local plan prices a detour. Layer 3, the collision guard, is a
separate node (:mod:`nodes.nav.collision_guard`). The node is :mod:`nodes.nav.dijkstra_planner`;
the stateless geometry and cost helpers are :mod:`nodes.nav.plan_geometry`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from nodes.nav.dijkstra import GridGraph, backtrack, cost_from, smooth_path
from nodes.nav.grid_frame import GridFrame, densify, extract_waypoint, inflate, plan_on_map, steer, to_robot, to_world
from nodes.nav.plan_geometry import (SpeedChoice, footprint_cost, on_rim, passes_people, people_motion,
                                     person_floor_cost, polyline_cost, remaining_m, rest_of_path,
                                     side_barriers, speed_profile, unseen_by_camera, waypoint_reach)


@dataclass(frozen=True)
class PlannerParams:
    """Algorithm 2 settings (metres, seconds, SI velocities)."""

    safe_zone_m: float = 0.25
    obstacle_radius_m: float = 4.0
    subgoal_m: float = 4.0
    waypoint_m: float = 2.0       # 1 m made the robot weave (turn-in-place on every new waypoint): bench/social_nav.py
    waypoint_min_m: float = 0.0   # ... but not past the local path's first corner, unless that is nearer than this
    corner_people_only: bool = True   # ... and only when the short cut past the corner passes people
    waypoint_timeout_s: float = 3.0
    stray_m: float = 1.5
    robot_radius_m: float = 0.35
    inflate_margin_m: float = 0.1
    v_max_mps: float = 1.0
    w_max_radps: float = 1.2
    crowd_margin_m: float = 0.3   # the cost grid is dilated by robot radius + this (personal space)
    person_cost: float = 0.0      # > 0: cells with people (high density, predicted crossings) cost at least this x the
                                  # median. Off: the learnt cost alone (its 'conflict' weight, learnt from real
                                  # walkers) keeps people at a distance; the hard safety distance is the guard's.
                                  # (Before the conflict feature, 4 carried the avoidance: issue 18.)
    commitment: float = 0.5       # cost of moving the sub-goal between re-plans, x typical cost per cell
    replan_margin_m: float = 0.5  # a blocked path is replaced only by a plan cheaper by this much typical floor; < 0: always
    side_hold_m: float = 2.0      # > 0: a re-plan because the path became blocked prices passing a person beside the path
                                  # on the other side than the path does as this much more typical floor (_hold_sides).
                                  # Over 6 starts (bench/social_nav.py): hallway strict robot contacts 2 -> 0, closest
                                  # min 0.23 -> 0.46 m, guard median 0.316 -> 0.314 (no real change); held out (toward,
                                  # crossing, group, students003, zara03) strict contacts 3 -> 1. 0: off
    side_near_m: float = 1.5      # ... people whose centre is this near the path (beside it, level with a point of it)
    side_ray_m: float = 3.0       # ... the barrier: a ray this long from each such person away from the path
    side_motion: bool = True      # ... only people seen there (set_people) who stay on their side until the robot is
                                  # level with them (not walking across the path); False: every people cell's group
    turn_near_radps: float = 0.0  # > 0: turning toward a person nearer than turn_near_m (beside or ahead, on the side
                                  # the robot turns to) is at most this fast (command); 0: steering's w_max_radps.
                                  # Off: 0.6 on hallway (6 starts, with a side hold that held every people cell's
                                  # side) gave guard median 0.275 against 0.260 without it
    turn_near_m: float = 1.5
    memory_s: float = 1.5         # unseen cells keep what was seen there this long
    fov_deg: float = 57.0         # the camera's horizontal field of view
    camera_x_m: float = 0.3       # camera ahead of the robot centre
    min_range_m: float = 0.4      # the camera measures nothing nearer
    # when to go (path-velocity decomposition, plan_geometry.speed_profile): the speed along the path is chosen
    # against the people's predicted motion (set_people), priced with the learnt cost
    conflict_price: float = 0.0   # the learnt price of a conflict cell (weights file 'conflict'); 0 = speed off
    speed_horizon_s: float = 2.0  # how far ahead in time the speed candidates are compared
    headway_s: float = 1.0        # the path ahead of the robot kept clear: this many seconds of its own travel
    accel_mps2: float = 0.8       # the robot's acceleration and braking (sim.crowd max_accel_mps2)
    people_timeout_s: float = 0.5  # predictions older than this are not used


@dataclass
class Decision:
    """What the planner decided on a cost grid: mode, the event that caused it, the waypoint (world, m)."""

    mode: str                      # idle | global | local | hold | reached | unreachable
    event: str = ""                # new_goal | safe_zone | waypoint_blocked | waypoint_behind | timeout | ...
    waypoint: np.ndarray | None = None
    path_xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    plan_ms: float = 0.0
    reason: str = ""
    score: float = float("inf")    # local plan: its cost to the sub-goal plus the typical cost of the rest of the way


class SocialPlanner:
    """Pure Algorithm 2 state machine; see the module docstring."""

    def __init__(self, params: PlannerParams = PlannerParams()) -> None:
        self.p = params
        self.goal: np.ndarray | None = None
        self.goal_tol_m = 0.3
        self.occupied: np.ndarray | None = None
        self.map_frame: GridFrame | None = None
        self.global_path: np.ndarray | None = None
        self.mode = "idle"
        self.waypoint: np.ndarray | None = None
        self.waypoint_t_s = 0.0
        self._graphs: dict[tuple[int, int], GridGraph] = {}
        self._event = "new_goal"
        self._subgoal: np.ndarray | None = None
        self._path: np.ndarray | None = None           # local path being followed (world, m)
        self._memory: list[tuple] = []
        self._walls: np.ndarray | None = None           # map cells on or next to static obstacles (not inflated)
        self._people: tuple | None = None               # (t_s, world xy, world velocity, when each was last seen)
        self._floor: tuple[float, float] | None = None  # typical planning-grid cell cost and cell size (m), last update
        self.speed: SpeedChoice | None = None          # the last command's speed choice (None: not asked)
        self.speed_steer_mps = 0.0                     # ... and the speed steering alone asked for

    # -- inputs -----------------------------------------------------------------------------------
    def set_goal(self, xy: tuple[float, float], tolerance_m: float = 0.3) -> None:
        """A new goal resets the plans; the same goal sent again (goals are re-published) changes nothing."""
        if self.goal is not None and np.allclose(self.goal, xy) and self.goal_tol_m == tolerance_m:
            return
        self.goal = np.asarray(xy, float).reshape(2)
        self.goal_tol_m = float(tolerance_m)
        self.global_path, self.waypoint, self._event, self._subgoal = None, None, "new_goal", None

    def set_map(self, occupancy: np.ndarray, frame: GridFrame) -> None:
        """Occupancy (rows = y, cols = x; > 0.5 occupied) of the known world map."""
        radius = (self.p.robot_radius_m + self.p.inflate_margin_m) / frame.resolution_m
        self.occupied = inflate(np.asarray(occupancy) > 0.5, radius)
        self._walls = inflate(np.asarray(occupancy) > 0.5, 0.15 / frame.resolution_m)
        self.map_frame = frame
        self.global_path, self._event = None, "new_map"

    def set_people(self, pose: tuple[float, float, float], points_m: np.ndarray, velocity_mps: np.ndarray,
                   t_s: float) -> None:
        """The flow's points (robot frame at ``pose``, (N, 3) m and m/s, taken at ``t_s``): what the speed
        profile predicts people from (:func:`nodes.nav.plan_geometry.people_motion`). Points on or within
        0.15 m of the map's static obstacles are not people. People the camera cannot see now (outside its
        view, or nearer than it measures) are kept ``memory_s``, moving on at their velocity: a walker who
        stalls right in front of the robot turns into depth holes, and planning as if they had gone had the
        robot drive at them (the guard then stopped it; the cost grid has the same memory, :meth:`_remember`).
        """
        xy, v = people_motion(points_m, velocity_mps)
        world = to_world(pose, xy)
        v_world = to_world((0.0, 0.0, pose[2]), v)          # velocities turn with the robot, do not move with it
        if self._walls is not None and self.map_frame is not None and len(world):
            cells = self.map_frame.cell_of(world)
            inside = self.map_frame.inside(cells)
            cells = self.map_frame.clamp(cells)
            keep = ~(inside & self._walls[cells[:, 0], cells[:, 1]])
            world, v_world = world[keep], v_world[keep]
        seen_world = world
        if self._people is not None and self.p.memory_s > 0:
            t0, old_xy, old_v, old_t = self._people
            age = t_s - old_t
            moved = old_xy + old_v * (t_s - t0)
            rel = to_robot(pose, moved)
            keep = ((age <= self.p.memory_s) & (np.hypot(rel[:, 0], rel[:, 1]) <= 2.0)
                    & unseen_by_camera(rel, camera_x_m=self.p.camera_x_m, fov_deg=self.p.fov_deg,
                                       min_range_m=self.p.min_range_m))
            world = np.vstack([world, moved[keep]])
            v_world = np.vstack([v_world, old_v[keep]])
            seen_t = np.concatenate([np.full(len(seen_world), float(t_s)), old_t[keep]])
        else:
            seen_t = np.full(len(world), float(t_s))
        self._people = (float(t_s), world, v_world, seen_t)

    def _graph(self, shape: tuple[int, int]) -> GridGraph:
        if shape not in self._graphs:
            self._graphs[shape] = GridGraph.of(shape)
        return self._graphs[shape]

    # -- layer 1 ----------------------------------------------------------------------------------
    def _global(self, pose: tuple[float, float, float]) -> str:
        """(Re)plan the global path when needed; returns an error reason or ''."""
        assert self.goal is not None
        if self.global_path is not None:
            if np.hypot(*(self.global_path - pose[:2]).T).min() <= self.p.stray_m:
                return ""
            self._event = "strayed"
        if self.occupied is None or self.map_frame is None:
            self.global_path = densify(np.stack([np.asarray(pose[:2]), self.goal]), 0.1)
            return ""
        path, result = plan_on_map(self.occupied, self.map_frame, pose[:2], tuple(self.goal),
                                   graph=self._graph(self.occupied.shape))
        self.global_path = path if result.reachable else None
        return "" if result.reachable else f"global goal: {result.reason}"

    def carrot(self, pose: tuple[float, float, float]) -> np.ndarray:
        """The global-path point ``waypoint_m`` ahead of the path point closest to the robot."""
        assert self.global_path is not None
        i = int(np.argmin(np.hypot(*(self.global_path - pose[:2]).T)))
        return extract_waypoint(self.global_path[i:], self.p.waypoint_m)

    # -- layer 2 ----------------------------------------------------------------------------------
    def update(self, pose: tuple[float, float, float], cost: np.ndarray, frame: GridFrame,
               high_density: np.ndarray, t_s: float, predicted: np.ndarray | None = None) -> Decision:
        """Algorithm 2 on one cost grid (robot frame, ``frame``) with its high-density mask.

        ``predicted`` (optional, rows x cols bool, see :func:`nodes.nav.plan_geometry.predict_conflicts`)
        marks cells a moving person is expected to reach when the robot would: they count as high
        density. Cells with people (high density or predicted) cost at least ``person_cost`` times the
        median cell (:func:`nodes.nav.plan_geometry.person_floor_cost`). Cells on static obstacles of
        the map never count as crowd (walls are dense too).
        """
        if self.goal is None:
            return Decision("idle", reason="no goal yet")
        if np.hypot(*(self.goal - pose[:2])) <= self.goal_tol_m:
            self.mode, self.waypoint = "reached", None
            return Decision("reached", "goal", self.goal)
        reason = self._global(pose)
        if reason:
            self.mode, self.waypoint = "unreachable", None
            return Decision("unreachable", reason=reason)
        cost, high_density = np.asarray(cost, float), np.asarray(high_density, bool)
        static = self._static_mask(pose, frame)
        cost, high_density = self._remember(pose, cost, frame, high_density & ~static, t_s)
        if predicted is not None and predicted.shape == cost.shape and predicted.any():
            high_density = high_density | (predicted & ~static)
        cost = person_floor_cost(cost, high_density, self.p.person_cost)
        footprint = footprint_cost(cost, self._clear_full_m / frame.resolution_m)
        if np.isfinite(cost).any():  # the speed profile prices progress as the local plan prices a detour (_local)
            self._floor = (float(np.median(footprint[np.isfinite(footprint)])), frame.resolution_m)
        event = self._replan_event(pose, frame, high_density, t_s)
        if not event:
            return Decision(self.mode, "", self.waypoint)
        if not self._obstacle_near(frame, high_density):
            self.mode, self.waypoint, self._subgoal = "global", None, None
            return Decision("global", event, self.carrot(pose), self.global_path)
        t0 = time.perf_counter()
        subgoal = self._subgoal
        grid = self._planning_cost(footprint, static)
        if event == "path_blocked":
            grid = self._hold_sides(pose, grid, frame, high_density, t_s)
        decision = self._local(pose, grid, frame, event, high_density)
        decision.plan_ms = (time.perf_counter() - t0) * 1e3
        if event == "path_blocked" and decision.mode == "local" and not self._worth_switching(pose, grid, frame, decision):
            self._subgoal = subgoal
            return Decision(self.mode, "", self.waypoint, plan_ms=decision.plan_ms, reason="path kept")
        self.mode, self.waypoint, self.waypoint_t_s = decision.mode, decision.waypoint, t_s
        self._path = decision.path_xy if decision.mode == "local" else None
        return decision

    def _path_blocked(self, pose: tuple[float, float, float], frame: GridFrame, people: np.ndarray) -> bool:
        """Does the local path being followed now pass within the robot's footprint of a person?"""
        if self._path is None or len(self._path) < 2:
            return False
        return passes_people(pose, frame, people, self._path, self._clear_m, ahead_only=True)

    @property
    def _clear_m(self) -> float:
        """How near a path may pass a people cell: the robot's radius plus half the crowd margin."""
        return self.p.robot_radius_m + 0.5 * self.p.crowd_margin_m

    def _remember(self, pose: tuple[float, float, float], cost: np.ndarray, frame: GridFrame, high: np.ndarray,
                  t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Cells the camera cannot see now (outside its field of view, or nearer than it can
        measure) keep the dearest cost and the density flag they had in the last ``memory_s``.

        The camera sees ~57 degrees; a pedestrian being passed leaves the view while still at
        arm's length, and planning as if they had vanished steers the robot back into them
        (the paper's Sec. 7.1 limitation). What is in view always overrides the memory.
        """
        self._memory = [m for m in self._memory if t_s - m[0] <= self.p.memory_s and m[3].shape == frame.shape]
        entry = (t_s, pose, cost, frame, high)
        if not self._memory or self.p.memory_s <= 0:
            self._memory.append(entry)
            return cost, high
        rr, cc = np.mgrid[:frame.shape[0], :frame.shape[1]]
        rel = frame.xy_of(np.stack([rr.ravel(), cc.ravel()], axis=1))
        unseen = unseen_by_camera(rel, camera_x_m=self.p.camera_x_m, fov_deg=self.p.fov_deg,
                                  min_range_m=self.p.min_range_m)
        world = to_world(pose, rel[unseen])
        fused_cost, fused_high = cost.reshape(-1).copy(), high.reshape(-1).copy()
        for _, m_pose, m_cost, m_frame, m_high in self._memory:
            cells = m_frame.cell_of(to_robot(m_pose, world))
            ok = m_frame.inside(cells)
            idx = np.flatnonzero(unseen)[ok]
            fused_cost[idx] = np.maximum(fused_cost[idx], m_cost[cells[ok, 0], cells[ok, 1]])
            fused_high[idx] |= m_high[cells[ok, 0], cells[ok, 1]]
        self._memory.append(entry)
        return fused_cost.reshape(cost.shape), fused_high.reshape(high.shape)

    def _replan_event(self, pose: tuple[float, float, float], frame: GridFrame, high: np.ndarray, t_s: float) -> str:
        if self._event:
            event, self._event = self._event, ""
            return event
        if self.mode != "local" or self.waypoint is None:
            return "global_path" if self.mode == "global" else "hold_retry"
        rel = to_robot(pose, self.waypoint)[0]
        if np.hypot(*rel) <= self.p.safe_zone_m:
            return "safe_zone"
        cell = frame.cell_of(rel)
        if frame.inside(cell)[0] and high[cell[0, 0], cell[0, 1]]:
            return "waypoint_blocked"
        if self._path_blocked(pose, frame, high):
            return "path_blocked"
        if self._passed(pose):
            return "waypoint_behind"
        return "timeout" if t_s - self.waypoint_t_s > self.p.waypoint_timeout_s else ""

    def _passed(self, pose: tuple[float, float, float]) -> bool:
        """Has the robot gone past its waypoint (behind the robot along the local path's direction)?

        Not "behind the robot's heading": while the robot turns toward a new waypoint on its
        other side, that waypoint is briefly behind its heading, and re-planning then (group:
        waypoint_behind while turning in place) picked yet another waypoint before the turn ended.
        """
        assert self.waypoint is not None
        if self._path is None or len(self._path) < 2:
            return bool(to_robot(pose, self.waypoint)[0, 0] < 0)
        return bool(np.dot(self.waypoint - np.asarray(pose[:2]), self.waypoint - self._path[0]) < 0)

    def _obstacle_near(self, frame: GridFrame, high: np.ndarray) -> bool:
        cells = np.argwhere(high)
        if len(cells) == 0:
            return False
        return bool((np.hypot(*frame.xy_of(cells).T) <= self.p.obstacle_radius_m).any())

    def _static_mask(self, pose: tuple[float, float, float], frame: GridFrame) -> np.ndarray:
        """Local cells (robot frame) that fall on inflated static obstacles of the map."""
        if self.occupied is None or self.map_frame is None:
            return np.zeros(frame.shape, bool)
        rr, cc = np.mgrid[:frame.shape[0], :frame.shape[1]]
        world = to_world(pose, frame.xy_of(np.stack([rr.ravel(), cc.ravel()], axis=1)))
        cells = self.map_frame.cell_of(world)
        inside = self.map_frame.inside(cells)
        cells = self.map_frame.clamp(cells)
        return (inside & self.occupied[cells[:, 0], cells[:, 1]]).reshape(frame.shape)

    def _local(self, pose: tuple[float, float, float], cost: np.ndarray, frame: GridFrame, event: str,
               people: np.ndarray | None = None) -> Decision:
        """Dijkstra from the robot over the local planning grid (``cost``, from :meth:`_planning_cost`) to a
        sub-goal; the sub-goal is the cell at the
        edge of the local action radius (``subgoal_m``; or the goal itself when nearer) that minimises
        cost-so-far + (typical cell cost) x (remaining global-path length).

        Taking the global path's point at ``subgoal_m`` as the sub-goal would end every local plan
        on that point even when a pedestrian stands on it; scoring the whole rim lets the plan end
        beside the person, on the side that is cheaper overall.
        """
        assert self.global_path is not None and self.goal is not None
        start = tuple(frame.clamp(frame.cell_of(np.zeros(2)))[0])
        dist, pred = cost_from(cost, start, graph=self._graph(cost.shape))
        rr, cc = np.mgrid[:frame.shape[0], :frame.shape[1]]
        cells = np.stack([rr.ravel(), cc.ravel()], axis=1)
        xy = frame.xy_of(cells)
        r = np.hypot(xy[:, 0], xy[:, 1])
        goal_rel = to_robot(pose, self.goal)[0]
        goal_cell = frame.cell_of(goal_rel)
        if np.hypot(*goal_rel) <= self.p.subgoal_m and frame.inside(goal_cell)[0]:
            rim = (np.abs(cells - goal_cell).max(axis=1) <= 1)           # the goal (or next to it)
        else:
            rim = on_rim(r, self.p.subgoal_m, frame.resolution_m)
        reachable = np.isfinite(dist.ravel()) & (r <= self.p.subgoal_m)
        ok = rim & reachable
        if not ok.any():        # the rim is walled off (facing a wall, a corner): any reachable cell will do
            ok = reachable & (np.abs(cells - np.array(start)).max(axis=1) > 0)
        if not ok.any():
            return Decision("hold", event, None, reason="local plan: no reachable cell around the robot")
        rim_world = to_world(pose, xy[ok])
        remaining = self._remaining_m(pose, rim_world)
        if remaining.min() >= self._remaining_m(pose, np.asarray(pose[:2])[None])[0]:
            # nothing in view gets closer to the goal: turn toward the global path and look again
            return Decision("global", event, self.carrot(pose), self.global_path, reason="no progress in view")
        typical = float(np.median(cost[np.isfinite(cost)]))
        score = dist.ravel()[ok] + typical * remaining / frame.resolution_m
        if self._subgoal is not None:      # commit to a side: moving the sub-goal costs like walking there
            score += self.p.commitment * typical * np.hypot(*(rim_world - self._subgoal).T) / frame.resolution_m
        k = int(np.argmin(score))
        plan_score = float(dist.ravel()[ok][k] + typical * remaining[k] / frame.resolution_m)
        self._subgoal = rim_world[k]
        sub = cells[np.flatnonzero(ok)[k]]
        corners = smooth_path(cost, backtrack(pred, tuple(sub)))
        path_xy = to_world(pose, np.vstack([np.zeros((1, 2)), frame.xy_of(corners[1:])]))
        reach = waypoint_reach(path_xy, self.p.waypoint_m, waypoint_min_m=self.p.waypoint_min_m, pose=pose,
                               frame=frame, people=people if self.p.corner_people_only else None,
                               clear_m=self._clear_m)
        return Decision("local", event, extract_waypoint(path_xy, reach), path_xy, score=plan_score)

    def _people_now(self, pose: tuple[float, float, float], t_s: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The people points (:meth:`set_people`) moved on to ``t_s`` and their velocities, robot frame at ``pose``;
        None when there is no prediction no older than ``people_timeout_s``."""
        if self._people is None or not 0 <= t_s - self._people[0] <= self.p.people_timeout_s:
            return None
        t0, xy, vel, _ = self._people
        return to_robot(pose, xy + vel * (t_s - t0)), to_robot((0.0, 0.0, pose[2]), vel)

    def _hold_sides(self, pose: tuple[float, float, float], grid: np.ndarray, frame: GridFrame,
                    people: np.ndarray, t_s: float) -> np.ndarray:
        """The planning grid with a price (``side_hold_m`` of typical floor per cell) on the cells a plan crosses to
        pass a person beside the path being followed on its other side (:func:`side_barriers`); unchanged when
        ``side_hold_m`` is 0 or there is no path.

        For re-plans because the path became blocked only: a walker's cells cost little more than free floor,
        and the fresh plan chose either side of the same walker grid after grid (hallway: the plan's offset
        +1.1 m then -1.1 m within 0.5 s); each flip turned the robot at its full rate, and that turn's arc swept
        into the people beside it. The other side stays open: a plan takes it when it is cheaper by more than
        the price, or when this side is walled off.
        """
        if self.p.side_hold_m <= 0 or self._path is None or len(self._path) < 2:
            return grid
        motion = None
        if self.p.side_motion:      # no fresh prediction: nobody seen, nobody holds a side
            motion = self._people_now(pose, t_s) or (np.zeros((0, 2)), np.zeros((0, 2)))
        barrier = side_barriers(to_robot(pose, self._path), people, frame, near_m=self.p.side_near_m,
                                length_m=self.p.side_ray_m, min_side_m=0.5 * frame.resolution_m,
                                motion=motion, robot_speed_mps=self.p.v_max_mps)
        start = frame.clamp(frame.cell_of(np.zeros(2)))[0]
        barrier[start[0], start[1]] = False
        if not barrier.any():
            return grid
        typical = float(np.median(grid[np.isfinite(grid)]))
        return np.where(barrier, grid + typical * self.p.side_hold_m / frame.resolution_m, grid)

    @staticmethod
    def _planning_cost(footprint: np.ndarray, static: np.ndarray) -> np.ndarray:
        """The grid the local plan searches: the robot's footprint cost (:func:`footprint_cost` of the cell
        costs), the map's static obstacles (``static``, :meth:`_static_mask`) impassable."""
        # the map's obstacles come already grown by the robot's radius (set_map): growing them again
        # with the footprint left a 4 m hallway 1.8 m of room for the robot centre instead of 3.1 m,
        # and held the robot in the middle lane, head-on with the oncoming walkers
        return np.where(static, np.inf, footprint)

    def _worth_switching(self, pose: tuple[float, float, float], grid: np.ndarray, frame: GridFrame,
                         new: Decision) -> bool:
        """Is the fresh plan ``new`` cheaper than what is left of the path being followed, priced on the
        same planning grid (``grid``), by more than walking ``replan_margin_m`` of typical floor costs?

        The path-blocked test flags a path that passes people (high density or predicted); with the
        learnt cost alone (``person_cost`` 0) the fresh plan may pass the same people because the cost
        says that is still the cheapest way, and the test fired again on the next grid: hallway
        re-planned on half of its cost grids, each plan a slightly different waypoint, and the robot
        weaved (heading swinging +-30 degrees, turn rate saturating both ways within 0.4 s). The
        cost decides which path is better; the margin keeps noise in the grid from flipping it. It is
        absolute (a length of floor), not a fraction: both costs include the rest of the way to the
        goal, which a fraction would scale with the distance left. Also switching whenever the fresh plan passes
        nobody (helper-59, hallway start 0): guard share 0.32 -> 0.39, braked while keeping a blocked path 0.19 -> 0.22
        (the plan flipped sides again).
        """
        if self.p.replan_margin_m < 0 or self._path is None or self.waypoint is None or self._subgoal is None:
            return True
        rest = rest_of_path(self._path, self.waypoint)
        cells = frame.cell_of(np.vstack([np.zeros((1, 2)), to_robot(pose, rest)]))
        if not frame.inside(cells).all():
            return True
        start = frame.clamp(frame.cell_of(np.zeros(2)))[0]
        cells[0] = start
        old = polyline_cost(grid, cells)
        typical = float(np.median(grid[np.isfinite(grid)]))
        old += typical * float(self._remaining_m(pose, self._path[-1:])[0]) / frame.resolution_m
        return bool(not np.isfinite(old) or new.score < old - typical * self.p.replan_margin_m / frame.resolution_m)

    def _remaining_m(self, pose: tuple[float, float, float], xy: np.ndarray) -> np.ndarray:
        """Distance (m) from world points (n, 2) to the global goal along the global path (ahead of the robot)."""
        assert self.global_path is not None
        return remaining_m(self.global_path, pose[:2], xy)

    # -- command ----------------------------------------------------------------------------------
    def command(self, pose: tuple[float, float, float], t_s: float | None = None,
                v_now_mps: float | None = None) -> tuple[float, float]:
        """(v_mps, w_radps) toward the current waypoint (global mode: the carrot); 0 when idle; held: turn in place.

        With ``t_s`` (and people from :meth:`set_people` no older than ``people_timeout_s``) and a
        ``conflict_price``, the speed is at most what :meth:`_speed` chooses along the path ahead; the
        turn rate is steering's. ``v_now_mps`` is the robot's speed (odometry; default: steering's).
        """
        self.speed = None
        if self.goal is None or self.mode in ("idle", "reached", "unreachable"):
            return 0.0, 0.0
        if np.hypot(*(self.goal - pose[:2])) <= self.goal_tol_m:
            return 0.0, 0.0
        if self.global_path is None and self._global(pose):
            return 0.0, 0.0
        if self.mode == "hold":
            # no cell in view to plan to (facing a wall or a corner): turn on the spot toward the
            # global path so the camera sees a way out. Standing still re-tried the same empty view
            # for ever (seen in a hallway trial: 25 s facing the wall after a detour toward it)
            return 0.0, steer(pose, self.carrot(pose), v_max_mps=self.p.v_max_mps, w_max_radps=self.p.w_max_radps)[1]
        target = self.carrot(pose) if self.mode == "global" or self.waypoint is None else self.waypoint
        final = bool(np.allclose(target, self.goal))
        # brake to stop on the goal point itself: it is reached on entering the tolerance, and braking
        # to stop inside it (0.15 m short) cost ~0.1 s at 0.8 m/s^2 for nothing
        v, w = steer(pose, target, v_max_mps=self.p.v_max_mps, w_max_radps=self.p.w_max_radps,
                     stop_at_m=0.0 if final else None)
        self.speed_steer_mps = v
        if t_s is not None:
            w = self._turn_bound(pose, t_s, w)
        if t_s is not None and v > 0:
            choice = self._speed(pose, target, t_s, v if v_now_mps is None else v_now_mps)
            if choice is not None:
                self.speed = choice
                v = min(v, choice.v_mps)
        return v, w

    def _turn_bound(self, pose: tuple[float, float, float], t_s: float, w_radps: float) -> float:
        """``w_radps`` at most ``turn_near_radps`` in size when it turns the robot toward a person (predicted now from
        :meth:`set_people`, no older than ``people_timeout_s``) within ``turn_near_m`` beside or ahead of it, on the
        side it turns to; unchanged otherwise (off, no fresh people, nobody there)."""
        if self.p.turn_near_radps <= 0 or abs(w_radps) <= self.p.turn_near_radps:
            return w_radps
        people = self._people_now(pose, t_s)
        if people is None or not len(people[0]):
            return w_radps
        rel = people[0]
        near = ((np.hypot(rel[:, 0], rel[:, 1]) <= self.p.turn_near_m) & (rel[:, 0] > -self.p.robot_radius_m)
                & (rel[:, 1] * w_radps > 0))
        return float(np.clip(w_radps, -self.p.turn_near_radps, self.p.turn_near_radps)) if near.any() else w_radps

    def _ahead(self, pose: tuple[float, float, float], target: np.ndarray, *, length_m: float = 4.0,
               dt_s: float = 0.1) -> np.ndarray:
        """The path the robot will drive (world, (n, 2)): steering's own track toward ``target`` (the unicycle
        rolled out with :func:`nodes.nav.grid_frame.steer`, so a turn is the arc it really drives, not the
        straight line to the waypoint), then on along the local path being followed (or the global path)
        beyond it; ``length_m`` of it at most."""
        if self.mode == "local" and self._path is not None and len(self._path) >= 2 and self.waypoint is not None:
            beyond = rest_of_path(self._path, target)[1:]
        elif self.global_path is not None:
            i = int(np.argmin(np.hypot(*(self.global_path - target).T)))
            beyond = self.global_path[i + 1:]
        else:
            beyond = np.zeros((0, 2))
        x, y, yaw = (float(a) for a in pose)
        track, travelled = [(x, y)], 0.0
        while travelled < length_m and np.hypot(target[0] - x, target[1] - y) > self.p.safe_zone_m:
            v, w = steer((x, y, yaw), target, v_max_mps=self.p.v_max_mps, w_max_radps=self.p.w_max_radps)
            v = max(v, 0.2 * self.p.v_max_mps)          # turning on the spot: the track starts where it stands
            x, y, yaw = x + v * np.cos(yaw) * dt_s, y + v * np.sin(yaw) * dt_s, yaw + w * dt_s
            track.append((x, y))
            travelled += v * dt_s
        return np.vstack([np.asarray(track), np.asarray(target, float)[None], beyond])

    def _speed(self, pose: tuple[float, float, float], target: np.ndarray, t_s: float,
               v_now_mps: float) -> SpeedChoice | None:
        """The speed profile's choice along the path ahead (None: off, or no fresh prediction of people)."""
        if self.p.conflict_price <= 0 or self.p.speed_horizon_s <= 0 or self._floor is None:
            return None
        people = self._people_now(pose, t_s)
        if people is None:
            return None
        price, cell = self._floor
        return speed_profile(to_robot(pose, self._ahead(pose, target)), *people, v_now_mps=v_now_mps,
                             v_max_mps=self.p.v_max_mps, conflict_price=self.p.conflict_price, progress_price=price,
                             cell_m=cell,
                             clear_m=self._clear_full_m, headway_s=self.p.headway_s,
                             horizon_s=self.p.speed_horizon_s, accel_mps2=self.p.accel_mps2)

    @property
    def _clear_full_m(self) -> float:
        """The robot's personal space: its radius plus the crowd margin (the footprint the cost grid is dilated by)."""
        return self.p.robot_radius_m + self.p.crowd_margin_m
