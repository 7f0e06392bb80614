"""SlimeVolley for G games at once: a numpy replica of ``slimevolleygym`` 0.1.0's game physics.

Every branch of the original ``Game.step`` (agents' update, the ball held for 30 frames after
a serve, the speed limit, the bounce loop off each slime and the fence stub, edges, fence,
scoring, lives) is an ``np.where`` over the games, with the same floating-point operations
in the same order, so a game stepped here with the same serve velocities and actions follows
the original bit for bit (``tests/nodes/learn/test_slime_game.py``). Two details of the
original kept on purpose: the observation is not refreshed on the step a point is scored
(``Game.step`` returns early), and a new serve keeps both slimes where they are.

Row 0 of every agent array is the left slime (``dir = -1``), row 1 the right one (``dir = +1``).
Serve velocities come from the caller, so the caller decides whose random stream draws them.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

# the original's constants, computed by the same expressions
REF_W = 24 * 2
REF_H = REF_W
REF_U = 1.5
REF_WALL_WIDTH = 1.0
REF_WALL_HEIGHT = 3.5
PLAYER_SPEED_X = 10 * 1.75
PLAYER_SPEED_Y = 10 * 1.35
MAX_BALL_SPEED = 15 * 1.5
TIMESTEP = 1 / 30.
NUDGE = 0.1
INIT_DELAY_FRAMES = 30
GRAVITY = -9.8 * 2 * 1.5
MAXLIVES = 5
T_LIMIT = 3000
AGENT_R = 1.5
BALL_R = 0.5
STUB_R = REF_WALL_WIDTH / 2
STUB_Y = REF_WALL_HEIGHT
SERVE_VX = (-20.0, 20.0)    # uniform(low, high) of the serve, as Game.newMatch draws it
SERVE_VY = (10.0, 25.0)

_G_DT = GRAVITY * TIMESTEP
_NUDGE_DT = NUDGE * TIMESTEP
_DIR = np.array([[-1.0], [1.0]])
_NET_IN = REF_WALL_WIDTH / 2 + AGENT_R     # a slime stays in its half
_NET_OUT = REF_W / 2 - AGENT_R
_MAX2 = MAX_BALL_SPEED * MAX_BALL_SPEED

#: BaselinePolicy's weights (7 x 15) and biases (7,), copied from slimevolleygym (120 parameters)
BASELINE_W = np.array([
    7.5719, 4.4285, 2.2716, -0.3598, -7.8189, -2.5422, -3.2034, 0.3935, 1.2202, -0.49, -0.0316, 0.5221, 0.7026,
    0.4179, -2.1689, 1.646, -13.3639, 1.5151, 1.1175, -5.3561, 5.0442, 0.8451, 0.3987, -2.9501, -3.7811, -5.8994,
    6.4167, 2.5014, 7.338, -2.9887, 2.4586, 13.4191, 2.7395, -3.9708, 1.6548, -2.7554, -1.5345, -6.4708, 9.2426,
    -0.7392, 0.4452, 1.8828, -2.6277, -10.851, -3.2353, -4.4653, -3.1153, -1.3707, 7.318, 16.0902, 1.4686, 7.0391,
    1.7765, -1.155, 2.6697, -8.8877, 1.1958, -3.2839, -5.4425, 1.6809, 7.6812, -2.4732, 1.738, 0.3781, 0.8718,
    2.5886, 1.6911, 1.2953, -9.0052, -4.6038, -6.7447, -2.5528, 0.4391, -4.9278, -3.6695, -4.8673, -1.6035,
    1.5011, -5.6124, 4.9747, 1.8998, 3.0359, 6.2983, -4.8568, -2.1888, -4.1143, -3.9874, -0.0459, 4.7134, 2.8952,
    -9.3627, -4.685, 0.3601, -1.3699, 9.7294, 11.5596, 0.1918, 3.0783, 0.0329, -0.1362, -0.1188, -0.7579, 0.3278,
    -0.977, -0.9377]).reshape(7, 15)
BASELINE_B = np.array([2.2935, -2.0353, -1.7786, 5.4567, -3.6368, 3.4996, -0.0685])


@dataclass
class Games:
    """State of G games; every field's last axis is the game."""

    bx: np.ndarray       # (G,) ball position (m) and velocity (m/s); prev: position before its last move
    by: np.ndarray
    bvx: np.ndarray
    bvy: np.ndarray
    bpx: np.ndarray
    bpy: np.ndarray
    delay: np.ndarray    # (G,) int: frames the served ball is still held
    x: np.ndarray        # (2, G) slimes (left, right)
    y: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    life: np.ndarray     # (2, G) int
    rel: np.ndarray      # (2, 12, G) each slime's last RelativeState (unscaled)

    @property
    def g(self) -> int:
        return self.bx.shape[0]

    def take(self, idx: np.ndarray) -> Games:
        """The games ``idx`` (copies), in that order."""
        return Games(**{f.name: getattr(self, f.name)[..., idx].copy() for f in fields(self)})


def new_games(serve_vx: np.ndarray, serve_vy: np.ndarray) -> Games:
    """Games as ``Game.reset`` leaves them, serving at ``(serve_vx, serve_vy)`` (G,) m/s."""
    n = len(serve_vx)
    z = np.zeros(n)
    games = Games(bx=z.copy(), by=z.copy(), bvx=z.copy(), bvy=z.copy(), bpx=z.copy(), bpy=z.copy(),
                  delay=np.zeros(n, np.int64), x=np.zeros((2, n)), y=np.zeros((2, n)), vx=np.zeros((2, n)),
                  vy=np.zeros((2, n)), life=np.zeros((2, n), np.int64), rel=np.zeros((2, 12, n)))
    reset_games(games, np.ones(n, bool), serve_vx, serve_vy)
    return games


def reset_games(games: Games, mask: np.ndarray, serve_vx: np.ndarray, serve_vy: np.ndarray) -> None:
    """New episodes where ``mask`` (G,): slimes home with 5 lives, a new serve; ``serve_*`` (mask.sum(),)."""
    games.x[:, mask] = _DIR * (REF_W / 4)
    games.y[:, mask] = AGENT_R
    games.vx[:, mask] = 0.0
    games.vy[:, mask] = 0.0
    games.life[:, mask] = MAXLIVES
    serve(games, mask, serve_vx, serve_vy)
    _update_rel(games, mask)


def serve(games: Games, mask: np.ndarray, serve_vx: np.ndarray, serve_vy: np.ndarray) -> None:
    """A new ball where ``mask`` (``Game.newMatch``): held at (0, REF_W/4) for 30 frames."""
    games.bx[mask] = 0.0
    games.by[mask] = REF_W / 4
    games.bpx[mask] = 0.0
    games.bpy[mask] = REF_W / 4
    games.bvx[mask] = serve_vx
    games.bvy[mask] = serve_vy
    games.delay[mask] = INIT_DELAY_FRAMES


def observe(games: Games) -> tuple[np.ndarray, np.ndarray]:
    """Observations (right, left), each (G, 12) float64, as ``Agent.getObservation`` scales them."""
    return games.rel[1].T / 10.0, games.rel[0].T / 10.0


def _update_rel(games: Games, mask: np.ndarray) -> None:
    d = _DIR
    rel = np.stack([games.x * d, games.y, games.vx * d, games.vy,
                    games.bx * d, np.broadcast_to(games.by, games.y.shape), games.bvx * d,
                    np.broadcast_to(games.bvy, games.y.shape),
                    games.x[::-1] * -d, games.y[::-1], games.vx[::-1] * -d, games.vy[::-1]], axis=1)
    if mask.all():
        games.rel = rel
    else:
        games.rel[..., mask] = rel[..., mask]


def _move_agents(games: Games, act_left: np.ndarray, act_right: np.ndarray) -> None:
    press = np.stack([np.asarray(act_left), np.asarray(act_right)]) > 0      # (2, G, 3)
    fwd, back, jump = press[..., 0], press[..., 1], press[..., 2]
    want_vx = np.where(fwd & ~back, -PLAYER_SPEED_X, np.where(back & ~fwd, PLAYER_SPEED_X, 0.0))
    want_vy = np.where(jump, PLAYER_SPEED_Y, 0.0)
    vy = games.vy + _G_DT
    vy = np.where(games.y <= REF_U + _NUDGE_DT, want_vy, vy)
    vx = want_vx * _DIR
    x = games.x + vx * TIMESTEP
    y = games.y + vy * TIMESTEP
    low = y <= REF_U
    y = np.where(low, REF_U, y)
    vy = np.where(low, 0.0, vy)
    inner = x * _DIR <= _NET_IN
    vx = np.where(inner, 0.0, vx)
    x = np.where(inner, _DIR * _NET_IN, x)
    outer = x * _DIR >= _NET_OUT
    games.vx = np.where(outer, 0.0, vx)
    games.x = np.where(outer, _DIR * _NET_OUT, x)
    games.y, games.vy = y, vy


def _move_ball(games: Games) -> None:
    free = games.delay == 0
    games.delay = np.where(free, games.delay, games.delay - 1)
    if not free.any():
        return
    vx = games.bvx + 0.0
    vy = games.bvy + _G_DT
    mag2 = vx * vx + vy * vy
    fast = mag2 > _MAX2
    if fast.any():
        mag = np.sqrt(mag2)
        vx = np.where(fast, vx / mag * MAX_BALL_SPEED, vx)
        vy = np.where(fast, vy / mag * MAX_BALL_SPEED, vy)
    games.bvx = np.where(free, vx, games.bvx)
    games.bvy = np.where(free, vy, games.bvy)
    games.bpx = np.where(free, games.bx, games.bpx)
    games.bpy = np.where(free, games.by, games.bpy)
    games.bx = np.where(free, games.bx + games.bvx * TIMESTEP, games.bx)
    games.by = np.where(free, games.by + games.bvy * TIMESTEP, games.by)


def _collide(games: Games, px: np.ndarray | float, py: np.ndarray | float, pvx: np.ndarray | float,
             pvy: np.ndarray | float, r: float) -> None:
    """``Particle.bounce`` where the ball overlaps a circle of radius ``r - BALL_R`` at (px, py)."""
    r2 = r * r
    dx, dy = px - games.bx, py - games.by
    hit = np.flatnonzero(r2 > dx * dx + dy * dy)
    if hit.size == 0:
        return
    px, py, pvx, pvy = (np.broadcast_to(p, games.bx.shape)[hit] for p in (px, py, pvx, pvy))
    bx, by, bvx, bvy = games.bx[hit], games.by[hit], games.bvx[hit], games.bvy[hit]
    nx, ny = bx - px, by - py
    abd = np.sqrt(nx * nx + ny * ny)
    nx, ny = nx / abd, ny / abd
    stepx, stepy = nx * NUDGE, ny * NUDGE
    inside = np.ones(hit.size, bool)
    while inside.any():     # the original nudges the ball out in NUDGE steps, one game at a time
        bx = np.where(inside, bx + stepx, bx)
        by = np.where(inside, by + stepy, by)
        dx, dy = px - bx, py - by
        inside = r2 > dx * dx + dy * dy
    ux, uy = bvx - pvx, bvy - pvy
    un = ux * nx + uy * ny
    ux = ux - nx * (un * 2.)
    uy = uy - ny * (un * 2.)
    games.bx[hit], games.by[hit] = bx, by
    games.bvx[hit], games.bvy[hit] = ux + pvx, uy + pvy


def _check_edges(games: Games) -> np.ndarray:
    """``Particle.checkEdges``: -1 ball down on the left half, +1 on the right, 0 in play."""
    bx, by, bvx, bvy = games.bx, games.by, games.bvx, games.bvy
    c = bx <= (BALL_R - REF_W / 2)
    bvx = np.where(c, -bvx, bvx)
    bx = np.where(c, BALL_R - REF_W / 2 + _NUDGE_DT, bx)
    c = bx >= (REF_W / 2 - BALL_R)
    bvx = np.where(c, -bvx, bvx)
    bx = np.where(c, REF_W / 2 - BALL_R - _NUDGE_DT, bx)
    down = by <= (BALL_R + REF_U)
    bvy = np.where(down, -bvy, bvy)
    by = np.where(down, BALL_R + REF_U + _NUDGE_DT, by)
    up = ~down & (by >= (REF_H - BALL_R))       # the original returns on a ground hit: later checks skipped
    bvy = np.where(up, -bvy, bvy)
    by = np.where(up, REF_H - BALL_R - _NUDGE_DT, by)
    low = ~down & (by <= REF_WALL_HEIGHT)
    c = low & (bx <= (REF_WALL_WIDTH / 2 + BALL_R)) & (games.bpx > (REF_WALL_WIDTH / 2 + BALL_R))
    bvx = np.where(c, -bvx, bvx)
    bx = np.where(c, REF_WALL_WIDTH / 2 + BALL_R + _NUDGE_DT, bx)
    c = low & (bx >= (-REF_WALL_WIDTH / 2 - BALL_R)) & (games.bpx < (-REF_WALL_WIDTH / 2 - BALL_R))
    bvx = np.where(c, -bvx, bvx)
    bx = np.where(c, -REF_WALL_WIDTH / 2 - BALL_R - _NUDGE_DT, bx)
    games.bx, games.by, games.bvx, games.bvy = bx, by, bvx, bvy
    return np.where(down, np.where(bx <= 0, -1, 1), 0)


def step_games(games: Games, act_left: np.ndarray, act_right: np.ndarray) -> np.ndarray:
    """One ``Game.step`` of every game; returns the reward (G,) int of the right slime.

    Parameters
    ----------
    games : Games
        Advanced in place.
    act_left, act_right : ndarray, shape (G, 3)
        (forward, backward, jump) per slime, pressed where > 0.

    Returns
    -------
    ndarray, shape (G,)
        +1 where the right slime won the point, -1 where it lost, else 0. The scoring games
        still need a new ball: call :func:`serve` on them with fresh serve velocities.
    """
    _move_agents(games, act_left, act_right)
    _move_ball(games)
    _collide(games, games.x[0], games.y[0], games.vx[0], games.vy[0], BALL_R + AGENT_R)
    _collide(games, games.x[1], games.y[1], games.vx[1], games.vy[1], BALL_R + AGENT_R)
    _collide(games, 0.0, STUB_Y, 0.0, 0.0, BALL_R + STUB_R)
    reward = -_check_edges(games)
    scored = reward != 0
    games.life[0] -= reward > 0
    games.life[1] -= reward < 0
    _update_rel(games, ~scored)
    return reward


class BaselineBatch:
    """slimevolleygym's ``BaselinePolicy`` (a 120-parameter recurrent net) for n games at once.

    ``policy(obs)`` maps (n, 12) observations to (n, 3) int8 buttons and advances each game's
    recurrent state; ``reset(mask)`` clears it (the original clears it only in ``reset()``).
    """

    def __init__(self, n: int) -> None:
        self.out = np.zeros((n, 7))

    def reset(self, mask: np.ndarray | None = None) -> None:
        if mask is None:
            self.out[:] = 0.0
        else:
            self.out[mask] = 0.0

    def __call__(self, obs: np.ndarray, idx: np.ndarray | None = None) -> np.ndarray:
        """Buttons for games ``idx`` (default: all n) from their observations (len(idx), 12)."""
        obs = np.asarray(obs, np.float64)
        prev = self.out if idx is None else self.out[idx]
        if obs.shape[0] != prev.shape[0]:
            raise ValueError(f"{prev.shape[0]} games' recurrent states for {obs.shape[0]} observations")
        out = np.tanh(np.concatenate([obs[:, :8], prev], axis=1) @ BASELINE_W.T + BASELINE_B)
        if idx is None:
            self.out = out
        else:
            self.out[idx] = out
        return (out[:, :3] > 0.75).astype(np.int8)
