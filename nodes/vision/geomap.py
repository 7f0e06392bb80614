"""Geo-referenced map images: a map image with its affine from pixels to local east-north
metres, a procedural map for tests, and the real Brighton Beach ortho render georeferenced by
its own frames' GPS (../shared/data/uav; BSD-2-Clause, (c) 2017 Piero Toffanin)."""
from __future__ import annotations

import csv
import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "uav" / "brighton_beach"
CACHE = Path(__file__).resolve().parents[2] / "out" / "cache" / "brighton_georeference.json"
MAPS = ("procedural", "brighton")
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GeoMap:
    """A map image and its affine G: [e, n] = G @ [u, v, 1]."""

    image: np.ndarray
    G: np.ndarray

    @property
    def m_per_px(self) -> float:
        return float(math.sqrt(abs(np.linalg.det(self.G[:, :2]))))

    def to_world(self, uv: np.ndarray) -> np.ndarray:
        uv = np.atleast_2d(uv)
        return uv @ self.G[:, :2].T + self.G[:, 2]

    def to_px(self, en: np.ndarray) -> np.ndarray:
        en = np.atleast_2d(en)
        return (en - self.G[:, 2]) @ np.linalg.inv(self.G[:, :2]).T

    def world_bounds(self) -> np.ndarray:
        """(2, 2) [[e_min, n_min], [e_max, n_max]] of the image's corners."""
        h, w = self.image.shape[:2]
        c = self.to_world(np.array([[0, 0], [w, 0], [w, h], [0, h]], float))
        return np.array([c.min(axis=0), c.max(axis=0)])


def procedural_map(*, rng: np.random.Generator, size_px: int = 1600, m_per_px: float = 0.12) -> GeoMap:
    """A textured field for tests that must not depend on real data: patches, roads, blobs,
    north up, centred on (0, 0)."""
    img = np.zeros((size_px, size_px, 3), np.float32)
    for cells, amp in ((6, 50), (24, 30), (96, 18)):
        g = rng.normal(0, amp, (cells, cells, 3)).astype(np.float32)
        img += cv2.resize(g, (size_px, size_px), interpolation=cv2.INTER_CUBIC)
    img += np.array([70, 120, 90], np.float32)
    for _ in range(40):                                        # roads
        p = rng.integers(0, size_px, 4)
        cv2.line(img, (int(p[0]), int(p[1])), (int(p[2]), int(p[3])), (150, 150, 150), int(rng.integers(6, 20)))
    for _ in range(600):                                       # trees, cars, roofs
        c = tuple(int(v) for v in rng.integers(0, size_px, 2))
        col = tuple(float(v) for v in rng.uniform(20, 230, 3))
        if rng.random() < 0.6:
            cv2.circle(img, c, int(rng.integers(4, 20)), col, -1)
        else:
            d = rng.integers(6, 30, 2)
            cv2.rectangle(img, c, (c[0] + int(d[0]), c[1] + int(d[1])), col, -1)
    img = np.clip(img, 0, 255).astype(np.uint8)
    h = size_px / 2 * m_per_px
    G = np.array([[m_per_px, 0, -h], [0, -m_per_px, h]])
    return GeoMap(img, G)


def frames_gps(path: Path = DATA / "frames_gps.csv") -> list[dict]:
    with open(path, newline="") as f:
        return [dict(r) for r in csv.DictReader(f)]


def enu_of(lat: np.ndarray, lon: np.ndarray, lat0: float, lon0: float) -> np.ndarray:
    """Local east-north metres (equirectangular; exact to mm over a few hundred metres)."""
    R = 6378137.0
    return np.stack([np.radians(lon - lon0) * R * math.cos(math.radians(lat0)), np.radians(lat - lat0) * R], axis=1)


def fit_similarity(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Least-squares similarity (Umeyama, no reflection) src (N, 2) -> dst (N, 2), as 2x3."""
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - ms, dst - md
    U, S, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / (a ** 2).sum())
    return np.hstack([s * R, (md - s * R @ ms)[:, None]])


def georeference(centres_px: np.ndarray, enu: np.ndarray) -> np.ndarray:
    """G (2x3, map px -> east-north) from frame centres in the map and their GPS positions: a
    similarity once the image's v axis (down) is turned to point north."""
    flip = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0]])
    S = fit_similarity(centres_px * [1, -1], enu)
    return S @ flip


def brighton_frames() -> list[tuple[np.ndarray, dict]]:
    """The 18 real frames (1000x562 BGR) with their GPS row."""
    rows = frames_gps()
    return [(cv2.imread(str(DATA / "frames_1000px" / r["file"])), r) for r in rows]


def register_brighton(method: str = "sift", every: int = 1) -> tuple[np.ndarray, list, list[dict], np.ndarray]:
    """The ortho image, each real frame's registration to it, the GPS rows and their east-north
    positions (metres from the first frame); ``every`` > 1 takes every n-th frame (about 1 s each)."""
    from nodes.vision.georegister import MapFeatures, register

    ortho = cv2.imread(str(DATA / "ortho_render_brighton_beach.jpg"))
    mf = MapFeatures.of(ortho, method=method)
    frames = brighton_frames()[::every]
    rows = [r for _, r in frames]
    lat = np.array([float(r["lat"]) for r in rows])
    lon = np.array([float(r["lon"]) for r in rows])
    enu = enu_of(lat, lon, lat[0], lon[0])
    # the frames are about 0.75 map px per frame px; two pyramid levels cover it (search mode)
    fixes = [register(f, mf, prescale=1.0, pyramid=(0.7, 0.8), alpha_range=(0.5, 2.0)) for f, _ in frames]
    return ortho, fixes, rows, enu


def _data_key() -> list:
    """What the georeference depends on: the data files' names, sizes and times."""
    files = [DATA / "ortho_render_brighton_beach.jpg", DATA / "frames_gps.csv", *sorted((DATA / "frames_1000px").glob("*"))]
    return [[f.name, f.stat().st_size, int(f.stat().st_mtime)] for f in files]


def brighton_map() -> GeoMap:
    """The real ortho render, georeferenced by its own frames' GPS (registration of each frame
    gives its centre in the image; a similarity fits those to the GPS positions).

    Registering the 18 frames takes seconds and every node of a launch that flies over this
    map needs the result, so G is kept in out/cache, keyed by the data files it came from."""
    key = _data_key()
    if CACHE.exists():
        cached = json.loads(CACHE.read_text())
        if cached.get("key") == key:
            return GeoMap(cv2.imread(str(DATA / "ortho_render_brighton_beach.jpg")), np.array(cached["G"]))
    log.info("georeferencing the Brighton ortho render from its 18 frames' GPS (once; cached in %s)", CACHE)
    ortho, fixes, _, enu = register_brighton()
    ok = [k for k, f in enumerate(fixes) if f.ok]
    if len(ok) < 3:
        raise ValueError(f"only {len(ok)} real frames registered to the ortho image: cannot georeference it")
    G = georeference(np.array([fixes[k].centre_px for k in ok]), enu[ok])
    try:
        CACHE.parent.mkdir(parents=True, exist_ok=True)
        CACHE.write_text(json.dumps({"key": key, "G": G.tolist()}))
    except OSError as exc:                       # a read-only checkout still works, only slower
        log.warning("could not cache the georeference: %s", exc)
    return GeoMap(ortho, G)


def load_map(name: str, seed: int = 0) -> GeoMap:
    """A map by name: "procedural" (seeded) or "brighton" (the real one)."""
    if name not in MAPS:
        raise ValueError(f"map must be one of {MAPS}, got {name!r}")
    return brighton_map() if name == "brighton" else procedural_map(rng=np.random.default_rng(seed))
