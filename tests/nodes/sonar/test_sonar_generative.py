"""Generative elevations per beam (nodes.sonar.generative) and their votes (nodes.sonar.generative_votes).

Ground truth from the FLS simulator: the flat seafloor (a surface leading at the aperture's bottom edge) and
a wall rising through the fan (leading at its top edge), each recovered from the intensity profile of one
ping; the uncertainty grows with range from the leading edge; a single view keeps both hypotheses (nothing
says which edge leads); a structure seen from one side; empty, saturated and malformed pings.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from nodes.sonar.carving import CarvingGrid, CarvingParams
from nodes.sonar.evaluation import surface_distances
from nodes.sonar.generative import GenerativeParams, level_of, slope_of, surface_elevations
from nodes.sonar.generative_votes import GenerativeCloud, GenerativeVotes, fuse
from sim.fls import PingSettings, load_scene, render_ping, sample_structures, sonar_frame

SETTINGS = PingSettings(n_beams=256, range_m=20.0)


def _true_elevation(ping, samples, labels) -> np.ndarray:
    """Each sample's true elevation: the simulator's first hits (of ``labels``) in its beam, interpolated in range."""
    out = np.full(samples.range_m.size, np.nan)
    for b in np.unique(samples.bearing_rad):
        hit = (ping.hit_bearings_rad == b) & np.isin(ping.hit_labels, labels)
        if hit.sum() < 3:
            continue
        order = np.argsort(ping.hit_ranges_m[hit])
        r, e = ping.hit_ranges_m[hit][order], ping.hit_elevations_rad[hit][order]
        sel = samples.bearing_rad == b
        inside = (samples.range_m[sel] >= r[0]) & (samples.range_m[sel] <= r[-1])
        out[np.flatnonzero(sel)[inside]] = np.interp(samples.range_m[sel][inside], r, e)
    return out


def test_slope_inverts_the_image_model() -> None:
    s = np.r_[0.0, np.geomspace(1e-3, 1e3, 50)]
    assert np.allclose(slope_of(s ** 2 / np.sqrt(1 + s ** 2)), s, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("seed", [None, 1])            # noise-free, then speckle + noise floor + quantisation
def test_the_flat_seafloor_is_recovered_from_its_bottom_edge(seed) -> None:
    scene = load_scene("flat")
    rng = None if seed is None else np.random.default_rng(seed)
    ping = render_ping(scene, scene.sonar_pose(3.0), SETTINGS, rng=rng)
    # the seafloor's reflectivity 0.3 x the simulator's level scale 60
    s = surface_elevations(ping.intensities, ping.bearings_rad, ping.range_resolution_m, ping.vertical_aperture_rad,
                           params=GenerativeParams(echo_scale=18.0, leading="bottom"))
    truth = _true_elevation(ping, s, [0])
    ok = np.isfinite(truth) & ~s.saturated
    assert ok.sum() > 5000
    err = np.abs(s.elevation_rad[ok] - truth[ok])
    assert np.median(err) < math.radians(0.6 if seed is None else 1.5)
    # the sigma covers the error: a 1-sigma holds most of it, 3 sigma nearly all
    z = err / s.sigma_rad[ok]
    assert np.mean(z <= 1) > 0.5 and np.mean(z <= 3) > 0.9


@pytest.mark.parametrize("gain_percent, bound_deg", [(10.0, 2.5), (50.0, 6.0)])
def test_a_wall_rising_through_the_fan_is_recovered_from_its_top_edge(gain_percent: float, bound_deg: float) -> None:
    scene = load_scene("wall")
    pose = sonar_frame(np.array([0.0, 0.0, -1.0]), math.pi / 2, scene.sonar.tilt_rad)   # 7.7 m from the face
    settings = PingSettings(n_beams=256, range_m=20.0, gain_percent=gain_percent)
    ping = render_ping(scene, pose, settings, rng=np.random.default_rng(2))
    gain = 10.0 ** (0.4 * (gain_percent - 50.0) / 10.0)
    s = surface_elevations(ping.intensities, ping.bearings_rad, ping.range_resolution_m, ping.vertical_aperture_rad,
                           params=GenerativeParams(leading="top"), gain=gain)
    truth = _true_elevation(ping, s, [1])
    ok = np.isfinite(truth)
    assert ok.sum() > 500
    err = np.abs(s.elevation_rad[ok] - truth[ok])
    # at 10 % gain the face's echo stays below full scale; at 50 % (the demo's) most of it clips and only the few
    # unclipped speckle samples carry its level (the censored estimate): the profile reads it short, the sigma says so
    assert np.median(err) < math.radians(bound_deg)
    assert np.mean(err / s.sigma_rad[ok] <= 3) > 0.85
    # the same points read from the wrong (bottom) edge are far off: the leading edge matters
    bottom = surface_elevations(ping.intensities, ping.bearings_rad, ping.range_resolution_m,
                                ping.vertical_aperture_rad, params=GenerativeParams(leading="bottom"), gain=gain)
    assert np.median(np.abs(bottom.elevation_rad[ok] - truth[ok])) > np.median(err) + math.radians(2.0)


def test_uncertainty_grows_from_the_leading_edge_and_one_view_keeps_both_hypotheses() -> None:
    scene = load_scene("wall")
    pose = sonar_frame(np.array([0.0, 0.0, -1.0]), math.pi / 2, scene.sonar.tilt_rad)
    ping = render_ping(scene, pose, SETTINGS, rng=np.random.default_rng(3))
    s = surface_elevations(ping.intensities, ping.bearings_rad, ping.range_resolution_m, ping.vertical_aperture_rad)
    assert set(np.unique(s.top)) == {True, False}         # both leading edges, one point each per bin
    for top in (True, False):
        sel = s.top == top
        long_runs = 0
        for run in np.unique(s.run[sel]):
            one = sel & (s.run == run)
            order = np.argsort(s.range_m[one])
            assert np.all(np.diff(s.swept_rad[one][order]) >= 0)
            if s.swept_rad[one].max() > math.radians(3.0):   # the far end of a run is less sure than its leading edge
                long_runs += 1
                assert s.sigma_rad[one][order][-1] > 1.5 * s.sigma_rad[one][order][0]
        assert long_runs > 50
    # a single ping in an empty grid: nothing refutes either hypothesis, both vote (the cloud says it is ambiguous
    # by holding both; the votes of later views are what picks one)
    grid = CarvingGrid(((-12, -2, -6.5), (12, 12, 0.0)), CarvingParams(), seafloor_z_m=-6.0)
    grid.integrate(ping.intensities, ping.bearings_rad, ping.range_resolution_m, pose, ping.vertical_aperture_rad)
    votes = GenerativeVotes(grid, min_votes=1)
    votes.integrate(ping.intensities, ping.bearings_rad, ping.range_resolution_m, pose, ping.vertical_aperture_rad)
    cloud = votes.cloud(flush=True)
    up = cloud.points_m[:, 2] > -2.5                      # the top hypothesis puts the wall's first returns high
    assert up.any() and (~up).any()
    assert np.all(np.isfinite(cloud.sigma_m)) and np.all(cloud.sigma_m > 0)


def test_the_seafloor_witnesses_which_edge_leads() -> None:
    # one short bright run (a low surface) at 6 m in every beam; the flat floor's echo from its near edge (row 600,
    # 12 m) on the port half, shadowed to row 800 on the starboard half
    bearings = np.radians(np.linspace(-30, 30, 128))
    img = np.zeros((1000, 128), np.uint8)
    img[300:330] = 180
    img[600:, :64] = 81
    img[800:, 64:] = 81
    floor = np.full(128, 600.0)
    s = surface_elevations(img, bearings, 0.02, math.radians(20), floor_rows=floor)
    port, starboard = s.beam < 62, s.beam >= 66                # (the beams next to the divide see both halves)
    # port: the bottom-edge ray reached the floor, nothing led there; the run reads from the top edge only
    assert np.any(port & s.top) and not np.any(port & ~s.top)
    # starboard: the bottom ray was blocked, and the run's top reading sweeps too little to be what blocked it
    assert np.any(starboard & ~s.top) and not np.any(starboard & s.top)
    # every run ends before the floor's near edge, the floor's own echo is never a run
    assert np.all(s.range_m < 600 * 0.02)
    blind = surface_elevations(img, bearings, 0.02, math.radians(20), floor_rows=floor,
                               params=GenerativeParams(floor_witness=False))
    assert np.all(blind.top[:blind.top.size // 2]) and np.any(blind.beam[~blind.top] < 64)


def test_a_one_sided_block_pass_votes_near_its_seen_faces() -> None:
    scene = load_scene("block")
    surface, _ = sample_structures(scene, 0.03)
    grid = CarvingGrid(((-6, -6, -6.5), (6, 10, 0.0)), CarvingParams(), seafloor_z_m=scene.seafloor.z_m)
    votes = GenerativeVotes(grid, settle_pings=20)
    rng = np.random.default_rng(4)
    for t in np.arange(0.0, 6.0, 0.1):
        pose = scene.sonar_pose(float(t))
        ping = render_ping(scene, pose, SETTINGS, rng=rng)
        args = (ping.intensities, ping.bearings_rad, ping.range_resolution_m, pose, ping.vertical_aperture_rad)
        grid.integrate(*args)
        votes.integrate(*args)
    cloud = votes.cloud(flush=True, min_votes=4)
    assert len(cloud.points_m) > 20
    d = surface_distances(cloud.points_m, surface)
    assert np.median(d) < 0.3
    # nothing on the far side of the block the pass never saw (its north face at y = 5)
    assert np.mean(cloud.points_m[:, 1] > 5.2) < 0.05


def test_empty_and_saturated_pings() -> None:
    bearings = np.radians(np.linspace(-60, 60, 128))
    empty = surface_elevations(np.zeros((400, 128), np.uint8), bearings, 0.05, math.radians(20))
    assert empty.range_m.size == 0 and empty.points_frd().shape == (0, 3)
    full = surface_elevations(np.full((400, 128), 255, np.uint8), bearings, 0.05, math.radians(20))
    # a beam bright over its whole range integrates past the aperture: finite points, flagged saturated
    assert full.range_m.size > 0 and np.all(np.isfinite(full.points_frd())) and np.all(np.isfinite(full.sigma_m()))
    assert full.saturated.mean() > 0.9
    assert np.all(np.abs(full.elevation_rad) <= math.radians(10) + 1e-9)
    grid = CarvingGrid(((-5, -5, -5), (5, 25, 5)), CarvingParams())
    votes = GenerativeVotes(grid, min_votes=1, settle_pings=0)
    pose = sonar_frame(np.zeros(3), math.pi / 2, 0.0)
    votes.integrate(np.full((400, 128), 255, np.uint8), bearings, 0.05, pose, math.radians(20))
    assert votes.cloud(flush=True).points_m.size == 0     # saturated points never vote


def test_bad_input_says_what_to_do() -> None:
    bearings = np.radians(np.linspace(-60, 60, 16))
    with pytest.raises(ValueError, match="one bearing per beam"):
        surface_elevations(np.zeros((10, 15), np.uint8), bearings, 0.05, 0.3)
    with pytest.raises(ValueError, match="range_resolution_m"):
        surface_elevations(np.zeros((10, 16), np.uint8), bearings, 0.0, 0.3)
    with pytest.raises(TypeError, match="uint8 or uint16"):
        level_of(np.zeros((4, 4), np.float32))
    with pytest.raises(ValueError, match="leading"):
        GenerativeParams(leading="middle")
    with pytest.raises(ValueError, match="odd smooth_beams"):
        GenerativeParams(smooth_beams=4)
    with pytest.raises(ValueError, match="min_votes"):
        GenerativeVotes(CarvingGrid(((0, 0, 0), (1, 1, 1)), CarvingParams()), min_votes=0)


def test_fuse_adds_only_voxels_the_carved_cloud_lacks() -> None:
    carved = np.array([[0.05, 0.05, 0.05], [1.05, 0.05, 0.05]])
    gen = GenerativeCloud(points_m=np.array([[0.05, 0.05, 0.05], [2.05, 0.05, 0.05]]), sigma_m=np.array([0.2, 0.3]),
                          votes=np.array([12, 15]))
    pts, sigma, votes = fuse(carved, np.array([0.03, 0.04]), np.array([3, 4]), gen, 0.1)
    assert pts.shape == (3, 3) and np.allclose(pts[2], [2.05, 0.05, 0.05])
    assert np.allclose(sigma, [0.03, 0.04, 0.3]) and list(votes) == [3, 4, 15]


def test_the_carved_cloud_node_adds_the_generative_voxels_when_asked() -> None:
    from msgs.geometry import Pose3D
    from msgs.sonar import SonarPing
    from nodes.sonar.carved_cloud import CarvedCloud
    from tether.testing import Harness

    scene = load_scene("block")
    rng = np.random.default_rng(6)
    events = []
    for t in np.arange(0.0, 6.05, 0.05):
        events.append((t, "pose", Pose3D.from_matrix(scene.sonar_pose(t), stamp_ns=int(round(t * 1e9)),
                                                     frame_id="world")))
    for k, t in enumerate(np.arange(0.02, 6.0, 0.1)):
        r = render_ping(scene, scene.sonar_pose(t), SETTINGS, rng=rng)
        events.append((t + 0.06, "ping", SonarPing(
            stamp_ns=int(round(t * 1e9)), intensities=r.intensities, bearings_rad=r.bearings_rad.astype(np.float32),
            range_resolution_m=r.range_resolution_m, range_m=r.range_m, ping_id=k, gamma=0.5,
            vertical_aperture_rad=r.vertical_aperture_rad)))
    events.sort(key=lambda e: e[0])
    params = {"bounds_m": [-8, -8, -6.5, 8, 10, 0], "seafloor_z_m": -6.0, "publish_every": 10, "settle_pings": 10}
    clouds = {}
    for generative in (False, True):
        with Harness(CarvedCloud, params=dict(params, generative=generative, generative_min_votes=4)) as h:
            h.feed(events)
        assert not h.node.dropped
        clouds[generative] = h.node.cloud(flush=True)
    plain, both = clouds[False], clouds[True]
    n = len(plain.points_m)
    assert len(both.points_m) > n                          # the generative voxels come on top
    assert np.allclose(np.asarray(both.points_m)[:n], np.asarray(plain.points_m))    # the carved ones unchanged
    sigma = np.asarray(both.sigma_m)
    assert np.all(np.isfinite(sigma) & (sigma > 0)) and len(sigma) == len(both.intensity)


def test_row_gained_pings_are_read_raw_with_their_gains_clipping_at_full_scale() -> None:
    """A device that amplifies far rows (a time-varying gain) clips them sooner. Compensating the image first moves a
    row's clipping point below full scale, where the censored level takes clipped samples for unclipped ones and
    reads the face several times too dim; the raw samples with their gains read it as a ping without row gains."""
    from nodes.sonar.gain import compensate_row_gains
    from nodes.sonar.generative import censored_level

    scene = load_scene("wall")
    pose = sonar_frame(np.array([0.0, 0.0, -1.0]), math.pi / 2, scene.sonar.tilt_rad)   # 7.7 m from the face
    ping = render_ping(scene, pose, PingSettings(n_beams=256, range_m=20.0, row_gain_db_per_m=1.0),
                       rng=np.random.default_rng(4))
    p, k = GenerativeParams(), 4
    raw, _ = censored_level(ping.intensities, k, p, 1.0, ping.row_gains)
    comp, _ = censored_level(compensate_row_gains(ping.intensities, ping.row_gains, 0.5).image, k, p, 1.0)
    true = ping.level[:raw.shape[1] * k].reshape(-1, k, ping.level.shape[1]).mean(axis=1).T
    on = true > 0.5                                        # the face's bins
    assert on.sum() > 300
    err_raw = np.median(np.abs(np.log(np.maximum(raw[on], 1e-6) / true[on])))
    err_comp = np.median(np.abs(np.log(np.maximum(comp[on], 1e-6) / true[on])))
    assert err_raw < 0.7 and err_comp > err_raw + 0.4
    # and the elevations integrated from the face's top edge follow
    kw = dict(params=GenerativeParams(leading="top"))
    args = (ping.bearings_rad, ping.range_resolution_m, ping.vertical_aperture_rad)
    s = surface_elevations(ping.intensities, *args, row_gains=ping.row_gains, **kw)
    c = surface_elevations(compensate_row_gains(ping.intensities, ping.row_gains, 0.5).image, *args, **kw)
    e_s, e_c = (np.nanmedian(np.abs(x.elevation_rad - _true_elevation(ping, x, [1]))) for x in (s, c))
    assert e_s < e_c
    with pytest.raises(ValueError, match="one finite gain > 0 per row"):
        surface_elevations(ping.intensities, *args, row_gains=ping.row_gains[:-1], **kw)


def test_the_carved_cloud_node_hands_the_generative_levels_the_raw_samples_and_their_row_gains(monkeypatch) -> None:
    from msgs.geometry import Pose3D
    from msgs.sonar import SonarPing
    from nodes.sonar.carved_cloud import CarvedCloud
    from tether.testing import Harness

    seen = []
    original = GenerativeVotes.integrate

    def spy(self, intensities, *args, **kwargs):
        seen.append((np.array(intensities), kwargs.get("row_gains")))
        return original(self, intensities, *args, **kwargs)

    monkeypatch.setattr(GenerativeVotes, "integrate", spy)
    scene = load_scene("block")
    r = render_ping(scene, scene.sonar_pose(3.0), PingSettings(n_beams=256, range_m=20.0, row_gain_db_per_m=1.0),
                    rng=np.random.default_rng(5))
    events = [(t, "pose", Pose3D.from_matrix(scene.sonar_pose(t), stamp_ns=int(round(t * 1e9)), frame_id="world"))
              for t in (2.9, 3.1)]
    events.append((3.05, "ping", SonarPing(stamp_ns=int(3e9), intensities=r.intensities,
                                           bearings_rad=r.bearings_rad.astype(np.float32),
                                           range_resolution_m=r.range_resolution_m, range_m=r.range_m, gamma=0.5,
                                           vertical_aperture_rad=r.vertical_aperture_rad, row_gains=r.row_gains)))
    with Harness(CarvedCloud, params={"bounds_m": [-8, -8, -6.5, 8, 10, 0], "seafloor_z_m": -6.0,
                                      "generative": True}) as h:
        h.feed(events)
    assert not h.node.dropped and len(seen) == 1
    img, gains = seen[0]
    assert np.array_equal(img, r.intensities) and np.allclose(gains, r.row_gains)
