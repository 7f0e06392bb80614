"""Scanning-sonar imager: one-beam pings (Ping360) -> the disc image, published every sector."""
from __future__ import annotations

from pathlib import Path

import cv2
import msgspec
import numpy as np

from msgs.sensor import Grid
from msgs.sonar import SonarPing
from nodes.sonar.scan import ScanImage
from tether import Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    n_angles: int = 400
    n_samples: int = 600              # the image's samples per beam (beams are resampled to it)
    size_px: int = 512
    sector_beams: int = 50            # publish an update every this many beams
    png: str = ""                     # write the image here at every completed turn (and at the end)

    def __post_init__(self) -> None:
        if self.sector_beams < 1 or self.size_px < 16:
            raise ValueError("sector_beams must be >= 1 and size_px >= 16")


class ScanImager(Node):
    """Input ``ping`` (one beam each); output ``image`` (sensor.Grid, metres per pixel, sonar at the centre)."""

    Config = Config
    inputs = {"ping": SonarPing}
    outputs = {"image": Grid}

    def setup(self) -> None:
        self.scan = ScanImage(self.config.n_angles, self.config.n_samples)
        self.bad = 0
        self.written = 0

    def on_ping(self, ping: SonarPing) -> dict[str, Grid] | None:
        data = np.asarray(ping.intensities)
        if data.ndim != 2 or data.shape[1] != 1 or len(ping.bearings_rad) != 1:
            self.bad += 1
            if self.bad in (1, 10, 100, 1000):
                self.log.warning("ping of shape %s is not one beam; skipped (%d so far)", data.shape, self.bad)
            return None
        try:
            turned = self.scan.add(float(ping.bearings_rad[0]), data[:, 0], float(ping.range_m))
        except ValueError as exc:
            self.bad += 1
            self.log.warning("beam skipped: %s", exc)
            return None
        if turned and self.config.png:
            self.write_png()
        if self.scan.beams % self.config.sector_beams:
            return None
        return {"image": self.grid(ping.stamp_ns, ping.frame_id)}

    def grid(self, stamp_ns: int, frame_id: str) -> Grid:
        img = self.scan.cartesian(self.config.size_px)
        res = 2 * self.scan.range_m / self.config.size_px
        half = self.config.size_px / 2
        return Grid(stamp_ns=stamp_ns, frame_id=frame_id, data=img, resolution_m=res,
                    origin_x_m=-(half - 0.5) * res, origin_y_m=-(half - 0.5) * res)

    def write_png(self) -> None:
        img = self.scan.cartesian(self.config.size_px)
        finite = np.isfinite(img)
        top = float(np.percentile(img[finite], 99.5)) if finite.any() else 1.0
        out = np.zeros(img.shape + (3,), np.uint8)
        grey = np.clip(np.nan_to_num(img) / max(top, 1e-6) * 255, 0, 255).astype(np.uint8)
        out[finite] = cv2.applyColorMap(grey, cv2.COLORMAP_INFERNO)[finite]
        c = self.config.size_px // 2
        cv2.line(out, (c, c), (c, 0), (0, 255, 0), 1)                       # ahead
        cv2.putText(out, f"{self.scan.range_m:.0f} m, turn {self.scan.turns}, {self.scan.coverage:.0%} of angles",
                    (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1)
        path = Path(self.config.png)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.stem + ".tmp.png")
        cv2.imwrite(str(tmp), out)
        tmp.replace(path)
        self.written += 1

    def teardown(self) -> None:
        if self.config.png and self.scan.beams:
            self.write_png()
