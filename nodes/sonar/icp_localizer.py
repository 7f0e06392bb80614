"""ICP localizer node: accumulated sonar cloud -> pose correction against the structure's known model."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

import msgspec
import numpy as np
import yaml

from msgs.geometry import Pose3D
from msgs.sensor import PointCloud
from msgs.sonar import IcpResult
from nodes.sonar.icp import IcpModel, IcpSettings, align
from nodes.sonar.model import load_mesh, sample_mesh, sample_seabed, sample_structures, tripod_model
from tether import Input, Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    # "tripod" (the paper's, with its two pylons), "tripod_symmetric" (without them), a .ply/.obj
    # mesh, or a scene .yaml whose `structures` list is sampled (sim/scenes/fls_*.yaml format)
    model: str = "tripod"
    spacing_m: float = 0.1                  # model surface sample spacing
    seabed_z_m: float = -6.0
    seabed_radius_m: float = 0.0            # > 0: add a seabed disc (when the cloud keeps seafloor points)
    grid_m: float = 0.1                     # nearest-point grid voxel; 0: KD-tree only
    method: Literal["point_to_plane", "point_to_point"] = "point_to_plane"
    kernel: Literal["huber", "cauchy", "none"] = "huber"
    kernel_scale_m: float = 0.2
    max_correspondence_m: float = 1.5
    min_correspondence_m: float = 0.3
    max_iterations: int = 30
    max_points: int = 800
    degeneracy_threshold: float = 0.02
    yaw_hypotheses: int = 6
    prior_window_deg: float = 90.0
    min_points: int = 50                    # smaller clouds are not aligned (result says converged=False)
    track: bool = True                      # start from the last trusted correction
    model_frame: str = "world"

    def __post_init__(self) -> None:
        if self.spacing_m <= 0 or self.grid_m < 0 or self.min_points < 6:
            raise ValueError("need spacing_m > 0, grid_m >= 0 and min_points >= 6")
        IcpSettings(**_settings_kwargs(self))           # raises ValueError on inconsistent tuning


def _settings_kwargs(cfg: Config) -> dict:
    return dict(method=cfg.method, kernel=cfg.kernel, kernel_scale_m=cfg.kernel_scale_m,
                max_correspondence_m=cfg.max_correspondence_m, min_correspondence_m=cfg.min_correspondence_m,
                max_iterations=cfg.max_iterations, max_points=cfg.max_points,
                degeneracy_threshold=cfg.degeneracy_threshold, yaw_hypotheses=cfg.yaw_hypotheses,
                prior_window_rad=math.radians(cfg.prior_window_deg), min_inliers=min(12, cfg.min_points))


def load_model(cfg: Config) -> tuple[np.ndarray, np.ndarray]:
    """Surface samples (points, normals) of the configured model."""
    if cfg.model in ("tripod", "tripod_symmetric"):
        return tripod_model(pylons=cfg.model == "tripod", spacing_m=cfg.spacing_m,
                            seabed_radius_m=cfg.seabed_radius_m, seabed_z_m=cfg.seabed_z_m)
    path = Path(cfg.model)
    if not path.is_file():
        raise ValueError(f"model {cfg.model!r}: not 'tripod', 'tripod_symmetric' or an existing .ply/.obj/.yaml file")
    if path.suffix.lower() in (".yaml", ".yml"):
        scene = yaml.safe_load(path.read_text()) or {}
        pts, nrm = sample_structures(scene.get("structures", []), cfg.spacing_m, base=path.parent)
    else:
        pts, nrm = sample_mesh(*load_mesh(path), cfg.spacing_m)
    if cfg.seabed_radius_m > 0:
        sp, sn = sample_seabed(cfg.seabed_z_m, tuple(pts[:, :2].mean(axis=0)), cfg.seabed_radius_m,
                               max(cfg.spacing_m, 0.25))
        pts, nrm = np.concatenate([pts, sp]), np.concatenate([nrm, sn])
    return pts, nrm


class IcpLocalizer(Node):
    """Input ``cloud`` (world frame, latest only); output ``correction`` (cloud -> model frame)."""

    Config = Config
    inputs = {"cloud": Input(PointCloud, latest=True)}
    outputs = {"correction": IcpResult}

    def setup(self) -> None:
        self._model = IcpModel.build(*load_model(self.config), grid_m=self.config.grid_m)
        self._settings = IcpSettings(**_settings_kwargs(self.config))
        self._last = np.eye(4)
        self.runs = 0
        self.flags = {"degenerate": 0, "ambiguous": 0, "failed": 0}
        self._warned: set[str] = set()

    def on_cloud(self, cloud: PointCloud) -> dict[str, IcpResult]:
        pts = np.asarray(cloud.points_m, float).reshape(-1, 3) if np.size(cloud.points_m) else np.zeros((0, 3))
        n_finite = int(np.all(np.isfinite(pts), axis=1).sum())
        if n_finite < self.config.min_points:
            self._count("failed", f"cloud has {n_finite} finite points, need >= {self.config.min_points}")
            return {"correction": IcpResult(stamp_ns=cloud.stamp_ns, frame_id=self.config.model_frame,
                                            correction=Pose3D.from_matrix(self._last), cloud_size=n_finite)}
        out = align(pts, self._model, self._last if self.config.track else None, self._settings)
        self.runs += 1
        if out.reason:
            self._count("failed", out.reason)
        if out.degenerate:
            self._count("degenerate", "degenerate geometry: some directions are not observable and were held "
                                      "at the prior (see covariance)")
        if out.ambiguous:
            self._count("ambiguous", "ambiguous fit: a distinct pose near the prior fits as well (symmetry)")
        if out.converged and not out.ambiguous and self.config.track:
            self._last = out.transform
        return {"correction": IcpResult(
            stamp_ns=cloud.stamp_ns, frame_id=self.config.model_frame,
            correction=Pose3D.from_matrix(out.transform, frame_id=self.config.model_frame),
            covariance=out.covariance, converged=out.converged, degenerate=out.degenerate,
            ambiguous=out.ambiguous, min_eigenvalue=out.min_eigenvalue, rmse_m=out.rmse_m,
            inlier_ratio=out.inlier_ratio, iterations=out.iterations, cloud_size=out.cloud_size)}

    def teardown(self) -> None:
        self.log.info("icp localizer: %d alignments, flags %s", self.runs, self.flags)

    def _count(self, flag: str, message: str) -> None:
        self.flags[flag] += 1
        if message not in self._warned:
            self._warned.add(message)
            self.log.warning(message)
