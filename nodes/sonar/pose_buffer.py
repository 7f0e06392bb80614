"""A time-ordered buffer of 4x4 poses that answers "where was the sensor at this stamp".

The pose at a stamp is interpolated between the two buffered poses around it: linear in
position, spherical-linear (slerp) in rotation. A stamp newer than the newest pose is not
answered from an old pose: the caller is told to wait for the next one. A stamp between two
poses further apart than ``max_gap_ns`` (a pose stream that paused) is not answered either.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

Status = Literal["exact", "interpolated", "wait", "before_first", "gap"]


def slerp_pose(a: np.ndarray, b: np.ndarray, u: float) -> np.ndarray:
    """Pose a fraction ``u`` (0..1) of the way from 4x4 ``a`` to 4x4 ``b`` (lerp position, slerp rotation)."""
    out = np.eye(4)
    out[:3, 3] = (1.0 - u) * a[:3, 3] + u * b[:3, 3]
    ra = Rotation.from_matrix(a[:3, :3])
    delta = (ra.inv() * Rotation.from_matrix(b[:3, :3])).as_rotvec()    # shortest arc from a to b
    out[:3, :3] = (ra * Rotation.from_rotvec(u * delta)).as_matrix()
    return out


@dataclass
class PoseBuffer:
    """Poses (4x4, sensor -> world) by stamp; keeps ``span_ns`` behind the newest, at most ``max_poses``."""

    span_ns: int = 5_000_000_000
    max_poses: int = 4096
    _stamps: list[int] = field(default_factory=list)
    _poses: list[np.ndarray] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self._stamps)

    @property
    def newest_ns(self) -> int | None:
        return self._stamps[-1] if self._stamps else None

    def add(self, stamp_ns: int, transform: np.ndarray) -> None:
        """Insert in stamp order (a pose at an existing stamp replaces it); forget what is too old."""
        i = bisect.bisect_left(self._stamps, stamp_ns)
        if i < len(self._stamps) and self._stamps[i] == stamp_ns:
            self._poses[i] = transform
        else:
            self._stamps.insert(i, stamp_ns)
            self._poses.insert(i, transform)
        cut = bisect.bisect_left(self._stamps, self._stamps[-1] - self.span_ns)
        cut = max(cut, len(self._stamps) - self.max_poses)
        if cut > 0:
            del self._stamps[:cut], self._poses[:cut]

    def at(self, stamp_ns: int, max_gap_ns: int) -> tuple[np.ndarray | None, Status, int]:
        """``(pose, status, bracket_ns)`` at ``stamp_ns``.

        ``status`` is ``"exact"`` (a pose at that very stamp), ``"interpolated"`` (between two poses at
        most ``max_gap_ns`` apart; ``bracket_ns`` is their distance), ``"wait"`` (newer than the newest
        pose, or nothing buffered yet: the pose for it may still come), ``"before_first"`` (older than
        the oldest buffered pose) or ``"gap"`` (the poses around it are too far apart). The pose is
        None unless the status is exact or interpolated.
        """
        if not self._stamps or stamp_ns > self._stamps[-1]:
            return None, "wait", 0
        i = bisect.bisect_left(self._stamps, stamp_ns)
        if self._stamps[i] == stamp_ns:
            return self._poses[i], "exact", 0
        if i == 0:
            return None, "before_first", 0
        t0, t1 = self._stamps[i - 1], self._stamps[i]
        if t1 - t0 > max_gap_ns:
            return None, "gap", t1 - t0
        return slerp_pose(self._poses[i - 1], self._poses[i], (stamp_ns - t0) / (t1 - t0)), "interpolated", t1 - t0
