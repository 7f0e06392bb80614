"""Geometry messages: poses, twists, paths, transforms. SI units, angles in radians."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

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
        """4x4 homogeneous transform (child -> frame_id); a non-unit quaternion is normalised,
        a zero one reads as no rotation."""
        out = np.eye(4)
        q = np.array([self.qx, self.qy, self.qz, self.qw], dtype=float)       # scipy: scalar last
        if np.all(np.isfinite(q)) and float(q @ q) > 0:
            out[:3, :3] = Rotation.from_quat(q).as_matrix()
        out[:3, 3] = (self.x_m, self.y_m, self.z_m)
        return out

    @classmethod
    def from_matrix(cls, transform: np.ndarray, **header: object) -> "Pose3D":
        """From a 4x4 homogeneous transform (a rotation part that is not orthonormal is
        replaced by the nearest rotation); the quaternion is returned with w >= 0."""
        m = np.asarray(transform, dtype=float)
        x, y, z, w = Rotation.from_matrix(m[:3, :3]).as_quat()
        if w < 0:
            w, x, y, z = -w, -x, -y, -z
        t = m[:3, 3]
        return cls(x_m=float(t[0]), y_m=float(t[1]), z_m=float(t[2]), qw=float(w), qx=float(x), qy=float(y),
                   qz=float(z), **header)  # type: ignore[arg-type]


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
