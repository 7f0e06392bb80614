"""Geometry messages: poses, twists, paths, transforms. SI units, angles in radians."""
from __future__ import annotations

import numpy as np

from tether.message import Message, const


class Point3(Message, tag="geometry.Point3"):
    x_m: float = 0.0
    y_m: float = 0.0
    z_m: float = 0.0


class Pose2D(Message, tag="geometry.Pose2D"):
    """Planar pose: position and heading (yaw, counter-clockwise from +x)."""

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0


class Pose3D(Message, tag="geometry.Pose3D"):
    """Pose in 3D: position and unit quaternion (w, x, y, z), Hamilton convention."""

    x_m: float = 0.0
    y_m: float = 0.0
    z_m: float = 0.0
    qw: float = 1.0
    qx: float = 0.0
    qy: float = 0.0
    qz: float = 0.0

    def matrix(self) -> np.ndarray:
        """4x4 homogeneous transform (child -> frame_id)."""
        w, x, y, z = self.qw, self.qx, self.qy, self.qz
        n = w * w + x * x + y * y + z * z
        s = 2.0 / n if n > 0 else 0.0
        rot = np.array([[1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
                        [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
                        [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)]])
        out = np.eye(4)
        out[:3, :3] = rot
        out[:3, 3] = (self.x_m, self.y_m, self.z_m)
        return out

    @classmethod
    def from_matrix(cls, transform: np.ndarray, **header: object) -> "Pose3D":
        """From a 4x4 homogeneous transform (rotation part must be orthonormal)."""
        r = np.asarray(transform, dtype=float)[:3, :3]
        t = np.asarray(transform, dtype=float)[:3, 3]
        # Shepperd's method: pick the largest diagonal term so the division is well conditioned.
        tr = np.trace(r)
        k = int(np.argmax([tr, r[0, 0], r[1, 1], r[2, 2]]))
        if k == 0:
            s = np.sqrt(1.0 + tr) * 2
            q = (0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s)
        elif k == 1:
            s = np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
            q = ((r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s)
        elif k == 2:
            s = np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
            q = ((r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s)
        else:
            s = np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
            q = ((r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s)
        w, x, y, z = (float(v) for v in q)
        if w < 0:
            w, x, y, z = -w, -x, -y, -z
        return cls(x_m=float(t[0]), y_m=float(t[1]), z_m=float(t[2]), qw=w, qx=x, qy=y, qz=z, **header)  # type: ignore[arg-type]


class PoseWithCovariance(Message, tag="geometry.PoseWithCovariance"):
    """3D pose with a 6x6 covariance over (x, y, z, roll, pitch, yaw) in the pose's frame."""

    pose: Pose3D = Pose3D()
    covariance: np.ndarray = const(np.zeros((6, 6)))


class Twist2D(Message, tag="geometry.Twist2D"):
    """Planar velocity in the body frame."""

    vx_mps: float = 0.0
    vy_mps: float = 0.0
    wz_radps: float = 0.0


class Odometry2D(Message, tag="geometry.Odometry2D"):
    """Planar pose plus body-frame velocity."""

    pose: Pose2D = Pose2D()
    twist: Twist2D = Twist2D()


class Path2D(Message, tag="geometry.Path2D"):
    """A planar path: N x 3 array of (x_m, y_m, yaw_rad) and optional per-point times (s)."""

    poses: np.ndarray = const(np.zeros((0, 3)))
    t_s: np.ndarray = const(np.zeros(0))


class Transform(Message, tag="geometry.Transform"):
    """A rigid transform from ``child_frame_id`` to ``frame_id`` (4x4 homogeneous)."""

    child_frame_id: str = ""
    matrix: np.ndarray = const(np.eye(4))
