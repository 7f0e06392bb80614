"""Labelled-for-free training pings for a sonar refiner: the FLS simulator over random seabeds.

A refiner learns to make simulated pings look like real ones (seed 04's SimGAN applied to the
forward-looking sonar of seed 01). The real pings it is judged against are the Oculus M1200d's in
../shared/data/sonar: 2 m range, 2.1 MHz, 256 beams over +-30 deg, 703 ranges, gain 50 %, a
sediment seabed seen from about half a metre. This module renders pings with that *geometry*
(range, beams, ranges, aperture) over random scenes of the same kind -- a textured seabed
0.4-0.7 m below the head, tilt 28-45 deg, a few cylinders and boxes lying on it -- and leaves
the simulator's image model (speckle, noise floor, beam pattern) as it is: that is the gap the
refiner has to close, not something to tune away here.

One setting is not geometry: at the real ping's gain of 50 % the simulator's level scale
(chosen for 20 m scenes) saturates a close seabed outright. :func:`unsaturated_gain` picks the
gain from simulated pings alone (the highest gain that keeps at most 1 % of pixels at full
scale), never from the real ones.

>>> pings = render_training_pings(64, seed=0)                  # (64, 703, 256) uint8
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from sim.fls_render import PingSettings, render_ping
from sim.fls_scene import load_scene, sonar_frame


@dataclass(frozen=True)
class CloseRangeSetup:
    """The real M1200d ping's geometry and the spread of scenes drawn around it."""

    n_beams: int = 256
    n_ranges: int = 703
    range_m: float = 2.0
    aperture_deg: float = 60.0                 # the real table: -30..+30 deg (the simulator's 'high' says 80)
    altitude_m: tuple[float, float] = (0.4, 0.7)
    tilt_deg: tuple[float, float] = (28.0, 45.0)
    objects: tuple[int, int] = (0, 3)          # cylinders / boxes lying on the seabed, inclusive
    elevation_rays: int = 160
    gamma: float = 0.5


def random_scene(rng: np.random.Generator, setup: CloseRangeSetup = CloseRangeSetup()) -> tuple[Any, np.ndarray]:
    """A scene dict's :class:`~sim.fls_scene.Scene` and the 4x4 sonar pose seeing it."""
    altitude = rng.uniform(*setup.altitude_m)
    tilt = rng.uniform(*setup.tilt_deg)
    yaw = rng.uniform(-np.pi, np.pi)
    floor_z = -1.0 - altitude
    structures = []
    for _ in range(int(rng.integers(setup.objects[0], setup.objects[1] + 1))):
        # placed in the footprint: 0.5-1.8 m ahead of the head, within +-30 deg
        r, b = rng.uniform(0.5, 1.8), rng.uniform(-0.5, 0.5)
        cx, cy = r * np.cos(yaw + b), r * np.sin(yaw + b)
        if rng.random() < 0.5:
            half = rng.uniform(0.1, 0.5)
            ang = rng.uniform(0, np.pi)
            rad = rng.uniform(0.01, 0.06)
            d = half * np.array([np.cos(ang), np.sin(ang), 0.0])
            c = np.array([cx, cy, floor_z + rad])
            structures.append({"type": "cylinder", "from_m": list(c - d), "to_m": list(c + d), "radius_m": rad,
                               "reflectivity": float(rng.uniform(0.5, 0.95))})
        else:
            size = rng.uniform([0.05, 0.05, 0.03], [0.4, 0.3, 0.2])
            structures.append({"type": "box", "center_m": [cx, cy, floor_z + size[2] / 2], "size_m": list(size),
                               "yaw_deg": float(rng.uniform(0, 180)), "reflectivity": float(rng.uniform(0.5, 0.9))})
    scene = load_scene({
        "name": "close-range",
        "seafloor": {"type": "plane", "z_m": floor_z, "reflectivity": float(rng.uniform(0.2, 0.4)),
                     "texture": {"seed": int(rng.integers(1 << 30)), "size_m": [5.0, 5.0], "cell_m": 0.01,
                                 "scales_m": [0.02, 0.08, 0.3]}},
        "structures": structures,
        "sonar": {"tilt_deg": tilt, "frequency": "high", "elevation_rays": setup.elevation_rays,
                  "high": {"horizontal_aperture_deg": setup.aperture_deg}},
    })
    return scene, sonar_frame(np.array([0.0, 0.0, -1.0]), yaw, np.radians(tilt))


def _settings(setup: CloseRangeSetup, gain_percent: float) -> PingSettings:
    return PingSettings(n_beams=setup.n_beams, range_m=setup.range_m, frequency="high", n_ranges=setup.n_ranges,
                        elevation_rays=setup.elevation_rays, gain_percent=gain_percent, gamma=setup.gamma)


def unsaturated_gain(setup: CloseRangeSetup = CloseRangeSetup(), *, seed: int = 12345, n: int = 16,
                     max_saturated: float = 0.01) -> float:
    """The highest gain (percent, 1 % steps) at which at most ``max_saturated`` of simulated pixels clip.

    Decided on ``n`` simulated pings (noise-free levels, so the rule does not depend on speckle
    draws), never on real data.
    """
    rng = np.random.default_rng(seed)
    levels = []
    for _ in range(n):
        scene, pose = random_scene(rng, setup)
        levels.append(render_ping(scene, pose, _settings(setup, 50.0), rng=None).level.ravel())
    level = np.concatenate(levels)
    q = float(np.quantile(level, 1.0 - max_saturated))
    if q <= 0:
        return 100.0
    # out = level * 10^(0.04 (g - 50)) clips at 1: g = 50 - 25 log10(q)
    return float(np.clip(np.floor(50.0 - 25.0 * np.log10(q)), 0.0, 100.0))


def render_training_pings(n: int, *, seed: int, setup: CloseRangeSetup = CloseRangeSetup(),
                          gain_percent: float | None = None, progress: bool = False) -> np.ndarray:
    """``n`` speckled pings (N, n_ranges, n_beams) uint8 from scenes drawn with ``seed``.

    ``gain_percent`` None: :func:`unsaturated_gain` for ``setup``.
    """
    gain = unsaturated_gain(setup) if gain_percent is None else float(gain_percent)
    rng = np.random.default_rng(seed)
    out = np.empty((n, setup.n_ranges, setup.n_beams), np.uint8)
    for i in range(n):
        scene, pose = random_scene(rng, setup)
        out[i] = render_ping(scene, pose, _settings(setup, gain), rng=rng).intensities
        if progress and (i + 1) % max(1, n // 10) == 0:
            print(f"  rendered {i + 1}/{n} pings", flush=True)
    return out


def with_beams(setup: CloseRangeSetup, n_beams: int) -> CloseRangeSetup:
    return replace(setup, n_beams=n_beams)


REAL_PINGS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "sonar" / "oculus-m1200d" / "three_pings_8bit.raw"


def real_oculus_pings(path: str | Path = REAL_PINGS) -> list[np.ndarray]:
    """The real M1200d pings' images (703 x 256 uint8 each); ``FileNotFoundError`` when the data is absent.

    ``three_pings_8bit.raw`` holds three consecutive pings of one static scene (pingId 415323-5;
    ``one_ping_8bit.raw`` repeats the first): three images, nearly alike.
    """
    from drivers.oculus_file import iter_oculus_file

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: the real Oculus pings are not here (../shared/data/sonar)")
    return [np.asarray(p.intensities) for p in iter_oculus_file(path)]
