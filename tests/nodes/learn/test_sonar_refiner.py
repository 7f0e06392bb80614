"""Sonar refiner (issue 15, deliverable 3): the gap statistics, the space-to-depth refiner, its
checkpoint, the node, and that refining keeps where the echoes are."""
from __future__ import annotations

import numpy as np
import pytest

from msgs.sonar import SonarPing
from nodes.learn.simgan import Refiner, SimGANConfig, init_simgan, load_refiner, refine_images, save_refiner
from nodes.learn.sonar_gap import discriminator_gap, intensity_gap, sample_patches, speckle_contrast, speckle_gap
from nodes.learn.sonar_refiner import DEFAULT_WEIGHTS, Refiner as PingRefiner, SonarRefiner
from sim.fls_dataset import CloseRangeSetup, real_oculus_pings, render_training_pings, unsaturated_gain
from tether.testing import Harness

RNG = np.random.default_rng(0)


def _speckle(shape, mean, rng):
    return np.clip(rng.standard_exponential(shape) * mean, 0, 255).astype(np.uint8)


def test_intensity_gap_is_the_shift_between_histograms():
    a = RNG.integers(50, 150, (2, 64, 64), dtype=np.uint8)
    assert intensity_gap(list(a), list(a)) == pytest.approx(0.0, abs=1e-9)
    assert intensity_gap(list(a), list(a + 10)) == pytest.approx(10.0, abs=0.05)


def test_speckle_gap_sees_smoothed_speckle_and_skips_dark_windows():
    import cv2

    rng = np.random.default_rng(1)
    rough = _speckle((128, 128), 60, rng)
    other = _speckle((128, 128), 60, rng)
    smooth = cv2.GaussianBlur(rough, (0, 0), 2.0)
    assert np.median(speckle_contrast(rough)) > 0.7 > np.median(speckle_contrast(smooth))
    assert speckle_gap([rough], [other]) < 0.05 < speckle_gap([smooth], [other])
    black = np.zeros((64, 64), np.uint8)
    assert len(speckle_contrast(black)) == 0 and np.isnan(speckle_gap([black], [other]))
    with pytest.raises(ValueError, match="non-empty 2-D uint8"):
        intensity_gap([np.zeros((4, 4), np.float32)], [other])


def test_fresh_discriminator_tells_apart_what_differs_and_not_what_does_not():
    rng = np.random.default_rng(2)
    same_a = sample_patches([_speckle((96, 96), 60, rng) for _ in range(4)], 200, 16, seed=0)
    same_b = sample_patches([_speckle((96, 96), 60, rng) for _ in range(4)], 200, 16, seed=1)
    bright = sample_patches([_speckle((96, 96), 120, rng) for _ in range(4)], 200, 16, seed=2)
    alike = discriminator_gap(same_a[:100], same_b[:100], same_a[100:], same_b[100:], steps=60, batch=32)
    differ = discriminator_gap(same_a[:100], bright[:100], same_a[100:], bright[100:], steps=60, batch=32)
    assert alike["gap"] < 0.3 and differ["auc"] > 0.9


def test_space_to_depth_refiner_starts_as_the_identity_on_any_size():
    import jax
    import jax.numpy as jnp

    x = np.random.default_rng(3).uniform(-1, 1, (2, 37, 22, 1)).astype(np.float32)     # not multiples of 4
    p = jax.jit(Refiner(8, 1, 4, "add").init)(jax.random.key(0, impl="rbg"), jnp.asarray(x))   # as init_simgan does
    for residual in ("add", "tanh"):                            # the same weights: only the output differs
        y = np.asarray(Refiner(8, 1, 4, residual).apply(p, jnp.asarray(x)))
        want = x if residual == "add" else np.clip(x, -0.999, 0.999)
        assert y.shape == x.shape and np.allclose(y, want, atol=1e-5)
    with pytest.raises(ValueError, match="residual"):
        jax.eval_shape(Refiner(8, 1, 4, "mul").init, jax.random.key(0, impl="rbg"), jnp.asarray(x))


def test_refiner_checkpoint_round_trip_and_mismatch(tmp_path):
    cfg = SimGANConfig(features=8, blocks=1, space_to_depth=4, residual="add")
    state = init_simgan(cfg, (16, 16, 1), seed=0)
    path = tmp_path / "r.simgan"
    save_refiner(path, state["r"], cfg, meta={"channels": 1})
    params, cfg2, meta = load_refiner(path)
    assert cfg2 == cfg and meta["channels"] == 1
    x = np.random.default_rng(4).integers(0, 256, (1, 20, 24, 1), dtype=np.uint8)
    assert np.array_equal(refine_images(params, x, cfg2), refine_images(state["r"], x, cfg))
    import jax

    wide = SimGANConfig(features=16, blocks=1, space_to_depth=4, residual="add")
    like = jax.eval_shape(lambda: init_simgan(wide, (16, 16, 1), seed=0)["r"])          # shapes only
    save_refiner(path, jax.tree_util.tree_map(lambda a: np.zeros(a.shape, a.dtype), like), wide, meta={"channels": 1})
    doc_cfg = load_refiner(path)[1]
    assert doc_cfg.features == 16                               # the config travels with the weights
    from nodes.learn.checkpoint import save_checkpoint

    save_checkpoint(tmp_path / "other.ckpt", {"w": np.zeros(3)}, meta={"kind": "ppo"})
    with pytest.raises(ValueError, match="not a SimGAN refiner"):
        load_refiner(tmp_path / "other.ckpt")


@pytest.fixture(scope="module")
def shipped() -> PingRefiner:
    if not DEFAULT_WEIGHTS.is_file():
        pytest.skip("no shipped sonar refiner weights")
    return PingRefiner()


def test_node_refines_intensities_only_and_drops_what_it_cannot_take(shipped):
    pings = [SonarPing(intensities=np.zeros((100, 64), np.uint8), range_m=2.0, ping_id=1),
             SonarPing(intensities=np.full((100, 64), 255, np.uint8), range_m=2.0, ping_id=2),
             SonarPing(intensities=np.full((50, 30), 40000, np.uint16), range_m=2.0, ping_id=3),
             SonarPing(intensities=np.zeros((10, 10), np.float32), ping_id=4),
             SonarPing(intensities=np.zeros((0, 0), np.uint8), ping_id=5)]
    with Harness(SonarRefiner) as h:
        h.feed([(0.1 * (i + 1), "sim_image", p) for i, p in enumerate(pings)])
        node = h.node
    out = h.of("refined_image")
    assert [o.ping_id for o in out] == [1, 2, 3] and node.dropped == 2
    for o, p in zip(out, pings):
        assert o.intensities.shape == p.intensities.shape and o.intensities.dtype == p.intensities.dtype
        assert o.range_m == p.range_m
    # the black shadow is lifted toward the real sonar's noise floor, white stays bright
    assert 0 < out[0].intensities.mean() < 128 and out[1].intensities.mean() > 128


def test_refining_keeps_where_the_echoes_are(shipped):
    """The labels a sonar image carries are the echoes' ranges: the leading edge of the seabed per
    beam must not move (the self-regularisation's job)."""
    from scipy.ndimage import uniform_filter1d

    pings = render_training_pings(2, seed=99, setup=CloseRangeSetup(n_beams=64, n_ranges=300, elevation_rays=60))

    def edge(a):
        x = uniform_filter1d(a.astype(np.float32), 5, axis=0)
        return np.argmax(x >= 0.5 * x.max(axis=0, keepdims=True), axis=0)

    for p in pings:
        moved = np.abs(edge(shipped(p)).astype(int) - edge(p).astype(int))
        assert np.median(moved) <= 3, moved


def test_training_pings_are_seeded_and_the_gain_rule_avoids_saturation():
    setup = CloseRangeSetup(n_beams=32, n_ranges=120, elevation_rays=40)
    a = render_training_pings(2, seed=5, setup=setup)
    assert np.array_equal(a, render_training_pings(2, seed=5, setup=setup)) and a.shape == (2, 120, 32)
    g = unsaturated_gain(setup, n=4)
    assert 0.0 <= g < 50.0                                      # the 20 m level scale saturates a close seabed
    assert (render_training_pings(4, seed=6, setup=setup, gain_percent=g) == 255).mean() < 0.03


def test_real_pings_load_when_present():
    try:
        real = real_oculus_pings()
    except FileNotFoundError:
        pytest.skip("../shared/data/sonar absent")
    assert len(real) == 3 and all(r.shape == (703, 256) and r.dtype == np.uint8 for r in real)


def test_refiner_sits_between_the_simulator_and_the_imager(monkeypatch):
    """launch/sonar_refined.yaml end to end: simulated pings pass the refiner into the imager. The
    launch runs until the imager's first image arrives here (at most 90 s), then stops on SIGINT."""
    import os
    import re
    import signal
    import subprocess
    import sys
    import tempfile
    import time
    from pathlib import Path

    from msgs.sonar import FanImage
    from tether.codec import Codec
    from tether.errors import TetherError
    from tether.introspect import subscribe

    if not DEFAULT_WEIGHTS.is_file():
        pytest.skip("no shipped sonar refiner weights")
    repo = Path(__file__).resolve().parents[3]
    base = tempfile.mkdtemp(prefix="tr-", dir="/tmp")          # short: ipc paths have a length limit
    monkeypatch.setenv("TETHER_RUNTIME_DIR", os.path.join(base, "rt"))
    monkeypatch.setenv("TETHER_KEYS_DIR", os.path.join(base, "keys"))
    launch = subprocess.Popen([sys.executable, "-m", "tether.cli", "launch", str(repo / "launch" / "sonar_refined.yaml"),
                               "--duration", "120"], cwd=repo, env=dict(os.environ), stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True)
    image = None
    try:
        deadline = time.monotonic() + 90
        while launch.poll() is None and time.monotonic() < deadline:
            try:
                _, sock = subscribe("imager/image")
                break
            except TetherError:
                time.sleep(0.2)
        else:
            pytest.fail("imager/image was never registered")
        try:
            while image is None and launch.poll() is None and time.monotonic() < deadline:
                if sock.poll(500):
                    frames = sock.recv_multipart(copy=False)
                    if frames[0].bytes == b"imager/image":
                        image = Codec().decode(FanImage, frames[1:])
        finally:
            sock.close(linger=0)
    finally:
        launch.send_signal(signal.SIGINT)
        out, _ = launch.communicate(timeout=60)
    assert launch.returncode == 0, out
    assert isinstance(image, FanImage) and np.asarray(image.image).size > 0, out
    refined = re.search(r"refiner: (\d+) pings refined, (\d+) dropped", out)
    assert refined and int(refined.group(1)) >= 1 and int(refined.group(2)) == 0, out
    assert "Traceback" not in out
