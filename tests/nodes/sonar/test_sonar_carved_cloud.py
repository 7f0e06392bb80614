"""CarvedCloud node through tether.testing: pings placed at the interpolated pose of their stamp, the cloud
lands on the structure with its sigma (PointCloud.sigma_m; older logs without it still decode), bad pings and poses are dropped and counted."""
from __future__ import annotations

import numpy as np

from msgs.geometry import Pose3D
from msgs.sonar import SonarPing
from nodes.sonar.carved_cloud import CarvedCloud
from nodes.sonar.evaluation import cloud_metrics
from sim.fls import PingSettings, load_scene, render_ping, sample_structures
from tether.testing import Harness

PARAMS = {"bounds_m": [-8, -8, -6.5, 8, 10, 0], "seafloor_z_m": -6.0, "publish_every": 5, "settle_pings": 10}


def _events(scene, times):
    """Poses at 20 Hz, pings at 6.7 Hz between them (their stamps fall between two poses)."""
    rng = np.random.default_rng(0)
    events = []
    for t in np.arange(times[0], times[-1] + 0.1, 0.05):
        pose = Pose3D.from_matrix(scene.sonar_pose(t), stamp_ns=int(round(t * 1e9)), frame_id="world")
        events.append((t, "pose", pose))
    for k, t in enumerate(times):
        r = render_ping(scene, scene.sonar_pose(t), PingSettings(n_beams=256, range_m=15.0), rng=rng)
        ping = SonarPing(stamp_ns=int(round(t * 1e9)), intensities=r.intensities,
                         bearings_rad=r.bearings_rad.astype(np.float32),
                         range_resolution_m=r.range_resolution_m, range_m=r.range_m, ping_id=k,
                         vertical_aperture_rad=r.vertical_aperture_rad)
        events.append((t + 0.06, "ping", ping))                 # arrives after the pose that follows its stamp
    return sorted(events, key=lambda e: e[0])


def test_cloud_lands_on_the_block_with_its_sigma() -> None:
    scene = load_scene("block")
    with Harness(CarvedCloud, params=PARAMS) as h:
        h.feed(_events(scene, np.arange(0.02, 6.0, 0.15)))
    clouds = h.of("points")
    assert len(clouds) == 40 // 5 and clouds[-1].frame_id == "world"
    assert h.node.pings == 40 and not h.node.dropped
    final = h.node.cloud(flush=True)
    pts, sigma = np.asarray(final.points_m, float), np.asarray(final.sigma_m)
    surface, _ = sample_structures(scene, 0.03)
    m = cloud_metrics(pts, surface)
    assert m["points"] >= 30 and m["acc_frac_0p2"] >= 0.85, m
    assert np.all((sigma > 0) & (sigma <= 0.3))                # the node publishes sigma <= max_sigma_m only
    assert len(sigma) == len(pts) == len(final.intensity) and np.all(np.asarray(final.intensity) >= 2)   # votes



def test_with_the_evidence_filter_the_node_publishes_unpinned_points_with_their_large_sigma() -> None:
    scene = load_scene("block")
    params = dict(PARAMS, keep="evidence")
    with Harness(CarvedCloud, params=params) as h:
        h.feed(_events(scene, np.arange(0.02, 6.0, 0.15)))
    final = h.node.cloud(flush=True)
    pts, sigma = np.asarray(final.points_m, float), np.asarray(final.sigma_m)
    surface, _ = sample_structures(scene, 0.03)
    assert cloud_metrics(pts, surface)["acc_frac_0p2"] >= 0.85
    assert np.any(sigma > 0.3) and np.all(np.isfinite(sigma))      # kept at any sigma, and says so
    with Harness(CarvedCloud, params=PARAMS) as default:
        default.feed(_events(scene, np.arange(0.02, 6.0, 0.15)))
    assert len(pts) > len(default.node.cloud(flush=True).points_m)

def test_a_point_cloud_logged_before_sigma_m_still_decodes() -> None:
    import msgpack

    from msgs.sensor import PointCloud
    from tether.codec import Codec

    codec = Codec()
    new = PointCloud(stamp_ns=7, frame_id="world", points_m=np.ones((4, 3), np.float32),
                     intensity=np.arange(4, dtype=np.float32), sigma_m=np.full(4, 0.2, np.float32))
    record = msgpack.unpackb(codec.encode_inline(new), raw=False)
    assert set(record) >= {"points_m", "intensity", "sigma_m"}
    del record["sigma_m"]                                          # what a log written before the field holds
    old = codec.decode_inline(PointCloud, msgpack.packb(record, use_bin_type=True))
    assert old.stamp_ns == 7 and len(old.points_m) == 4 and np.array_equal(old.intensity, new.intensity)
    assert old.sigma_m.shape == (0,)                              # the default: no uncertainty given


def test_bad_pings_and_poses_are_counted_not_raised() -> None:
    scene = load_scene("block")
    events = _events(scene, [0.02, 0.17])
    bad_pose = Pose3D(x_m=float("nan"), stamp_ns=int(0.3e9))
    bad_ping = SonarPing(stamp_ns=int(0.12e9), intensities=np.zeros((50, 8), np.uint8),
                         bearings_rad=np.zeros(3, np.float32), range_resolution_m=0.02)
    early = SonarPing(stamp_ns=int(-1e9), intensities=np.zeros((50, 3), np.uint8),
                      bearings_rad=np.array([-0.1, 0.0, 0.1], np.float32), range_resolution_m=0.02)
    with Harness(CarvedCloud, params=PARAMS) as h:
        h.feed(events + [(0.2, "ping", bad_ping), (0.21, "pose", bad_pose), (0.22, "ping", early)])
    assert h.node.pings == 2
    assert sum(h.node.dropped.values()) == 3, h.node.dropped
    assert any("bearing" in k for k in h.node.dropped) and any("pose" in k for k in h.node.dropped)


def test_gap_weight_reaches_the_grid_and_a_negative_one_is_refused() -> None:
    import msgspec
    import pytest

    from nodes.sonar.carved_cloud import Config

    with Harness(CarvedCloud, params={**PARAMS, "gap_weight": 2.0}) as h:
        pass
    assert h.node.grid.params.gap_weight == 2.0
    with pytest.raises((ValueError, msgspec.ValidationError), match="gap_weight"):
        Config(gap_weight=-1.0)
