"""Polar imager node: raw sonar ping -> Cartesian fan image (seed 01, eq. 1-6).

The ping's per-row gains (when the sonar sends them) are divided out first, in the sample's own
encoding (``nodes.sonar.gain``: ``sample / g ** gamma``, 8 or 16 bit kept), so the fan shows every
range at the same gain. A ping whose gains are all zero, negative or NaN (or not one per row)
is rendered unscaled and counted in ``gain_problems``; a few bad rows take their neighbours' gain.
"""
from __future__ import annotations

import math
from typing import Literal

import msgspec
import numpy as np

from msgs.sonar import FanImage, SonarPing
from nodes.sonar.gain import compensate_row_gains
from nodes.sonar.polar import FanRenderer
from tether import Input, Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    width_px: int = 1024
    height_px: int = 0                              # 0: from the fan's aspect ratio
    interpolation: Literal["nearest", "bilinear"] = "bilinear"
    backend: Literal["numpy", "cv2"] = "cv2"        # cv2.remap on the cached maps is the fastest bilinear
    row_gains: Literal["apply", "ignore"] = "apply"  # divide out the sonar's per-row gains

    def __post_init__(self) -> None:
        if self.width_px < 2 or self.width_px > 8192 or self.height_px < 0 or self.height_px > 8192:
            raise ValueError("width_px must be in [2, 8192] and height_px 0 (auto) or in [2, 8192]")


class PolarImager(Node):
    """Input ``ping`` (latest only); output ``image``: the fan in the sonar frame, m/px in the message.

    The lookup table is rebuilt only when the ping geometry (ranges, resolution, bearing table)
    changes. A malformed ping is logged once per kind, counted in ``dropped`` and skipped.
    """

    Config = Config
    inputs = {"ping": Input(SonarPing, latest=True)}
    outputs = {"image": FanImage}

    def setup(self) -> None:
        cfg = self.config
        self._renderer = FanRenderer(width_px=cfg.width_px, height_px=cfg.height_px,
                                     interpolation=cfg.interpolation, backend=cfg.backend)
        self.rendered = 0
        self.dropped = 0
        self.gain_problems = {"invalid": 0, "mismatch": 0, "repaired": 0}
        self._warned: set[str] = set()
        self._mask: np.ndarray | None = None

    def on_ping(self, ping: SonarPing) -> dict[str, FanImage] | None:
        resolution = ping.range_resolution_m
        if not resolution > 0 and ping.range_m > 0 and ping.intensities.shape[0] > 0:
            resolution = ping.range_m / ping.intensities.shape[0]
        intensities = np.asarray(ping.intensities)
        if self.config.row_gains == "apply":
            gained = compensate_row_gains(intensities, np.asarray(ping.row_gains), ping.gamma)
            if gained.status in self.gain_problems:
                self.gain_problems[gained.status] += 1
                self._warn_once(gained.status, "ping %d: row gains %s (%d bad rows)%s", ping.ping_id, gained.status,
                                gained.bad_rows, "; rendered unscaled" if gained.status != "repaired" else "")
            intensities = gained.image
        try:
            image, lut = self._renderer.render(intensities, np.asarray(ping.bearings_rad), resolution,
                                               alloc=self._loan_image_and_mask)
        except ValueError as exc:
            self.dropped += 1
            self._warn_once(str(exc).split(",")[0], "dropping ping %d: %s", ping.ping_id, exc)
            return None
        self.rendered += 1
        mask, self._mask = self._mask, None
        mask[...] = lut.mask
        return {"image": FanImage(stamp_ns=ping.stamp_ns, frame_id=ping.frame_id, image=image, mask=mask,
                                  m_per_px=lut.m_per_px, origin_row_px=lut.origin_row_px,
                                  origin_col_px=lut.origin_col_px, ping_id=ping.ping_id)}

    def _loan_image_and_mask(self, shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
        """The fan image's array, with room for the mask behind it: one loan, so in a live graph both
        cross to the subscribers without a copy (a message's large buffers must share one slot)."""
        nbytes = math.prod(shape) * np.dtype(dtype).itemsize
        block = self.loan("image", (nbytes + math.prod(shape),), np.uint8)
        self._mask = block[nbytes:].reshape(shape)
        return block[:nbytes].view(dtype).reshape(shape)

    def teardown(self) -> None:
        self.log.info("polar imager: %d pings rendered, %d dropped, %d lookup-table builds, row-gain problems %s",
                      self.rendered, self.dropped, self._renderer.builds, self.gain_problems)

    def _warn_once(self, kind: str, fmt: str, *args: object) -> None:
        if kind not in self._warned:
            self._warned.add(kind)
            self.log.error(fmt, *args)
