"""nodes.control.tracking_eval: errors against an interpolated reference; node summary + PNG."""
from __future__ import annotations

import math

import numpy as np
import pytest

from msgs.control import TrajectoryPoint, VehicleState
from nodes.control.tracking_eval import TrackingEval, summarize, tracking_errors
from tether.testing import Harness


def test_errors_against_the_interpolated_reference_and_heading_wrap():
    ref_t = np.array([0.0, 1.0, 2.0])
    ref = np.array([[0, 0, math.pi - 0.1], [1, 0, -math.pi + 0.1], [2, 0, -math.pi + 0.3]])   # crosses +-pi
    t = np.array([-0.5, 0.5, 1.5, 3.0])
    pose = np.array([[9, 9, 0], [0.5, 0.003, math.pi], [1.5, -0.004, -math.pi + 0.2], [9, 9, 0]])
    keep, pos, head = tracking_errors(ref_t, ref, t, pose)
    assert keep.tolist() == [False, True, True, False]
    assert pos == pytest.approx([0.003, 0.004])
    assert head == pytest.approx([0.0, 0.0], abs=1e-12)             # short way round the wrap
    s = summarize(pos, head)
    assert s["rms_mm"] == pytest.approx(math.sqrt((9 + 16) / 2)) and s["max_mm"] == pytest.approx(4.0)
    assert math.isnan(summarize(np.zeros(0), np.zeros(0))["rms_mm"])
    with pytest.raises(ValueError, match="strictly increasing"):
        tracking_errors(np.array([0.0, 0.0]), ref[:2], t, pose)


def test_node_summary_and_png(tmp_path):
    png = tmp_path / "track.png"
    h = Harness(TrackingEval, params={"png": str(png), "skip_s": 0.0})
    events = []
    for k in range(200):
        t = k * 0.02
        events.append((t, "reference", TrajectoryPoint(stamp_ns=int(t * 1e9), x_m=math.cos(t), y_m=math.sin(t), theta_rad=t)))
        events.append((t + 0.001, "state", VehicleState(stamp_ns=int(t * 1e9), x_m=math.cos(t) + 0.002,
                                                        y_m=math.sin(t), theta_rad=t + 0.01)))
    h.feed(events)
    errors = [m.data for m in h.of("error")]
    assert len(errors) >= 190 and max(errors) == pytest.approx(0.002, abs=1e-9)
    h.close()
    s = h.node.summary
    assert s["rms_mm"] == pytest.approx(2.0, abs=1e-6) and s["rms_heading_deg"] == pytest.approx(math.degrees(0.01))
    assert png.stat().st_size > 10_000
