"""The moving-camera simulator, the self-calibration node and report, and ``tether selfcal``."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from nodes.vision.calib_report import CalibReport
from nodes.vision.selfcal_node import SelfCalibration
from sim.moving_camera_node import MovingCamera
from tether.cli import main as tether_main
from tether.errors import ConfigError
from tether.testing import Harness


def _frames(n, **params):
    cam = Harness(MovingCamera, params=dict(frames=n, rate_hz=2.0, **params))
    cam.advance_to(n / 2.0 + 1)
    return cam, [(o.t_ns / 1e9 - cam.start_ns / 1e9, o.output, o.msg) for o in cam.outputs]


def test_node_calibrates_a_camera_moving_through_the_room(tmp_path):
    cam, events = _frames(6)
    truth = cam.of("truth")[0]
    cal = Harness(SelfCalibration, params=dict(min_keyframes=4))
    cal.feed([e for e in events if e[1] == "image"])
    infos = cal.of("camera_info")
    assert len(infos) == 3                                  # after keyframes 4, 5 and 6
    last = infos[-1]
    assert not last.degenerate, last.reason
    assert abs(last.fx_px - truth.fx_px) / truth.fx_px < 0.02
    assert 0 < last.fx_sigma_px < 0.03 * last.fx_px
    report = Harness(CalibReport, params=dict(path=str(tmp_path / "cal.json")))
    report.feed([(0.0, "truth", truth)] + [(0.1 + k, "estimate", m) for k, m in enumerate(infos)])
    report.close()
    saved = json.loads((tmp_path / "cal.json").read_text())
    assert saved["f_rel_err"] < 0.02 and saved["degenerate"] is False


def test_node_flags_a_turntable_and_keeps_finite_numbers():
    _, events = _frames(5, motion="fixating")
    cal = Harness(SelfCalibration, params=dict(min_keyframes=4))
    cal.feed([e for e in events if e[1] == "image"])
    last = cal.of("camera_info")[-1]
    assert last.degenerate and last.reason
    assert np.isfinite([last.fx_px, last.fy_px, last.cx_px, last.cy_px]).all()


def test_node_config_and_image_size_are_checked():
    with pytest.raises(ConfigError):
        Harness(SelfCalibration, params=dict(features="surf"))
    with pytest.raises(ConfigError):
        Harness(SelfCalibration, params=dict(principal_point=[1.0]))
    with pytest.raises(ConfigError):
        Harness(MovingCamera, params=dict(motion="orbit"))


CHESS = Path(__file__).resolve().parents[4] / "shared" / "data" / "camera" / "opencv-chessboard-stereo"


@pytest.mark.skipif(not CHESS.exists(), reason="../shared/data/camera is absent")
def test_cli_selfcal_on_real_chessboard_views(capsys):
    code = tether_main(["selfcal", *map(str, sorted(CHESS.glob("right*.jpg"))), "--chessboard", "9x6", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and not out["degenerate"]
    assert abs(out["fx_px"] - 542.35) / 542.35 < 0.03       # SOURCES.md: calibrateCamera's right camera


def test_cli_selfcal_refuses_too_few_images(tmp_path, capsys):
    paths = []
    for k in range(2):
        p = tmp_path / f"{k}.png"
        cv2.imwrite(str(p), np.full((48, 64), 100, np.uint8))
        paths.append(str(p))
    assert tether_main(["selfcal", *paths]) != 0
    assert "at least three" in capsys.readouterr().err
