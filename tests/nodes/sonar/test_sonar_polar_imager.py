"""PolarImager node through the in-process harness: images out, bad pings dropped, node keeps running."""
from __future__ import annotations

import numpy as np
import pytest

from msgs.sonar import FanImage, SonarPing
from nodes.sonar.polar_imager import PolarImager
from tether import Input, Node
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


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_image_and_mask_share_one_loan_and_each_ping_gets_its_own(dtype) -> None:
    """The node renders into one loaned block (image, then mask) per ping: right pixels, right mask, and
    no ping overwrites another's (a live graph's zero-copy path is tests/tether/test_shm_runtime.py's)."""
    from nodes.sonar.polar import FanGeometry, build_lut, render_fan

    pings = [_ping(k) for k in (4, 5)]
    pings = [SonarPing(**{**{f: getattr(p, f) for f in p.__struct_fields__},
                          "intensities": p.intensities.astype(dtype) * (257 if dtype == np.uint16 else 1)})
             for p in pings]
    with Harness(PolarImager, params={"width_px": 300, "backend": "cv2"}) as h:
        h.feed([(0.0, "ping", pings[0]), (0.1, "ping", pings[1])])
        first, second = h.of("image")
    for msg, ping in ((first, pings[0]), (second, pings[1])):
        lut = build_lut(FanGeometry.of(ping.intensities, ping.bearings_rad, 0.05), width_px=300)
        np.testing.assert_array_equal(msg.image, render_fan(ping.intensities, lut, backend="cv2"))
        np.testing.assert_array_equal(msg.mask, lut.mask)
        assert msg.image.dtype == dtype and msg.mask.dtype == np.uint8    # the first ping's image survived the second
    assert not np.array_equal(first.image, second.image)


class _Pings(Node):
    """Publishes three pings 0.3 s apart (the imager samples its input: latest only), then idles."""

    outputs = {"ping": SonarPing}

    def run(self) -> None:
        for k in (6, 7, 8):
            self.publish("ping", _ping(k, n_beams=128, n_ranges=300))
            self.stopping.wait(0.3)
        self.stopping.wait()


class _FanKeeper(Node):
    inputs = {"image": Input(FanImage, depth=10)}

    def setup(self) -> None:
        self.kept: list[FanImage] = []

    def on_image(self, msg: FanImage) -> None:
        self.kept.append(msg)


def test_in_a_live_graph_the_fan_crosses_without_a_copy(tmp_path) -> None:
    import threading
    import time

    from nodes.sonar.polar import FanGeometry, build_lut, render_fan
    from tether import shm
    from tether.runtime import NodeRuntime, RunSpec, Source

    if not shm.Settings.from_env().enabled:
        pytest.skip("no /dev/shm or OFD locks here")
    pings_at, fans_at = f"ipc://{tmp_path}/pings", f"ipc://{tmp_path}/fans"
    source = NodeRuntime(RunSpec(graph="g", node_id="sonar", node="t:_Pings", binds=[pings_at],
                                 expect_subscribers={"sonar/ping": 1}, wait_subscribers_s=30), _Pings)
    imager = NodeRuntime(RunSpec(graph="g", node_id="imager", node="t:PolarImager", binds=[fans_at],
                                 params={"width_px": 400}, inputs={"ping": Source(topic="sonar/ping", endpoint=pings_at)},
                                 expect_subscribers={"imager/image": 1}, wait_subscribers_s=30), PolarImager)
    keeper = NodeRuntime(RunSpec(graph="g", node_id="keep", node="t:_FanKeeper",
                                 inputs={"image": Source(topic="imager/image", endpoint=fans_at)}), _FanKeeper)
    threads = [threading.Thread(target=rt.serve, daemon=True) for rt in (keeper, imager, source)]
    for t in threads:
        t.start()
    try:
        deadline = time.monotonic() + 20
        # kept is made by setup, on the serving thread: it may not exist yet (a loaded machine may skip a ping)
        while len(getattr(keeper.node, "kept", ())) < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        counters = imager.shm_counters()
    finally:
        for rt in (source, imager, keeper):
            rt.stop()
        for t in threads:
            t.join(30)
    kept = keeper.node.kept
    assert kept and counters["placed"] == counters["loaned"] == imager.node.rendered   # image and mask: one loan
    for msg in kept:
        ping = _ping(msg.ping_id, n_beams=128, n_ranges=300)
        lut = build_lut(FanGeometry.of(ping.intensities, ping.bearings_rad, 0.05), width_px=400)
        np.testing.assert_array_equal(msg.image, render_fan(ping.intensities, lut, backend="cv2"))
        np.testing.assert_array_equal(msg.mask, lut.mask)
