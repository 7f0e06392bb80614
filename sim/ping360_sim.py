"""Ping360 simulator node: a :class:`sim.ping360_device.Ping360Device` behind a pseudo-terminal,
its head fixed in an FLS scene; the driver opens ``link`` (a symlink to the pty) as its port.

Output ``pose`` (geometry.Pose3D, the head at angle 0, once a second). The device runs in its
own thread and answers whatever the driver sends; the node only owns its life.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import msgspec
import numpy as np

from msgs.geometry import Pose3D
from sim.fls_scene import load_scene, sonar_frame
from sim.ping360_device import BeamRenderer, Ping360Device
from tether import Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    scene: str = "tripod"
    x_m: float = 0.0
    y_m: float = -12.0
    depth_m: float = 3.0
    yaw_deg: float = 90.0             # angle 0 of the head, CCW from east
    tilt_deg: float = 5.0
    link: str = "out/ping360.pty"     # the driver's port
    baudrate: int = 115200            # the line's pace
    garbage_rate: float = 0.0
    corrupt_rate: float = 0.0
    seed: int = 0
    rate_hz: float = 1.0

    def __post_init__(self) -> None:
        if self.baudrate <= 0 or not 0 <= self.garbage_rate <= 1 or not 0 <= self.corrupt_rate <= 1:
            raise ValueError("baudrate must be positive, garbage_rate and corrupt_rate in [0, 1]")


class Ping360Sim(Node):
    """Timer ``tick``; output ``pose``."""

    Config = Config
    outputs = {"pose": Pose3D}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        c = self.config
        self.pose = sonar_frame(np.array([c.x_m, c.y_m, -c.depth_m]), math.radians(c.yaw_deg), math.radians(c.tilt_deg))
        renderer = BeamRenderer(load_scene(c.scene), self.pose, seed=c.seed)
        self.device = Ping360Device(renderer, baudrate=c.baudrate, garbage_rate=c.garbage_rate,
                                    corrupt_rate=c.corrupt_rate, seed=c.seed).start()
        link = Path(c.link)
        link.parent.mkdir(parents=True, exist_ok=True)
        if link.is_symlink() or link.exists():
            link.unlink()
        os.symlink(self.device.port, link)
        self.log.info("Ping360 simulator on %s (-> %s), %d baud", link, self.device.port, c.baudrate)

    def on_tick(self, tick: Any) -> dict[str, Pose3D]:
        return {"pose": Pose3D.from_matrix(self.pose, stamp_ns=self.now_ns(), frame_id="world")}

    def teardown(self) -> None:
        self.device.close()
        link = Path(self.config.link)
        if link.is_symlink():
            link.unlink()
        self.log.info("Ping360 simulator: %d beams sent, %d requests", self.device.beams_sent, self.device.requests)
