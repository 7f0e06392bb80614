"""Load real pedestrian tracks (ETH / UCY, Social-GAN text format) and sample them at any time.

The files live in ``../shared/data/pedestrians/eth_ucy_sgan_format/<name>.txt`` (read at
runtime, never copied into the repository): tab-separated ``frame ped_id x y`` in metres,
one row per pedestrian per annotated frame, annotated every 10 video frames. The time
between two annotated frames is 0.4 s for every set EXCEPT ``biwi_eth``, where it is
10/15 s = 0.667 s (see SOURCES.md: using 0.4 s there gives a false median speed of
2.45 m/s instead of 1.47 m/s).

>>> tracks = load_tracks("students003")
>>> ids, xy, vel = tracks.state_at(12.0)       # pedestrians alive at t = 12 s
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: seconds between two annotated rows (10 video frames) per data set
ROW_PERIOD_S: dict[str, float] = {
    "biwi_eth": 10.0 / 15.0,
    "biwi_hotel": 0.4,
    "crowds_zara03": 0.4,
    "students003": 0.4,
    "uni_examples": 0.4,
}
_FRAMES_PER_ROW = 10.0
GAP_ROWS = 2.5          # a walker unseen for longer than this many rows is out of sight, not walking a straight line


def default_root() -> Path:
    """``$TETHER_SHARED_DATA/pedestrians`` or ``<repo>/../shared/data/pedestrians`` (read at call time)."""
    base = os.environ.get("TETHER_SHARED_DATA")
    if base:
        return Path(base) / "pedestrians"
    return Path(__file__).resolve().parents[2] / "shared" / "data" / "pedestrians"


@dataclass(frozen=True)
class Tracks:
    """Per-pedestrian tracks of one data set.

    Attributes
    ----------
    name : str
        Data set name, e.g. ``"biwi_eth"``.
    ids : ndarray, shape (P,), int64
        Pedestrian ids, sorted.
    t_s : tuple of ndarray, each shape (n_i,)
        Sample times of pedestrian ``i`` in seconds from the first row of the file, increasing.
    xy_m : tuple of ndarray, each shape (n_i, 2)
        Positions in metres, world frame of the data set.
    row_period_s : float
        Seconds between consecutive annotated rows.
    max_gap_s : float
        Longest time between two samples of one walker that is still bridged; a longer gap is a
        walker out of sight (absent in :meth:`state_at`, cut in :meth:`segments`). Files read by
        :func:`parse_tracks` bridge 2.5 rows (annotators skip a row now and then); tracks built
        by hand bridge everything unless told.
    """

    name: str
    ids: np.ndarray
    t_s: tuple[np.ndarray, ...]
    xy_m: tuple[np.ndarray, ...]
    row_period_s: float
    max_gap_s: float = float("inf")

    def __post_init__(self) -> None:
        first = np.array([t[0] for t in self.t_s]) if self.t_s else np.zeros(0)
        last = np.array([t[-1] for t in self.t_s]) if self.t_s else np.zeros(0)
        object.__setattr__(self, "_first_s", first)
        object.__setattr__(self, "_last_s", last)

    @property
    def duration_s(self) -> float:
        """Time of the last sample (s)."""
        return max((float(t[-1]) for t in self.t_s), default=0.0)

    def segments(self, i: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """Track ``i`` cut at its gaps (longer than :attr:`max_gap_s`): [(t (n,), xy (n, 2)), ...]."""
        t, xy = self.t_s[i], self.xy_m[i]
        cuts = np.flatnonzero(np.diff(t) > self.max_gap_s + 1e-9) + 1
        return [(a, b) for a, b in zip(np.split(t, cuts), np.split(xy, cuts))]

    def state_at(self, t_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pedestrians present at ``t_s``: ids (M,), positions (M, 2) m, velocities (M, 2) m/s.

        Positions are linearly interpolated between the two samples around ``t_s``; the
        velocity is that segment's finite difference. A pedestrian is present from its
        first to its last sample (inclusive), except inside a gap between two samples longer
        than :attr:`max_gap_s`: nobody knows where they walked then, and interpolating would
        slide them through the crowd on a straight line they never took.
        """
        ids, pos, vel = [], [], []
        for i in np.flatnonzero((self._first_s <= t_s) & (t_s <= self._last_s)):  # type: ignore[attr-defined]
            pid, t, xy = self.ids[i], self.t_s[i], self.xy_m[i]
            if len(t) == 1:
                ids.append(pid), pos.append(xy[0]), vel.append(np.zeros(2))
                continue
            k = int(np.clip(np.searchsorted(t, t_s, side="right") - 1, 0, len(t) - 2))
            seg_dt = t[k + 1] - t[k]
            if seg_dt > self.max_gap_s + 1e-9 and t[k] < t_s < t[k + 1]:
                continue                                   # out of sight (a gap in the track)
            a = (t_s - t[k]) / seg_dt
            ids.append(pid)
            pos.append(xy[k] + a * (xy[k + 1] - xy[k]))
            vel.append((xy[k + 1] - xy[k]) / seg_dt)
        if not ids:
            return np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2))
        return np.asarray(ids, np.int64), np.asarray(pos, float), np.asarray(vel, float)

    def speeds_mps(self) -> np.ndarray:
        """Every finite-difference speed of every track (m/s), concatenated."""
        parts = [np.linalg.norm(np.diff(xy, axis=0), axis=1) / np.diff(t) for t, xy in zip(self.t_s, self.xy_m)
                 if len(t) > 1]
        return np.concatenate(parts) if parts else np.zeros(0)


def parse_tracks(table: np.ndarray, *, name: str, row_period_s: float) -> Tracks:
    """Build :class:`Tracks` from an (R, 4) array of ``frame ped_id x y`` rows.

    Frame numbers are converted with ``row_period_s / 10`` seconds per video frame and
    shifted so the first frame is t = 0.
    """
    table = np.asarray(table, dtype=float)
    if table.ndim != 2 or table.shape[1] != 4:
        raise ValueError(f"expected rows of 'frame ped_id x y' (R x 4), got shape {table.shape}")
    if not np.all(np.isfinite(table)):
        raise ValueError(f"{name}: the track table has non-finite entries; fix or drop those rows")
    if len(table) == 0:
        return Tracks(name, np.zeros(0, np.int64), (), (), row_period_s, GAP_ROWS * row_period_s)
    t_all = (table[:, 0] - table[:, 0].min()) * (row_period_s / _FRAMES_PER_ROW)
    pid_all = table[:, 1].astype(np.int64)
    order = np.lexsort((t_all, pid_all))
    pid_all, t_all, xy_all = pid_all[order], t_all[order], table[order, 2:4]
    ids, starts = np.unique(pid_all, return_index=True)
    bounds = list(starts[1:]) + [len(pid_all)]
    t_s, xy_m = [], []
    for lo, hi in zip(starts, bounds):
        t, keep = np.unique(t_all[lo:hi], return_index=True)   # drop duplicated frames of one pedestrian
        t_s.append(t)
        xy_m.append(xy_all[lo:hi][keep])
    return Tracks(name, ids, tuple(t_s), tuple(xy_m), row_period_s, GAP_ROWS * row_period_s)


def load_tracks(name: str, root: str | Path | None = None) -> Tracks:
    """Read ``eth_ucy_sgan_format/<name>.txt`` under ``root`` (default :func:`default_root`).

    Raises ``ValueError`` for an unknown set and ``FileNotFoundError`` when the data is absent.
    """
    if name not in ROW_PERIOD_S:
        raise ValueError(f"unknown pedestrian data set {name!r}; choose one of {sorted(ROW_PERIOD_S)}")
    path = Path(root if root is not None else default_root()) / "eth_ucy_sgan_format" / f"{name}.txt"
    if not path.is_file():
        raise FileNotFoundError(f"pedestrian tracks not found at {path} (set TETHER_SHARED_DATA or pass root=)")
    table = np.loadtxt(path, dtype=float, ndmin=2)
    return parse_tracks(table, name=name, row_period_s=ROW_PERIOD_S[name])
