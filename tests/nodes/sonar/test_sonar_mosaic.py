"""The mosaic node on the simulated survey (virtual time): seabed projection, keyframes,
registrations, the graph, and what it publishes; the textured seabed and survey path of
the FLS simulator it needs."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from msgs.sensor import Grid
from msgs.sonar import SonarPing
from nodes.slam import fourier
from nodes.sonar.icp import yaw_of
from nodes.sonar.mosaic import Config, SonarMosaic
from nodes.sonar.seabed import SeabedGrid, SeabedProjector
from sim.fls_render import PingSettings, render_ping
from sim.fls_scene import load_scene
from sim.subimages import survey_pings
from tether.launch import load_launch
from tether.testing import Harness


@pytest.fixture(scope="module")
def survey():
    return load_scene("survey")


def test_the_survey_path_runs_its_waypoints_out_and_back(survey):
    p = survey.platform
    xy, yaw = p.position_heading(0.0)
    assert np.allclose(xy, [-20, -12]) and yaw == pytest.approx(0.0)
    xy, yaw = p.position_heading(32 / 1.5 + 4 / 1.5)                  # 4 m up the second leg, heading north
    assert np.allclose(xy, [12, -8]) and yaw == pytest.approx(math.pi / 2)
    total = sum(np.linalg.norm(np.diff(p.waypoints, axis=0), axis=1))
    xy, yaw = p.position_heading(total / 1.5 + 1.0)                   # on the way back
    assert np.allclose(xy, p.waypoints[-1] - 1.5 * np.diff(p.waypoints[-2:], axis=0)[0] / np.linalg.norm(
        np.diff(p.waypoints[-2:], axis=0)[0]))


def test_the_projected_ping_is_the_seabed_texture_where_it_lies(survey):
    cfg = Config()
    pose = survey.sonar_pose(3.0)
    r = render_ping(survey, pose, PingSettings(n_beams=256, range_m=20), rng=None)
    ping = SonarPing(intensities=r.intensities, bearings_rad=r.bearings_rad.astype(np.float32),
                     range_resolution_m=r.range_resolution_m, range_m=r.range_m,
                     vertical_aperture_rad=r.vertical_aperture_rad)
    image, mask = SeabedProjector(SeabedGrid()).project(ping.intensities, ping.bearings_rad, ping.range_resolution_m,
                                                        ping.vertical_aperture_rad, pose)
    n, c = cfg.image_px, (cfg.image_px - 1) / 2
    cols, rows = np.meshgrid(np.arange(n), np.arange(n))
    yaw = yaw_of(pose)
    fwd, left = cfg.center_ahead_m + (cols - c) * cfg.cell_m, (rows - c) * cfg.cell_m
    texture = survey.seafloor.texture.factor_at(pose[0, 3] + fwd * math.cos(yaw) - left * math.sin(yaw),
                                                pose[1, 3] + fwd * math.sin(yaw) + left * math.cos(yaw))
    s = fourier.phase_correlate(texture.astype(np.float32), image, fixed_mask=mask, moving_mask=mask, shift_hint=(0, 0))
    assert abs(s.dx) < 0.3 and abs(s.dy) < 0.3 and s.pnr > 20
    assert 0.2 < mask.mean() < 0.9 and abs(float(image[mask].mean()) - 1.0) < 0.1     # flat-fielded


def test_mosaic_node_on_the_first_leg(survey, tmp_path):
    h = Harness(SonarMosaic, params={"out_dir": str(tmp_path)})
    for t, ping, nav, truth in survey_pings(survey, duration_s=18.0, seed=1):
        h.feed([(t, "nav", nav), (t, "truth", truth), (t + 0.001, "ping", ping)], until_s=t + 0.002)
    node = h.node
    report = node.report()
    assert report["keyframes"] >= 12 and report["closures"] >= 10
    assert report["ate_m_graph"] < 0.3 and report["ate_m_chain"] < 0.5
    grids = h.of("mosaic")
    assert grids and isinstance(grids[-1], Grid) and grids[-1].resolution_m == pytest.approx(0.1)
    assert np.isfinite(grids[-1].data).mean() > 0.3
    track = h.of("trajectory")[-1].poses
    assert track.shape == (int(report["keyframes"]), 3)
    h.close()
    assert (tmp_path / "mosaic.png").stat().st_size > 1000 and (tmp_path / "mosaic_trajectories.png").exists()


def test_the_launch_file_validates():
    launch = load_launch(Path(__file__).resolve().parents[3] / "launch" / "sonar_mosaic.yaml")
    assert {n.id for n in launch.nodes} == {"sim", "sonar", "nav", "mosaic"}
