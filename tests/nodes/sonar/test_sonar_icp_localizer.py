"""IcpLocalizer node: corrections out, tracking, bad clouds answered with converged=False."""
from __future__ import annotations

import numpy as np
import pytest

from msgs.sensor import PointCloud
from msgs.sonar import IcpResult
from nodes.sonar.icp_localizer import IcpLocalizer
from nodes.sonar.model import tripod_model
from tether.errors import ConfigError
from tether.testing import Harness

PARAMS = {"spacing_m": 0.15, "grid_m": 0.0, "yaw_hypotheses": 0}


def _cloud(yaw_deg: float, shift, seed: int = 0) -> PointCloud:
    pts, nrm = tripod_model(spacing_m=0.15)
    rng = np.random.default_rng(seed)
    facing = np.einsum("ij,ij->i", np.array([1.0, -14.0, -1.0]) - pts, nrm) > 0
    view = pts[facing][rng.choice(facing.sum(), 1200, replace=False)] + rng.normal(0, 0.02, (1200, 3))
    a = np.radians(yaw_deg)
    rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    return PointCloud(stamp_ns=5, frame_id="world", points_m=(view @ rot.T + shift).astype(np.float32))


def test_correction_undoes_the_offset_and_tracks() -> None:
    with Harness(IcpLocalizer, params=PARAMS) as h:
        h.feed([(0.0, "cloud", _cloud(8.0, [0.3, 0.2, 0.0])), (1.0, "cloud", _cloud(8.0, [0.3, 0.2, 0.0], seed=1))])
    results = h.of("correction")
    assert len(results) == 2 and all(isinstance(r, IcpResult) for r in results)
    first, second = results
    assert first.converged and not first.degenerate and not first.ambiguous and first.cloud_size == 1200
    yaw = np.degrees(2 * np.arctan2(first.correction.qz, first.correction.qw))
    assert yaw == pytest.approx(-8.0, abs=0.3)
    assert first.covariance.shape == (6, 6) and np.all(np.isfinite(first.covariance))
    assert second.iterations <= first.iterations           # started from the tracked correction


@pytest.mark.parametrize("points", [np.zeros((0, 3), np.float32), np.full((500, 3), np.nan, np.float32)])
def test_empty_or_nan_cloud_gives_an_unconverged_result(points) -> None:
    with Harness(IcpLocalizer, params=PARAMS) as h:
        h.feed([(0.0, "cloud", PointCloud(points_m=points))])
    (res,) = h.of("correction")
    assert not res.converged and res.cloud_size == 0 and h.node.flags["waiting"] == 1 and h.node.runs == 0


def test_model_from_a_mesh_file(tmp_path) -> None:
    obj = tmp_path / "cube.obj"
    obj.write_text("v 0 0 0\nv 2 0 0\nv 2 2 0\nv 0 2 0\nv 0 0 2\nv 2 0 2\nv 2 2 2\nv 0 2 2\n"
                   "f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n")
    with Harness(IcpLocalizer, params={**PARAMS, "model": str(obj), "spacing_m": 0.1}) as h:
        assert len(h.node._model.points) > 500


def test_config_errors() -> None:
    with pytest.raises(ConfigError):
        IcpLocalizer.make_config({"method": "gicp"})
    with pytest.raises(ConfigError):
        IcpLocalizer.make_config({"min_correspondence_m": 2.0, "max_correspondence_m": 1.0})
