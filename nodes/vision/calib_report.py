"""Calibration report node: each intrinsics estimate against the truth, logged; the last one
written to a JSON file."""
from __future__ import annotations

import json
import math
from pathlib import Path

import msgspec

from msgs.sensor import CameraInfo
from tether import Input, Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    path: str = "out/selfcal.json"


class CalibReport(Node):
    """Inputs ``estimate`` and ``truth`` (latest kept); logs relative errors, writes ``path``."""

    Config = Config
    inputs = {"estimate": CameraInfo, "truth": Input(CameraInfo, depth=1, latest=True)}

    def setup(self) -> None:
        self.truth: CameraInfo | None = None
        self.last: dict | None = None

    def on_truth(self, msg: CameraInfo) -> None:
        self.truth = msg

    def on_estimate(self, msg: CameraInfo) -> None:
        row = {k: getattr(msg, k) for k in ("fx_px", "fy_px", "cx_px", "cy_px", "fx_sigma_px", "fy_sigma_px",
                                             "cx_sigma_px", "cy_sigma_px", "method", "degenerate", "reason")}
        row = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in row.items()}
        text = (f"fx {msg.fx_px:.1f} +- {msg.fx_sigma_px:.1f}, fy {msg.fy_px:.1f} +- {msg.fy_sigma_px:.1f}, "
                f"c ({msg.cx_px:.1f}, {msg.cy_px:.1f}) px by {msg.method}")
        if self.truth is not None:
            row["f_rel_err"] = max(abs(msg.fx_px - self.truth.fx_px) / self.truth.fx_px,
                                   abs(msg.fy_px - self.truth.fy_px) / self.truth.fy_px)
            text += f"; truth fx {self.truth.fx_px:.1f}: {100 * row['f_rel_err']:.2f} % off"
        if msg.degenerate:
            text = "DEGENERATE (" + msg.reason + "): " + text
        self.log.info("%s", text)
        self.last = row

    def teardown(self) -> None:
        if self.last is not None:
            Path(self.config.path).parent.mkdir(parents=True, exist_ok=True)
            Path(self.config.path).write_text(json.dumps(self.last, indent=1))
