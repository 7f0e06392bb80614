"""UAV simulator node (seed 11): the kinematic multirotor of :mod:`sim.aerial` over a map,
stepped on a timer with the latest command; its nadir camera, a drifting inertial estimate and
the truth. A command older than ``command_timeout_s`` is dropped: the UAV hovers, it never
keeps flying on a stale command.

Outputs each tick: ``truth`` and ``ins`` (uav.UavState; the INS drifts as a random walk and
carries a barometric altitude); every ``image_every`` ticks ``image`` (sensor.Image, bgr8).
"""
from __future__ import annotations

import math
from typing import Any

import msgspec
import numpy as np

from msgs.sensor import Image
from msgs.uav import UavCommand, UavState as UavStateMsg
from nodes.vision.geomap import MAPS, load_map
from sim.aerial import Camera, Command, Limits, Look, Uav, UavState, render_nadir
from tether import Input, Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    map: str = "procedural"          # or "brighton" (the real ortho, georeferenced by its frames' GPS)
    map_seed: int = 0
    start_e_m: float = 0.0
    start_n_m: float = 0.0
    start_yaw_rad: float = 0.0
    start_alt_m: float = 40.0
    rate_hz: float = 10.0
    image_every: int = 2             # camera at rate_hz / image_every
    command_timeout_s: float = 0.5
    ins_drift_m_per_sqrt_s: float = 0.5
    baro_noise_m: float = 0.5
    width_px: int = 640
    height_px: int = 480
    hfov_deg: float = 80.0
    gain: float = 1.0
    blur_px: float = 0.6
    noise_grey: float = 2.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.map not in MAPS:
            raise ValueError(f"map must be one of {MAPS}, got {self.map!r}")
        if self.rate_hz <= 0 or self.image_every < 1 or self.start_alt_m <= 0:
            raise ValueError("rate_hz, image_every and start_alt_m must be positive")


class UavSim(Node):
    """Input ``command`` (latest); timer ``tick``; outputs ``image``, ``ins``, ``truth``."""

    Config = Config
    inputs = {"command": Input(UavCommand, depth=1, latest=True)}
    outputs = {"image": Image, "ins": UavStateMsg, "truth": UavStateMsg}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        c = self.config
        self.map = load_map(c.map, c.map_seed)
        self.cam = Camera(c.width_px, c.height_px, c.hfov_deg)
        self.uav = Uav(UavState(c.start_e_m, c.start_n_m, c.start_yaw_rad, c.start_alt_m), Limits())
        self.look = Look(blur_px=c.blur_px, gain=c.gain, noise_grey=c.noise_grey)
        self.rng = np.random.default_rng(c.seed)
        self.drift = np.zeros(2)
        self.cmd: UavCommand | None = None
        self.cmd_ns = 0
        self.ticks = 0
        self.stale = 0

    def on_command(self, msg: UavCommand) -> None:
        self.cmd, self.cmd_ns = msg, self.now_ns()

    def on_tick(self, tick: Any) -> list[tuple[str, Any]]:
        c = self.config
        dt = 1.0 / c.rate_hz
        now = self.now_ns()
        fresh = self.cmd is not None and now - self.cmd_ns <= c.command_timeout_s * 1e9
        if self.cmd is not None and not fresh:
            self.stale += 1
            if self.stale == 1:
                self.log.warning("uav sim: no command for %.1f s: hovering", c.command_timeout_s)
        cmd = Command(self.cmd.forward_mps, self.cmd.right_mps, self.cmd.yaw_rate_radps, self.cmd.climb_mps) \
            if fresh else Command()
        s = self.uav.step(cmd, dt)
        self.drift += self.rng.normal(0, c.ins_drift_m_per_sqrt_s * math.sqrt(dt), 2)
        out: list[tuple[str, Any]] = [
            ("truth", UavStateMsg(stamp_ns=now, frame_id="world", e_m=s.e, n_m=s.n, alt_m=s.alt, yaw_rad=s.yaw)),
            ("ins", UavStateMsg(stamp_ns=now, frame_id="world", e_m=s.e + self.drift[0], n_m=s.n + self.drift[1],
                                alt_m=s.alt + float(self.rng.normal(0, c.baro_noise_m)), yaw_rad=s.yaw, source="ins"))]
        if self.ticks % c.image_every == 0:
            img = render_nadir(self.map, s, self.cam, look=self.look, rng=self.rng)
            out.append(("image", Image(stamp_ns=now, frame_id="camera", data=img, encoding="bgr8")))
        self.ticks += 1
        return out
