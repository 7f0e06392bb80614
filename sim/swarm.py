"""Swarm foraging with task partitioning (seed 09): robots carry food from a source to a nest
in a 4 m x 1 m arena and may hand it over at exchange zones.

Vectorised over robots *and* over independent worlds: every state array is (B, N) -- B
seeded worlds of N robots advanced together -- so a bench runs its 30 seeds in one call and
no Python loop runs over robots in a step (the only loops are over exchange zones)::

    from sim.swarm import SwarmScene, SwarmWorld, seed_scene
    world = SwarmWorld(seed_scene(zones=1), n_robots=20, seeds=range(30))
    world.run(200.0)                 # t_max = 200 s in 0.1 s ticks, as in the seed
    world.food                       # (B,) items delivered to the nest
    world.food / world.n             # individual efficiency I_eff = F / N, per world
    world.contact_s, world.wait_s    # (B, N) seconds each robot spent bouncing off others / waiting

The seed's model (section 3): robots are discs of radius 0.07 m with unicycle dynamics,
speed v in [0, 0.1] m/s following a P law, heading following a PD law toward 0 (carrying:
right, to the nest) or pi (not carrying: left, to the source). They have no obstacle
sensing: robots that touch bounce, each turning away from the other, and the walls reflect
them. With exchange zones the corridor is cut into segments; a robot works one segment,
and at the zone ending it waits for a partner (``transfer="direct"``: a carrier and a
receiver in the same zone hand over) or uses a cache there (``"cache"``: drop if not full,
pick if not empty). After waiting longer than ``theta_s`` (the threshold Theta) it gives up
and is reassigned to the neighbouring segment, carrying on as in the seed's FSM (figure 2).
``transfer="p2p"`` is the seed's section 4.4: no zones, a carrier that meets a robot without
food (ahead of it, toward the nest) gives it the food and both turn round. The seed's
hand-overs are instantaneous; here both partners stand still ``handover_s`` (2 s) and only
then may hand over again -- with instantaneous ones, food jumped from robot to robot through
a dense crowd faster than any robot moves (F/N *rising* to 4.9 at N = 60, measured).

``policy="adaptive"`` is the perspective of the seed's conclusion, after Pini et al. (2011,
"Task partitioning in swarms of robots: an adaptive method for strategy selection", Swarm
Intelligence 5): each robot decides from costs it experienced itself. Partitioning costs
its waits at zones (running mean ``mean_wait``); not partitioning costs the extra time a
leg takes when it goes on through a zone, over what its legs inside one segment take
(``mean_cross_excess - mean_own_excess``, excess = duration - distance / v_max). Since
going on means passing the zone twice (there and back), a robot reaching a zone waits
with probability sigmoid(beta (2 benefit - wait) / scale). It is our reading of their
idea, not their exact rule; both estimates start at 0, so robots first try both ways.

An optional wall with a gate stands on each exchange zone's centre line
(``gate_width_m``): non-partitioning robots must steer through the opening, the setting in
which Pini et al. found partitioning to pay. A gate narrower than a robot lets nobody through.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Iterable

import numpy as np

TRANSFERS = ("direct", "cache", "p2p")
POLICIES = ("fixed", "adaptive")


@dataclass(frozen=True)
class SwarmScene:
    """Arena, robots and task partitioning (SI units; defaults are the seed's)."""

    length_m: float = 4.0
    width_m: float = 1.0
    radius_m: float = 0.07
    v_max_mps: float = 0.1
    source_m: float = 0.5              # the source is x < source_m
    nest_m: float = 0.5                # the nest is x > length_m - nest_m
    zones_m: tuple[float, ...] = ()    # exchange-zone centres along x, increasing
    zone_width_m: float = 0.3
    transfer: str = "direct"
    cache_capacity: int = 10
    bounce_s: float = 1.0              # after a contact a robot drives away along the bounce heading this long
    handover_s: float = 2.0            # both partners stand still this long after a hand-over (direct, p2p)
    theta_s: float = 30.0              # waiting threshold Theta (inf: wait forever; 0: never wait)
    policy: str = "fixed"
    adaptive_beta: float = 4.0
    adaptive_memory: float = 0.3       # weight of the newest experience in the running means
    gate_width_m: float | None = None  # a wall with a gate of this width at each zone centre
    gate_y_m: float = 0.5
    kp_heading: float = 4.0            # 1/s^2
    kd_heading: float = 4.0            # 1/s: critically damped with kp = 4
    kp_speed: float = 2.0              # 1/s

    def __post_init__(self) -> None:
        if self.transfer not in TRANSFERS:
            raise ValueError(f"transfer {self.transfer!r} must be one of {TRANSFERS}")
        if self.policy not in POLICIES:
            raise ValueError(f"policy {self.policy!r} must be one of {POLICIES}")
        zones = np.asarray(self.zones_m, float)
        if self.transfer == "p2p" and len(zones):
            raise ValueError("transfer 'p2p' hands food over anywhere: give no exchange zones")
        half = self.zone_width_m / 2
        if len(zones) and (np.any(np.diff(zones) <= self.zone_width_m) or zones[0] - half < self.source_m
                           or zones[-1] + half > self.length_m - self.nest_m):
            raise ValueError(f"exchange zones {self.zones_m} must be increasing, {self.zone_width_m} m apart "
                             f"and between the source and the nest")
        if not (self.theta_s >= 0):
            raise ValueError(f"theta_s must be >= 0 (inf: wait forever), got {self.theta_s}")
        if self.radius_m <= 0 or 2 * self.radius_m >= self.width_m:
            raise ValueError(f"robot radius {self.radius_m} m must be positive and fit the arena's width")


def seed_scene(zones: int = 0, **changes: object) -> SwarmScene:
    """The seed's arena with 0, 1 or 2 exchange zones, deliberately off the middle (section 3.3)."""
    centres = {0: (), 1: (1.8,), 2: (1.4, 2.6)}
    if zones not in centres:
        raise ValueError(f"the seed studies 0, 1 or 2 exchange zones, not {zones}")
    return replace(SwarmScene(zones_m=centres[zones]), **changes)


def wrap(angle: np.ndarray) -> np.ndarray:
    """Angles to (-pi, pi]."""
    return np.pi - np.mod(np.pi - angle, 2 * np.pi)


def mutual_nearest(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i, j) with j the nearest column of row i and i the nearest row of column j.

    ``d`` (B, N, N) distances, inf where i may not pair with j. Returns (B, N) masks of the
    rows and of the columns that paired; each paired row has exactly one paired column.
    """
    to, back = d.argmin(axis=2), d.argmin(axis=1)
    rows = np.arange(d.shape[1])[None]
    mutual = np.isfinite(d.min(axis=2)) & (np.take_along_axis(back, to, axis=1) == rows)
    took = (mutual[:, :, None] & (to[:, :, None] == rows[:, None, :])).any(axis=1)
    return mutual, took


class SwarmWorld:
    """B independent worlds of N robots, stepped together (see the module docstring)."""

    def __init__(self, scene: SwarmScene, n_robots: int, seeds: Iterable[int] = (0,)) -> None:
        seeds = list(seeds)
        if n_robots < 0 or not seeds:
            raise ValueError("need n_robots >= 0 and at least one seed")
        self.scene, self.n, self.b = scene, int(n_robots), len(seeds)
        self.rngs = [np.random.default_rng(s) for s in seeds]
        shape = (self.b, self.n)
        r, s = scene.radius_m, scene
        draw = np.stack([np.stack([g.uniform(r, s.length_m - r, self.n), g.uniform(r, s.width_m - r, self.n),
                                   g.uniform(0, 2 * np.pi, self.n), g.random(self.n)]) for g in self.rngs]) \
            if self.n else np.zeros((self.b, 4, 0))
        self.x, self.y, self.th = draw[:, 0].copy(), draw[:, 1].copy(), draw[:, 2].copy()
        self.carrying = draw[:, 3] < 0.5
        self.om = np.zeros(shape)
        self.v = np.zeros(shape)
        self.zc = np.asarray(s.zones_m, float)
        self.seg = np.searchsorted(self.zc, self.x)            # the segment a robot works: 0 .. Z
        self.t_w = np.zeros(shape)                             # current wait
        self.waiting = np.zeros(shape, bool)
        self.decided = np.zeros(shape, bool)                   # adaptive: chose to wait at this arrival
        self.leg_t0 = np.zeros(shape)                          # adaptive: when and where the current leg began
        self.leg_x0 = self.x.copy()
        self.leg_crossed = np.zeros(shape, bool)               # ... and whether it went on through a zone
        self.mean_wait = np.zeros(shape)
        self.mean_cross_excess = np.zeros(shape)
        self.mean_own_excess = np.zeros(shape)
        self.cache = np.zeros((self.b, len(self.zc)), int)
        self.bounce_until = np.zeros(shape)                    # end of the current bounce
        self.bounce_th = np.zeros(shape)
        self.busy_until = np.zeros(shape)                      # end of the robot's last hand-over
        self.food = np.zeros(self.b, int)
        self.picked = np.zeros(self.b, int)                    # items taken at the source
        self.handovers = np.zeros(self.b, int)
        self.contact_s = np.zeros(shape)
        self.wait_s = np.zeros(shape)
        self.t_s = 0.0
        self._eye = np.eye(self.n, dtype=bool)[None]
        self._touching = np.zeros((self.b, self.n, self.n), bool)

    # -- one tick -----------------------------------------------------------------------
    def step(self, dt_s: float = 0.1) -> None:
        """Advance every world by ``dt_s``: control, motion, walls, contacts, then the task."""
        if not (0 < dt_s <= 1.0):
            raise ValueError(f"dt_s must be in (0, 1] s, got {dt_s}")
        self.t_s += dt_s
        if self.n == 0:
            return
        s = self.scene
        theta0, v0 = self._targets()
        self.contact_s += np.where(self.bounce_until > self.t_s - dt_s, dt_s, 0.0)   # interference: time bouncing
        err = wrap(theta0 - self.th)
        # The seed writes theta' = Kp (theta0 - theta) + Kd dtheta/dt, which is implicit in
        # theta'. The PD it means acts on a heading rate: omega' = Kp e - Kd omega.
        self.om += dt_s * (s.kp_heading * err - s.kd_heading * self.om)
        self.th = wrap(self.th + dt_s * self.om)
        self.v = np.clip(self.v + dt_s * s.kp_speed * (v0 - self.v), 0.0, s.v_max_mps)
        x_before = self.x.copy()
        self.x = self.x + dt_s * self.v * np.cos(self.th)
        self.y = self.y + dt_s * self.v * np.sin(self.th)
        self._walls(x_before)
        touching = self._contacts(dt_s)
        if s.transfer == "p2p":
            self._p2p(touching)
        else:
            self._zones(dt_s)

    def run(self, duration_s: float, dt_s: float = 0.1, progress: object = None) -> None:
        """Step until ``t_s`` reaches ``duration_s`` (``progress(t_s)`` after each second if given)."""
        steps = int(round((duration_s - self.t_s) / dt_s))
        every = max(1, int(round(1.0 / dt_s)))
        for k in range(steps):
            self.step(dt_s)
            if progress is not None and (k + 1) % every == 0:
                progress(self.t_s)

    # -- control ------------------------------------------------------------------------
    def _targets(self) -> tuple[np.ndarray, np.ndarray]:
        s = self.scene
        right = self.carrying
        theta0 = np.where(right, 0.0, np.pi)
        v0 = np.where(self.busy_until > self.t_s, 0.0, s.v_max_mps)
        if len(self.zc):
            # a waiting robot drives on to the zone's centre line and parks there
            near = self.zc[np.clip(np.where(right, self.seg, self.seg - 1), 0, len(self.zc) - 1)]
            parked = self.waiting & np.where(right, self.x >= near - s.radius_m - 0.01,
                                             self.x <= near + s.radius_m + 0.01)
            v0 = np.where(parked, 0.0, v0)
            if s.gate_width_m is not None:
                # steer through the gate of the next wall ahead, when there is one within 0.6 m
                ahead = np.where(right, np.searchsorted(self.zc, self.x), np.searchsorted(self.zc, self.x) - 1)
                valid = (ahead >= 0) & (ahead < len(self.zc)) & ~self.waiting
                wall = self.zc[np.clip(ahead, 0, len(self.zc) - 1)]
                gap = np.abs(wall - self.x)
                steer = valid & (gap < 0.6)
                aim = np.arctan2(s.gate_y_m - self.y, np.where(right, 1.0, -1.0) * np.maximum(gap, 0.15))
                theta0 = np.where(steer, aim, theta0)
        bouncing = self.bounce_until > self.t_s
        return np.where(bouncing, self.bounce_th, theta0), v0

    # -- physics ------------------------------------------------------------------------
    def _walls(self, x_before: np.ndarray) -> None:
        s, r = self.scene, self.scene.radius_m
        out_x = (self.x < r) | (self.x > s.length_m - r)
        out_y = (self.y < r) | (self.y > s.width_m - r)
        self.x = np.clip(self.x, r, s.length_m - r)
        self.y = np.clip(self.y, r, s.width_m - r)
        if s.gate_width_m is not None and len(self.zc):
            opening = s.gate_width_m / 2 - r                  # < 0: nobody fits through
            blocked = np.abs(self.y - s.gate_y_m) > opening
            for wall in self.zc:
                side = np.sign(x_before - wall)
                hit = blocked & (np.abs(self.x - wall) < r) | blocked & (np.sign(self.x - wall) != side)
                hit &= side != 0
                self.x = np.where(hit, wall + side * r, self.x)
                out_x |= hit
        self.th = np.where(out_x, np.pi - self.th, self.th)
        self.th = wrap(np.where(out_y, -self.th, self.th))
        self.om = np.where(out_x | out_y, 0.0, self.om)

    def _contacts(self, dt_s: float) -> np.ndarray:
        """Separate overlapping robots, turn each away from the others; (B, N, N) who touched whom."""
        r = self.scene.radius_m
        dx = self.x[:, :, None] - self.x[:, None, :]
        dy = self.y[:, :, None] - self.y[:, None, :]
        d = np.hypot(dx, dy)
        touching = (d < 2 * r) & ~self._eye
        before, self._touching = self._touching, touching
        if not touching.any():
            return touching
        # coincident centres have no normal: a seeded random direction per robot breaks the tie
        zero = touching & (d < 1e-9)
        if zero.any():
            angle = self._draw(zero.any(axis=(1, 2))) * 2 * np.pi
            dx = np.where(zero, np.cos(angle)[:, :, None] - np.cos(angle)[:, None, :] + 1e-9, dx)
            dy = np.where(zero, np.sin(angle)[:, :, None] - np.sin(angle)[:, None, :], dy)
            d = np.maximum(np.hypot(dx, dy), 1e-12)
        push = np.where(touching, (2 * r - d) / 2 / np.maximum(d, 1e-12), 0.0)
        px, py = (push * dx).sum(axis=2), (push * dy).sum(axis=2)
        self.x = np.clip(self.x + px, r, self.scene.length_m - r)
        self.y = np.clip(self.y + py, r, self.scene.width_m - r)
        # the bounce happens once per contact, at its onset: turning away at every tick of a
        # contact made the outcome depend on the tick (a jam lasts more ticks at a smaller dt)
        onset = touching & ~before
        new = onset.any(axis=2)
        nx, ny = np.where(onset, dx, 0.0).sum(axis=2), np.where(onset, dy, 0.0).sum(axis=2)
        away = np.arctan2(ny, nx)
        self.th = np.where(new, away, self.th)                 # bounce: away from whoever it met ...
        self.om = np.where(new, 0.0, self.om)
        self.bounce_th = np.where(new, away, self.bounce_th)   # ... and keep going that way for bounce_s,
        self.bounce_until = np.where(new, self.t_s + self.scene.bounce_s, self.bounce_until)   # whatever dt
        return touching

    # -- the task -----------------------------------------------------------------------
    def _zones(self, dt_s: float) -> None:
        s = self.scene
        src = ~self.carrying & (self.seg == 0) & (self.x <= s.source_m)
        nest = self.carrying & (self.seg == len(self.zc)) & (self.x >= s.length_m - s.nest_m)
        self.food += nest.sum(axis=1)
        self.picked += src.sum(axis=1)
        self._end_leg(src | nest)
        self.carrying = (self.carrying | src) & ~nest
        if not len(self.zc):
            return
        half = s.zone_width_m / 2
        zone_ahead = np.where(self.carrying, self.seg, self.seg - 1)      # zone at the end of the leg
        inside = (zone_ahead >= 0) & (zone_ahead < len(self.zc))
        centre = self.zc[np.clip(zone_ahead, 0, len(self.zc) - 1)]
        arrived = inside & np.where(self.carrying, self.x >= centre - half, self.x <= centre + half)
        new = arrived & ~self.waiting
        if new.any():
            self._end_leg(new)
            wait = np.ones_like(new)
            if s.policy == "adaptive":
                benefit = 2 * (self.mean_cross_excess - self.mean_own_excess)
                scale = np.maximum(np.maximum(np.abs(benefit), self.mean_wait), 1.0)
                p = 1.0 / (1.0 + np.exp(-s.adaptive_beta * (benefit - self.mean_wait) / scale))
                wait = self._draw(new.any(axis=1)) < p
            self.waiting |= new & wait
            self._stop_waiting(new & ~wait, give_up=True)
        if s.transfer == "direct":
            self._hand_over(zone_ahead)
        else:
            self._use_cache(zone_ahead)
        self.t_w = np.where(self.waiting, self.t_w + dt_s, 0.0)
        self.wait_s += np.where(self.waiting, dt_s, 0.0)
        self._stop_waiting(self.waiting & (self.t_w > s.theta_s), give_up=True)

    def _hand_over(self, zone: np.ndarray) -> None:
        """Mutually nearest carrier/receiver pairs waiting at the same zone swap the food."""
        giver = self.waiting & self.carrying
        taker = self.waiting & ~self.carrying
        pair = giver[:, :, None] & taker[:, None, :] & (zone[:, :, None] == zone[:, None, :])
        if not pair.any():
            return
        self._stop_waiting(self._swap(pair), give_up=False)

    def _use_cache(self, zone: np.ndarray) -> None:
        cap = self.scene.cache_capacity
        for z in range(len(self.zc)):
            drop = self.waiting & self.carrying & (zone == z)
            rank = np.cumsum(drop, axis=1) - 1
            drop &= rank < (cap - self.cache[:, z])[:, None]
            self.cache[:, z] += drop.sum(axis=1)
            pick = self.waiting & ~self.carrying & (zone == z)
            rank = np.cumsum(pick, axis=1) - 1
            pick &= rank < self.cache[:, z][:, None]
            self.cache[:, z] -= pick.sum(axis=1)
            self.handovers += pick.sum(axis=1)
            self._stop_waiting(drop | pick, give_up=False)
            self.carrying = (self.carrying & ~drop) | pick

    def _stop_waiting(self, who: np.ndarray, *, give_up: bool) -> None:
        """``who`` leave the zone: served (hand-over, cache) or, with ``give_up``, reassigned to the
        neighbouring segment, carrying on (the FSM's t_w > Theta edge, or the adaptive choice not to wait)."""
        a = self.scene.adaptive_memory
        waited = self.waiting & who
        self.mean_wait = np.where(waited, (1 - a) * self.mean_wait + a * self.t_w, self.mean_wait)
        if give_up:
            self.seg = np.where(who, np.where(self.carrying, self.seg + 1, self.seg - 1), self.seg)
        self.waiting &= ~who
        self.t_w = np.where(who, 0.0, self.t_w)
        self._start_leg(who, crossed=give_up)

    def _start_leg(self, who: np.ndarray, *, crossed: bool) -> None:
        self.leg_t0 = np.where(who, self.t_s, self.leg_t0)
        self.leg_x0 = np.where(who, self.x, self.leg_x0)
        self.leg_crossed = np.where(who, crossed, self.leg_crossed)

    def _end_leg(self, who: np.ndarray) -> None:
        """A leg ended: its delay over free flow feeds the adaptive estimates (crossing a zone or not)."""
        a = self.scene.adaptive_memory
        excess = (self.t_s - self.leg_t0) - np.abs(self.x - self.leg_x0) / self.scene.v_max_mps
        cross, own = who & self.leg_crossed, who & ~self.leg_crossed
        self.mean_cross_excess = np.where(cross, (1 - a) * self.mean_cross_excess + a * excess, self.mean_cross_excess)
        self.mean_own_excess = np.where(own, (1 - a) * self.mean_own_excess + a * excess, self.mean_own_excess)
        self._start_leg(who, crossed=False)

    def _p2p(self, touching: np.ndarray) -> None:
        s = self.scene
        src = ~self.carrying & (self.x <= s.source_m)
        nest = self.carrying & (self.x >= s.length_m - s.nest_m)
        self.food += nest.sum(axis=1)
        self.picked += src.sum(axis=1)
        self.carrying = (self.carrying | src) & ~nest
        # a carrier passes its food to a robot without food that it touches ahead of it
        ahead = self.x[:, None, :] > self.x[:, :, None]
        free = self.busy_until <= self.t_s                     # a hand-over takes time: food moves no faster than robots
        pair = touching & (self.carrying & free)[:, :, None] & (~self.carrying & free)[:, None, :] & ahead
        if not pair.any():
            return
        self._swap(pair)

    def _swap(self, pair: np.ndarray) -> np.ndarray:
        """Mutually nearest (giver, taker) pairs of ``pair`` (B, N, N) hand the food over and stand
        still ``handover_s``; returns who took part."""
        d = np.where(pair, np.hypot(self.x[:, :, None] - self.x[:, None, :], self.y[:, :, None] - self.y[:, None, :]),
                     np.inf)
        gave, took = mutual_nearest(d)
        self.handovers += gave.sum(axis=1)
        self.carrying = (self.carrying & ~gave) | took
        self.busy_until = np.where(gave | took, self.t_s + self.scene.handover_s, self.busy_until)
        return gave | took

    def _draw(self, worlds: np.ndarray) -> np.ndarray:
        """(B, N) uniform numbers; a world's generator is used only when that world needs one,
        so a world's path does not depend on which other worlds share the batch."""
        return np.stack([g.random(self.n) if need else np.zeros(self.n) for g, need in zip(self.rngs, worlds)])

    # -- summaries ----------------------------------------------------------------------
    def efficiency(self) -> np.ndarray:
        """(B,) individual efficiency F / N (0 for N = 0)."""
        return self.food / max(self.n, 1)
