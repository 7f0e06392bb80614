"""The marker simulator, the localiser, the SLAM node and the viewer through the in-process harness."""
from __future__ import annotations

import math

import numpy as np
import pytest

from msgs.sets import MarkerRanges
from nodes.sets.codac_env import available
from nodes.sets.set_localizer import SetLocalizerNode
from nodes.sets.set_slam import SetSlamNode
from nodes.sets.set_view import SetView
from sim.markers import SEED_MARKERS
from sim.markers_node import MarkerSim
from tether.errors import ConfigError
from tether.testing import Harness

pytestmark = pytest.mark.skipif(not available(), reason="codac is not installed")
MARKERS = [list(m) for m in SEED_MARKERS]


def _sim_events(steps=40, **params):
    sim = Harness(MarkerSim, params=dict(steps=steps, rate_hz=10.0, **params))
    sim.advance_to(steps / 10 + 1)
    return sim, [(o.t_ns / 1e9 - sim.start_ns / 1e9, o.output, o.msg) for o in sim.outputs]


def test_sim_stops_after_its_steps_and_publishes_every_step():
    sim, _ = _sim_events(steps=12)
    assert [m.step for m in sim.of("odom")] == list(range(1, 13)) == [m.step for m in sim.of("ranges")]
    r = sim.of("ranges")[5]
    assert r.marker_id.dtype == np.int32 and len(r.range_m) == len(r.marker_id) == len(r.bearing_rad)


def test_localiser_node_boxes_hold_the_truth_at_every_step():
    sim, events = _sim_events(steps=40)
    loc = Harness(SetLocalizerNode, params=dict(markers=MARKERS, eps_m=0.05))
    loc.feed([e for e in events if e[1] in ("odom", "ranges")])
    est = loc.of("estimate")
    truth = sim.of("truth")
    assert len(est) == 40
    for e, t in zip(est, truth):
        assert e.consistent and e.box[0, 0] <= t.x_m <= e.box[1, 0] and e.box[0, 1] <= t.y_m <= e.box[1, 1]
        assert e.width_m < 1.0 and e.compute_ms > 0 and len(e.inner) + len(e.boundary) > 0


def test_localiser_node_flags_an_impossible_measurement_and_skips_unknown_markers():
    loc = Harness(SetLocalizerNode, params=dict(markers=[[0.0, 0.0], [10.0, 0.0]], start_err_m=1.0, max_outliers=0))
    bad = MarkerRanges(step=1, marker_id=np.array([0, 1, 7], np.int32), range_m=np.array([0.5, 0.5, 3.0]),
                       range_err_m=np.full(3, 0.1), bearing_rad=np.full(3, math.nan), bearing_err_rad=np.zeros(3))
    loc.feed([(0.1, "ranges", bad)])
    (e,) = loc.of("estimate")
    assert not e.consistent and len(e.inner) == len(e.boundary) == 0
    assert np.allclose(e.box, [[-1, -1], [1, 1]])                      # the prediction, not a guess
    assert loc.node.unknown_markers == 1


def test_slam_node_tube_holds_the_truth_and_markers_get_boxes():
    sim, events = _sim_events(steps=60)
    slam = Harness(SetSlamNode, params=dict(n_markers=4))
    slam.feed([e for e in events if e[1] in ("odom", "ranges")])
    last = slam.of("map")[-1]
    truth = np.array([[0.0, 0.0]] + [[t.x_m, t.y_m] for t in sim.of("truth")])
    assert last.consistent and last.tube.shape == (61, 2, 2)
    assert np.all((last.tube[:, 0] <= truth) & (truth <= last.tube[:, 1]))
    bounded = np.all(np.isfinite(last.markers.reshape(4, -1)), axis=1)
    assert bounded.sum() >= 2
    m = np.array(SEED_MARKERS)[bounded]
    assert np.all((last.markers[bounded, 0] <= m) & (m <= last.markers[bounded, 1]))


def test_configs_are_checked():
    with pytest.raises(ConfigError):
        SetLocalizerNode.make_config({"engine": "fortran"})
    with pytest.raises(ConfigError):
        SetLocalizerNode.make_config({"markers": [[1.0, 2.0, 3.0]]})
    with pytest.raises(ConfigError):
        MarkerSim.make_config({"scene": "moon"})
    with pytest.raises(ConfigError):
        SetSlamNode.make_config({"n_markers": 0})


def test_view_writes_a_png_with_the_boxes(tmp_path):
    sim, events = _sim_events(steps=20)
    loc = Harness(SetLocalizerNode, params=dict(markers=MARKERS))
    loc.feed([e for e in events if e[1] in ("odom", "ranges")])
    path = tmp_path / "sets.png"
    view = Harness(SetView, params=dict(path=str(path), markers=MARKERS))
    view.feed([(o.t_ns / 1e9 - loc.start_ns / 1e9, "estimate", o.msg) for o in loc.outputs] +
              [e for e in events if e[1] == "truth"])
    view.close()
    import cv2
    img = cv2.imread(str(path))
    assert img is not None and img.shape[1] > 1000                     # two panels: the run and the last paving
    assert view.node.outside == 0
