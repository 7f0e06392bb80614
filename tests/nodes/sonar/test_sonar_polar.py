"""Polar -> Cartesian fan: targets land where geometry says, for any bearing table, and hard pings stay sane."""
from __future__ import annotations

import numpy as np
import pytest

from nodes.sonar.polar import FanGeometry, FanRenderer, build_lut, render_fan

MODES = [("nearest", "numpy"), ("bilinear", "numpy"), ("nearest", "cv2"), ("bilinear", "cv2")]


def _pixel_of(lut, x_m: float, y_m: float) -> tuple[float, float]:
    return lut.origin_row_px - y_m / lut.m_per_px, lut.origin_col_px + x_m / lut.m_per_px


def _blob_centre(image: np.ndarray) -> tuple[float, float]:
    w = image.astype(float)
    rows, cols = np.indices(w.shape)
    return float((rows * w).sum() / w.sum()), float((cols * w).sum() / w.sum())


def _tables() -> dict[str, np.ndarray]:
    uniform = np.deg2rad(np.linspace(-65, 65, 256))
    k = np.linspace(-1, 1, 256)
    nonuniform = np.deg2rad(65 * np.sin(k * np.pi / 2) ** 1 * (0.7 + 0.3 * k ** 2))  # denser at the centre
    return {"uniform": uniform, "descending": uniform[::-1].copy(), "nonuniform": nonuniform,
            "wide": np.deg2rad(np.linspace(-100, 100, 256))}


@pytest.mark.parametrize("table", ["uniform", "descending", "nonuniform", "wide"])
@pytest.mark.parametrize("interpolation,backend", MODES)
def test_point_target_lands_at_its_range_and_bearing(table: str, interpolation: str, backend: str) -> None:
    bearings = _tables()[table]
    n_ranges, dr = 400, 0.05
    for j, i in [(20, 300), (128, 150), (240, 399), (0, 50), (255, 200)]:
        ping = np.zeros((n_ranges, bearings.size), np.uint8)
        ping[i, j] = 255
        lut = build_lut(FanGeometry.of(ping, bearings, dr), width_px=1200)
        image = render_fan(ping, lut, interpolation=interpolation, backend=backend)
        if image.max() == 0:   # a single cell can fall between pixel centres in nearest mode
            continue
        r, th = (i + 0.5) * dr, bearings[j]
        want = _pixel_of(lut, r * np.sin(th), r * np.cos(th))
        got = _blob_centre(image)
        beam_px = r * abs(bearings[min(j + 1, 255)] - bearings[max(j - 1, 0)]) / lut.m_per_px
        assert abs(got[0] - want[0]) <= 1.5 + beam_px and abs(got[1] - want[1]) <= 1.5 + beam_px, (table, i, j)


def test_port_and_starboard_are_not_folded() -> None:
    """arctan(y/x) would map a port target onto starboard; arctan2 keeps it at x < 0."""
    bearings = np.deg2rad(np.linspace(-60, 60, 128))
    ping = np.zeros((200, 128), np.uint8)
    ping[150, 10] = 255          # bearing ~ -51 deg: port
    lut = build_lut(FanGeometry.of(ping, bearings, 0.1), width_px=800)
    image = render_fan(ping, lut, interpolation="bilinear")
    _, col = _blob_centre(image)
    assert col < lut.origin_col_px - 50


def test_wide_fan_reaches_behind_the_beam_line() -> None:
    bearings = np.deg2rad(np.linspace(-100, 100, 128))
    lut = build_lut(FanGeometry.of(np.zeros((100, 128)), bearings, 0.1), width_px=600)
    x0, x1, y0, y1 = lut.geometry.bounding_box()
    assert y0 < -0.1 * 10 * 0.9 and x1 == pytest.approx(10.0, abs=1e-9) and x0 == pytest.approx(-10.0, abs=1e-9)
    assert lut.mask[-1].any()    # the bottom row (behind the sonar) is inside the fan


def test_descending_table_is_the_mirror_of_ascending() -> None:
    rng = np.random.default_rng(1)
    bearings = np.deg2rad(np.linspace(-40, 40, 64))
    ping = rng.integers(0, 256, (120, 64), dtype=np.uint8)
    asc = render_fan(ping, build_lut(FanGeometry.of(ping, bearings, 0.1), width_px=300))
    desc = render_fan(ping[:, ::-1].copy(), build_lut(FanGeometry.of(ping, bearings[::-1], 0.1), width_px=300))
    assert np.abs(asc.astype(int) - desc).max() <= 1 and (asc != desc).mean() < 1e-3   # float32 rounding only


@pytest.mark.parametrize("interpolation,backend", MODES)
def test_zero_saturated_and_garbage_pings(interpolation: str, backend: str) -> None:
    rng = np.random.default_rng(2)
    bearings = np.deg2rad(np.linspace(-65, 65, 128))
    lut = build_lut(FanGeometry.of(np.zeros((300, 128)), bearings, 0.05), width_px=400)
    zero = render_fan(np.zeros((300, 128), np.uint8), lut, interpolation=interpolation, backend=backend)
    assert not zero.any()
    full = render_fan(np.full((300, 128), 255, np.uint8), lut, interpolation=interpolation, backend=backend)
    np.testing.assert_array_equal(full, 255 * lut.mask)      # saturated stays saturated, no wrap-around
    garbage = rng.integers(0, 65536, (300, 128), dtype=np.uint16)
    out = render_fan(garbage, lut, interpolation=interpolation, backend=backend)
    assert out.dtype == np.uint16 and out.shape == lut.shape
    assert out[lut.mask == 0].max() == 0 and out.max() <= garbage.max()


def test_bilinear_beats_nearest_on_a_smooth_field() -> None:
    bearings = np.deg2rad(np.linspace(-65, 65, 256))
    n_ranges, dr = 500, 0.04
    r = (np.arange(n_ranges) + 0.5) * dr

    def field(rr, th):
        return 100 + 80 * np.sin(rr * 1.3) * np.cos(th * 7)

    ping = field(r[:, None], bearings[None, :]).astype(np.float32)
    lut = build_lut(FanGeometry.of(ping, bearings, dr), width_px=800)
    rows, cols = np.indices(lut.shape)
    x = (cols - lut.origin_col_px) * lut.m_per_px
    y = (lut.origin_row_px - rows) * lut.m_per_px
    truth = field(np.hypot(x, y), np.arctan2(x, y))
    # between the outermost beam centres (beyond them the edge value is held: no data there)
    inner = ((lut.mask > 0) & (np.hypot(x, y) > 2 * dr) & (np.hypot(x, y) < r[-1])
             & (np.abs(np.arctan2(x, y)) <= bearings[-1]))
    errs = {}
    for interp, backend in MODES:
        img = render_fan(ping, lut, interpolation=interp, backend=backend)
        errs[interp, backend] = np.abs(img - truth)[inner].max()
    assert errs["bilinear", "numpy"] < 0.5 * errs["nearest", "numpy"]
    assert errs["bilinear", "numpy"] < 1.0 and errs["bilinear", "cv2"] < 1.5


def test_lookup_table_is_cached_per_geometry() -> None:
    bearings = np.deg2rad(np.linspace(-30, 30, 32))
    renderer = FanRenderer(width_px=100)
    ping = np.ones((50, 32), np.uint8)
    renderer.render(ping, bearings, 0.1)
    renderer.render(2 * ping, bearings.copy(), 0.1)
    assert renderer.builds == 1
    renderer.render(ping, bearings * 0.9, 0.1)
    renderer.render(np.ones((60, 32), np.uint8), bearings * 0.9, 0.1)
    assert renderer.builds == 3


@pytest.mark.parametrize("bearings,shape,match", [
    (np.deg2rad([-10, 5, -5, 10]), (10, 4), "ascending"),
    (np.deg2rad([-10, 0, 0, 10]), (10, 4), "ascending"),
    (np.array([0.0, np.nan, 0.2, 0.3]), (10, 4), "finite"),
    (np.deg2rad([-10, 0, 10]), (10, 4), "one entry per column"),
    (np.array([0.1]), (10, 1), "2 beams"),
])
def test_corrupt_geometry_raises_clearly(bearings, shape, match) -> None:
    with pytest.raises(ValueError, match=match):
        FanGeometry.of(np.zeros(shape), bearings, 0.1)


def test_shape_mismatch_and_bad_mode_raise() -> None:
    lut = build_lut(FanGeometry.of(np.zeros((10, 4)), np.linspace(-0.3, 0.3, 4), 0.1), width_px=50)
    with pytest.raises(ValueError, match="rebuild"):
        render_fan(np.zeros((11, 4)), lut)
    with pytest.raises(ValueError, match="interpolation"):
        render_fan(np.zeros((10, 4)), lut, interpolation="cubic")


def test_real_oculus_ping_numpy_and_cv2_agree(shared_data) -> None:
    raw = (shared_data / "sonar" / "oculus-m1200d" / "one_ping_8bit.raw").read_bytes()
    bearings = np.deg2rad(np.frombuffer(raw, "<i2", 256, offset=122) / 100.0)
    ping = np.frombuffer(raw, np.uint8, 703 * 256, offset=2048).reshape(703, 256)
    assert np.ptp(np.diff(bearings)) > 1e-4           # the real table is non-uniform
    lut = build_lut(FanGeometry.of(ping, bearings, 0.0028421889710794315), width_px=512)
    a = render_fan(ping, lut, interpolation="bilinear", backend="numpy").astype(int)
    b = render_fan(ping, lut, interpolation="bilinear", backend="cv2").astype(int)
    assert np.abs(a - b).max() <= 3 and a[lut.mask > 0].mean() == pytest.approx(ping.mean(), rel=0.35)


@pytest.mark.parametrize("interpolation,backend", MODES)
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float64])
def test_rendering_into_a_given_array_is_the_same_image(interpolation: str, backend: str, dtype) -> None:
    """What a node's loan receives: every pixel written (the loaned slot holds an older image), no other array."""
    rng = np.random.default_rng(5)
    bearings = np.deg2rad(np.linspace(-65, 65, 128))
    ping = (rng.random((300, 128)) * 200).astype(dtype)
    lut = build_lut(FanGeometry.of(ping, bearings, 0.05), width_px=400)
    fresh = render_fan(ping, lut, interpolation=interpolation, backend=backend)
    slot = np.full(lut.shape, 99, dtype)                       # stale contents of a reused slot
    got = render_fan(ping, lut, interpolation=interpolation, backend=backend, out=slot)
    assert got is slot
    np.testing.assert_array_equal(slot, fresh)
    with pytest.raises(ValueError, match="out is"):
        render_fan(ping, lut, interpolation=interpolation, backend=backend, out=np.zeros((3, 3), dtype))
    loans = []
    renderer = FanRenderer(width_px=400, interpolation=interpolation, backend=backend)
    image, _ = renderer.render(ping, bearings, 0.05, alloc=lambda shape, dt: loans.append(np.empty(shape, dt)) or loans[-1])
    assert image is loans[0] and len(loans) == 1
    np.testing.assert_array_equal(image, fresh)
