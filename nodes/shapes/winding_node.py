"""Winding node: a segmentation (mask or edge map) -> its winding-number grid and inside mask."""
from __future__ import annotations

import msgspec
import numpy as np

from msgs.sensor import Grid, Image
from nodes.shapes.inside_outside import SOURCES, inside_mask, winding_image
from tether import Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    source: str = "mask"              # mask: regions; edges: thin curves (open gaps tolerated)
    merge_px: float = 3.0             # edge ends closer than this are joined
    threshold: float = 0.5            # inside where w >= threshold
    resolution_m: float = 1.0         # metres per pixel of the output grid (1: pixel units)

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise ValueError(f"source must be one of {SOURCES}, got {self.source!r}")
        if self.merge_px < 0 or self.resolution_m <= 0:
            raise ValueError("merge_px must be >= 0 and resolution_m positive")


class WindingNode(Node):
    """Input ``image`` (mono8; non-zero = region or edge); outputs ``winding`` (Grid) and ``inside`` (Image mono8)."""

    Config = Config
    inputs = {"image": Image}
    outputs = {"winding": Grid, "inside": Image}

    def on_image(self, msg: Image) -> list[tuple[str, object]] | None:
        data = np.asarray(msg.data)
        if data.ndim == 3:
            data = data.max(axis=2)
        if data.ndim != 2 or data.size == 0:
            self.log.warning("image of shape %s is not a 2-D segmentation; skipped", data.shape)
            return None
        c = self.config
        w, curves = winding_image(data, source=c.source, merge_px=c.merge_px)
        if curves == 0:
            self.log.debug("no contour in the image: winding 0 everywhere")
        inside = (inside_mask(w, c.threshold) * 255).astype(np.uint8)
        return [("winding", Grid(stamp_ns=msg.stamp_ns, frame_id=msg.frame_id, data=w, resolution_m=c.resolution_m)),
                ("inside", Image(stamp_ns=msg.stamp_ns, frame_id=msg.frame_id, data=inside, encoding="mono8"))]
