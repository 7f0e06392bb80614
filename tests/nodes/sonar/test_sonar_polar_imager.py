"""PolarImager node through the in-process harness: images out, bad pings dropped, node keeps running."""
from __future__ import annotations

import numpy as np
import pytest

from msgs.sonar import FanImage, SonarPing
from nodes.sonar.polar_imager import PolarImager
from tether.errors import ConfigError
from tether.testing import Harness


def _ping(ping_id: int, n_beams: int = 64, n_ranges: int = 100, **kw) -> SonarPing:
    rng = np.random.default_rng(ping_id)
    args = dict(intensities=rng.integers(0, 256, (n_ranges, n_beams), dtype=np.uint8),
                bearings_rad=np.deg2rad(np.linspace(-65, 65, n_beams)).astype(np.float32),
                range_resolution_m=0.05, range_m=n_ranges * 0.05, ping_id=ping_id, stamp_ns=ping_id * 10**8,
                frame_id="sonar")
    args.update(kw)
    return SonarPing(**args)


@pytest.mark.parametrize("interpolation", ["nearest", "bilinear"])
def test_images_come_out_with_geometry(interpolation: str) -> None:
    with Harness(PolarImager, params={"width_px": 300, "interpolation": interpolation}) as h:
        h.feed([(0.0, "ping", _ping(1)), (0.1, "ping", _ping(2))])
        images = h.of("image")
    assert len(images) == 2 and all(isinstance(m, FanImage) for m in images)
    img = images[1]
    assert img.ping_id == 2 and img.stamp_ns == 2 * 10**8 and img.frame_id == "sonar"
    assert img.image.shape == img.mask.shape and img.image.shape[1] == 300
    assert img.image.dtype == np.uint8 and not img.image[img.mask == 0].any()
    # the sonar origin is on the bottom edge of a forward fan, centred
    assert img.origin_col_px == pytest.approx(149.5, abs=0.6)
    assert img.m_per_px == pytest.approx(2 * 5.0 * np.sin(np.deg2rad(65 + 130 / 63 / 2)) / 300, rel=1e-3)
    assert h.node._renderer.builds == 1


def test_bad_pings_are_dropped_and_counted() -> None:
    bad_count = _ping(3, bearings_rad=np.zeros(10, np.float32))
    shuffled = _ping(4, bearings_rad=np.random.default_rng(0).permutation(np.linspace(-1, 1, 64)).astype(np.float32))
    with Harness(PolarImager, params={"width_px": 200}) as h:
        h.feed([(0.0, "ping", bad_count), (0.1, "ping", shuffled), (0.2, "ping", _ping(5))])
    assert [m.ping_id for m in h.of("image")] == [5]
    assert h.node.dropped == 2


def test_resolution_falls_back_to_range_over_rows() -> None:
    with Harness(PolarImager, params={"width_px": 200}) as h:
        h.feed([(0.0, "ping", _ping(6, range_resolution_m=0.0))])
    assert len(h.of("image")) == 1


def test_config_is_validated() -> None:
    with pytest.raises(ConfigError):
        PolarImager.make_config({"interpolation": "cubic"})
    with pytest.raises(ConfigError):
        PolarImager.make_config({"width_px": 1})
