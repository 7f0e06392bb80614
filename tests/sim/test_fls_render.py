"""FLS image formation: effective region, shadows, true hits, noise statistics, quantisation."""
from __future__ import annotations

import json

import numpy as np
import pytest

from sim.fls_render import PingSettings, bearing_table, render_ping
from sim.fls_scene import load_scene, sonar_frame

H = 5.0                 # sonar altitude in these scenes (sonar 1 m deep, seabed 6 m)


def _scene(tilt_deg: float = 30.0, structures=(), **sonar) -> object:
    return load_scene({"name": "t", "seafloor": {"type": "plane", "z_m": -6.0, "reflectivity": 0.3},
                       "structures": list(structures), "sonar": {"tilt_deg": tilt_deg, **sonar}})


def _pose(scene, yaw: float = 0.0) -> np.ndarray:
    return sonar_frame(np.array([0.0, 0.0, -1.0]), yaw, scene.sonar.tilt_rad)


def _centre_beam(ping) -> int:
    return int(np.argmin(np.abs(ping.bearings_rad)))


def test_bearing_table_reproduces_the_real_m1200d_table():
    table = bearing_table(256, np.radians(60.0))
    golden = np.array([-3000, -2974, -2948, -2922, -2896])               # expected_parse.json, first 5
    assert np.abs(table[:5] - golden).max() <= 1
    steps = np.diff(table)
    assert steps.min() == 22 and steps.max() == 26                       # 0.22 deg centre, 0.26 edges
    np.testing.assert_array_equal(table, -table[::-1])
    with pytest.raises(ValueError, match="n_beams"):
        bearing_table(1, 1.0)


def test_bearing_table_matches_the_shared_ping_to_a_hundredth_of_a_degree(shared_data):
    from drivers.oculus_protocol import decode_ping

    real = decode_ping((shared_data / "sonar/oculus-m1200d/one_ping_8bit.raw").read_bytes()).bearings_cdeg
    assert np.abs(bearing_table(256, np.radians(60.0)).astype(int) - real).max() <= 1


def test_flat_seafloor_lights_exactly_the_effective_region():
    scene = _scene(tilt_deg=30.0)                                        # s = 20 deg, t = 30 deg
    ping = render_ping(scene, _pose(scene), PingSettings(range_m=20.0, n_beams=256))
    col = ping.level[:, _centre_beam(ping)]
    rows = np.nonzero(col > 0)[0]
    r_first, r_last = (rows[0] + 0.5) * ping.range_resolution_m, (rows[-1] + 0.5) * ping.range_resolution_m
    r_emin, r_emax = H / np.sin(np.radians(40)), H / np.sin(np.radians(20))      # eq. (7), (8)
    assert r_first == pytest.approx(r_emin, abs=0.06) and r_last == pytest.approx(r_emax, abs=0.06)
    assert np.all(ping.intensities[: rows[0] - 2] == 0)                  # no noise without an rng


def test_seafloor_level_does_not_depend_on_resolution_or_ray_count():
    scene = _scene(tilt_deg=30.0)
    band = slice(None)
    means = []
    for n_ranges, rays in ((400, 40), (1000, 40), (1000, 90)):
        ping = render_ping(scene, _pose(scene), PingSettings(range_m=20.0, n_ranges=n_ranges, elevation_rays=rays))
        r = (np.arange(n_ranges) + 0.5) * ping.range_resolution_m
        band = (r > 9.0) & (r < 13.0)
        means.append(float(ping.level[band, _centre_beam(ping)].mean()))
    assert means[0] > 0 and np.ptp(means) / np.mean(means) < 0.05


def test_a_pile_casts_a_shadow_and_highlights_in_front():
    pile = {"type": "cylinder", "from_m": [10.0, 0.0, -6.0], "to_m": [10.0, 0.0, 1.0], "radius_m": 0.5}
    scene = _scene(tilt_deg=30.0, structures=[pile])
    ping = render_ping(scene, _pose(scene), PingSettings(range_m=20.0, n_beams=256, elevation_rays=60))
    r = (np.arange(ping.level.shape[0]) + 0.5) * ping.range_resolution_m
    on = _centre_beam(ping)
    off = int(np.argmin(np.abs(ping.bearings_rad - np.radians(20))))
    behind = (r > 11.0) & (r < 14.0)
    assert np.all(ping.level[behind, on] == 0) and np.all(ping.level[behind, off] > 0)     # shadow vs seafloor
    front = (r > 9.0) & (r < 10.6)
    assert ping.level[front, on].max() > 10 * ping.level[behind, off].mean()                # metal outshines sand
    assert np.any(ping.hit_labels == 1) and np.any(ping.hit_labels == 0)


def test_true_hits_are_consistent_with_the_image_geometry():
    scene = load_scene("tripod")
    pose = scene.sonar_pose(12.0)
    ping = render_ping(scene, pose, PingSettings(range_m=20.0), rng=np.random.default_rng(0))
    origin = pose[:3, 3]
    np.testing.assert_allclose(np.linalg.norm(ping.hits_m - origin, axis=1), ping.hit_ranges_m, rtol=1e-9)
    assert ping.hit_ranges_m.max() < 20.0
    seafloor = ping.hit_labels == 0
    np.testing.assert_allclose(ping.hits_m[seafloor, 2], -6.0, atol=1e-9)
    assert set(np.unique(ping.hit_labels)) - {0} and ping.hits_m[~seafloor, 2].max() > -5.0   # structures seen
    local = (ping.hits_m - origin) @ pose[:3, :3]                        # back into the sonar frame (FRD)
    np.testing.assert_allclose(np.arctan2(local[:, 1], local[:, 0]), ping.hit_bearings_rad, atol=1e-9)
    np.testing.assert_allclose(np.arcsin(local[:, 2] / ping.hit_ranges_m), ping.hit_elevations_rad, atol=1e-9)


def test_speckle_keeps_the_mean_and_noise_floor_fills_the_water_column():
    scene = _scene(tilt_deg=30.0, speckle=1.0, noise_floor=0.0)
    settings = PingSettings(range_m=20.0, gamma=1.0, bits=16, n_beams=512)
    ping = render_ping(scene, _pose(scene), settings, rng=np.random.default_rng(1))
    region = (ping.level > 0) & (ping.level < 0.2)
    observed = ping.intensities[region].astype(float) / 65535
    assert observed.mean() == pytest.approx(ping.level[region].mean(), rel=0.03)
    level = ping.level[region].astype(float)
    spread = np.sqrt(2 * np.mean(level ** 2) - level.mean() ** 2)       # Var(L E) with E ~ Exp(1)
    assert observed.std() == pytest.approx(spread, rel=0.05)
    noisy = render_ping(_scene(tilt_deg=30.0, noise_floor=0.01), _pose(scene), PingSettings(range_m=20.0),
                        rng=np.random.default_rng(1))
    water = noisy.level == 0
    assert noisy.intensities[water].mean() > 10                           # sqrt(0.01) * 255 = 25.5 on average


def test_bits_gain_gamma_and_seed():
    scene = load_scene("tripod")
    pose = scene.sonar_pose(10.0)
    img = {b: render_ping(scene, pose, PingSettings(bits=b), rng=np.random.default_rng(5)).intensities for b in (8, 16)}
    assert img[8].dtype == np.uint8 and img[16].dtype == np.uint16
    assert np.abs(img[16].astype(float) / 257 - img[8]).max() <= 1.0
    again = render_ping(scene, pose, PingSettings(bits=8), rng=np.random.default_rng(5)).intensities
    np.testing.assert_array_equal(again, img[8])
    lo, hi = (render_ping(scene, pose, PingSettings(gain_percent=g), rng=np.random.default_rng(5)).intensities
              for g in (20, 80))
    assert hi.mean() > 1.5 * lo.mean() and np.all(hi >= lo)
    g1 = render_ping(scene, pose, PingSettings(gamma=1.0), rng=np.random.default_rng(5)).intensities
    assert g1.mean() < img[8].mean()                                      # gamma 0.5 lifts dark echoes
    with pytest.raises(ValueError, match="bits"):
        render_ping(scene, pose, PingSettings(bits=12))


def test_range_is_clipped_to_the_frequency_mode_maximum():
    scene = load_scene("tripod")
    ping = render_ping(scene, scene.sonar_pose(0.0), PingSettings(range_m=30.0, frequency="high", n_beams=256))
    assert ping.range_m == 10.0 and ping.horizontal_aperture_rad == pytest.approx(np.radians(80))
    assert ping.bearings_rad.max() == pytest.approx(np.radians(40), abs=1e-3)
    assert json.dumps(float(ping.vertical_aperture_rad))                  # plain float, not numpy


def test_row_gains_rise_with_range_and_are_what_the_image_got() -> None:
    from sim.fls import PingSettings, load_scene, render_ping

    scene = load_scene("tripod")
    pose = scene.sonar_pose(14.0)
    flat = render_ping(scene, pose, PingSettings(n_beams=128, range_m=20.0, gain_percent=10), rng=None)
    sloped = render_ping(scene, pose, PingSettings(n_beams=128, range_m=20.0, gain_percent=10, row_gain_db_per_m=0.5),
                         rng=None)
    np.testing.assert_allclose(flat.row_gains, 1.0)
    g = sloped.row_gains
    assert g.shape == (flat.intensities.shape[0],) and np.all(np.diff(g) > 0)
    assert 10 * np.log10(g[-1] / g[0]) == pytest.approx(10.0, abs=0.1)       # 0.5 dB/m over 20 m
    unsat = (sloped.intensities < 250) & (flat.intensities < 250) & (flat.intensities > 20)
    want = flat.intensities * np.sqrt(g)[:, None]
    np.testing.assert_allclose(sloped.intensities[unsat], want[unsat], atol=1.5)
