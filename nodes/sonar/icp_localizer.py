"""ICP localizer node: sonar returns -> pose correction against the structure's known model.

Two sources (``source``):

* ``"cloud"``: the accumulated world cloud of ``HighlightCloud`` (``points``), every point on the
  lower aperture edge (eq. 13). Simple, but the elevation guess distorts it (a pylon's first
  return comes from the upper edge: placed too deep and too close).
* ``"arcs"``: each line scan (``HighlightCloud`` output ``scan``, sonar frame) with the sonar pose
  it was taken at (the same navigation pose the cloud uses) becomes elevation arcs
  (:mod:`nodes.sonar.arcs`); ICP registers the arcs, so no elevation is guessed. A sliding window
  (``window_s``) keeps the arcs whose navigation drift is close to the current one.

The model's own yaw symmetries are found when it is loaded (:mod:`nodes.sonar.symmetry`, logged);
each alignment searches the whole circle of yaw and, where distinct poses fit about as well, says
"ambiguous" and lists them with their costs (``hypotheses``) instead of choosing. A correction that
is otherwise trusted must also pass a Mahalanobis gate against the navigation prior
(``gate_sigma_m``, ``gate_sigma_yaw_deg`` at ``gate_confidence``, :mod:`nodes.sonar.icp_gate`); one
that fails it is published with ``gated`` and ``ambiguous`` set, and counted.

``dof`` restricts the correction: ``xy_yaw`` (default) for a vehicle whose depth sensor and AHRS
give z, roll and pitch; the held directions have zero variance in the 6x6 covariance.
"""
from __future__ import annotations

import math
import time
from collections import deque
from pathlib import Path
from typing import Literal

import msgspec
import numpy as np

from msgs.geometry import Pose3D
from msgs.sensor import PointCloud
from msgs.sonar import IcpResult
from nodes.sonar.arcs import arcs_from_scan
from nodes.sonar.icp import IcpModel, IcpSettings, align
from nodes.sonar.icp_gate import gate_threshold, mahalanobis_to_prior
from nodes.sonar.model import load_mesh, sample_mesh, sample_seabed, sample_structures, tripod_model
from tether import Input, Node
from tether.yamlsafe import load_yaml_file


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    # "tripod" (the paper's, with its two pylons), "tripod_symmetric" (without them), a .ply/.obj
    # mesh, or a scene .yaml whose `structures` list is sampled (sim/scenes/fls_*.yaml format)
    model: str = "tripod"
    source: Literal["cloud", "arcs"] = "cloud"
    dof: Literal["xy_yaw", "xyz_yaw", "all"] = "xy_yaw"
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
    max_points: int = 800                   # points (or arcs) ICP samples from the cloud
    degeneracy_threshold: float = 0.02
    yaw_hypotheses: int = 8                 # restarts over the whole circle (plus the model's twins)
    prior_window_deg: float = 180.0         # only corrections this close to the prior's yaw can be chosen
    symmetry: bool = True                   # find the model's yaw twins when it is loaded
    gate_sigma_m: float = 2.0               # navigation prior: position (at the structure) ...
    gate_sigma_yaw_deg: float = 15.0        # ... and heading standard deviations
    gate_confidence: float = 0.99           # a trusted correction lies inside this chi-square quantile
    max_rmse_m: float = 0.08                # a fit with a larger residual RMS is not trusted (0: no limit)
    min_points: int = 50                    # fewer points (arcs) are not aligned: the result says converged=False
    track: bool = True                      # start from the last trusted correction
    recheck_every: int = 4                  # while tracking a checked pose, yaw restarts every n-th alignment only
    model_frame: str = "world"
    # source "arcs"
    arc_samples: int = 11                   # elevations per arc
    spread_deg: float = 0.0                 # vertical aperture; 0: read it from the scan points (beam model)
    window_s: float = 10.0                  # keep arcs this recent (0: all, up to max_arcs)
    max_arcs: int = 30_000
    align_every: int = 5                    # scans between alignments
    max_pose_age_s: float = 0.5             # scan without a pose this close in time: dropped

    def __post_init__(self) -> None:
        if self.spacing_m <= 0 or self.grid_m < 0 or self.min_points < 6:
            raise ValueError("need spacing_m > 0, grid_m >= 0 and min_points >= 6")
        if self.recheck_every < 1 or self.arc_samples < 1 or self.align_every < 1 or self.window_s < 0 or self.max_arcs < self.min_points:
            raise ValueError("need arc_samples >= 1, align_every >= 1, window_s >= 0 and max_arcs >= min_points")
        IcpSettings(**_settings_kwargs(self))           # raises ValueError on inconsistent tuning
        if not (self.gate_sigma_m > 0 and self.gate_sigma_yaw_deg > 0 and 0 < self.gate_confidence < 1):
            raise ValueError("need gate_sigma_m > 0, gate_sigma_yaw_deg > 0 and 0 < gate_confidence < 1")


def _settings_kwargs(cfg: Config) -> dict:
    return dict(method=cfg.method, dof=cfg.dof, kernel=cfg.kernel, kernel_scale_m=cfg.kernel_scale_m,
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
        scene = load_yaml_file(path) or {}
        floor = (scene.get("seafloor") or {}).get("z_m")
        pts, nrm = sample_structures(scene.get("structures", []), cfg.spacing_m, base=path.parent,
                                     seabed_z_m=None if floor is None else float(floor))
    else:
        pts, nrm = sample_mesh(*load_mesh(path), cfg.spacing_m)
    if cfg.seabed_radius_m > 0:
        sp, sn = sample_seabed(cfg.seabed_z_m, tuple(pts[:, :2].mean(axis=0)), cfg.seabed_radius_m,
                               max(cfg.spacing_m, 0.25))
        pts, nrm = np.concatenate([pts, sp]), np.concatenate([nrm, sn])
    return pts, nrm


def _hypothesis_rows(hypotheses: list[tuple[float, np.ndarray]]) -> np.ndarray:
    """(H, 4) rows (x_m, y_m, yaw_rad, cost) of the near-equal corrections, best first."""
    rows = [(t[0, 3], t[1, 3], math.atan2(t[1, 0], t[0, 0]), score) for score, t in hypotheses]
    return np.array(rows, np.float64).reshape(-1, 4)


def _moved(a: np.ndarray, b: np.ndarray, pivot: np.ndarray, cfg: IcpSettings) -> bool:
    """Whether two corrections differ by a distinct pose (yaw or displacement at ``pivot``)."""
    dyaw = abs(math.remainder(math.atan2(a[1, 0], a[0, 0]) - math.atan2(b[1, 0], b[0, 0]), 2 * math.pi))
    moved = float(np.linalg.norm((a[:3, :3] - b[:3, :3]) @ pivot + a[:3, 3] - b[:3, 3]))
    return dyaw > cfg.distinct_yaw_rad or moved > cfg.distinct_m


class IcpLocalizer(Node):
    """Inputs ``cloud`` (source cloud) or ``scan`` + ``pose`` (source arcs); output ``correction``.

    The correction maps the navigation world frame onto the model frame (apply it to the
    navigation pose). Flags counted in ``flags``: ``waiting`` (too little data to try: before the
    structure enters the near field), ``failed`` (tried, no fit), ``degenerate``, ``ambiguous``.
    """

    Config = Config
    outputs = {"correction": IcpResult}

    @classmethod
    def ports_for(cls, config: Config):
        if config.source == "arcs":
            inputs = {"scan": Input(PointCloud, depth=128), "pose": Input(Pose3D, depth=128)}
        else:
            inputs = {"cloud": Input(PointCloud, latest=True)}
        return inputs, cls.outputs, cls.timers

    def setup(self) -> None:
        self._model = IcpModel.build(*load_model(self.config), grid_m=self.config.grid_m,
                                     symmetry=self.config.symmetry)
        if self._model.symmetry is not None:
            self.log.info("model %s: %s", self.config.model, self._model.symmetry.describe())
        self._gate = gate_threshold(self.config.gate_confidence)
        self._settings = IcpSettings(**_settings_kwargs(self.config))
        self._tracking = IcpSettings(**{**_settings_kwargs(self.config), "yaw_hypotheses": 0})
        self._last = np.eye(4)
        self._checked = False           # _last passed the yaw-restart ambiguity check
        self._since_check = 0
        self.runs = 0
        self.scans = 0
        self.flags = {"waiting": 0, "failed": 0, "degenerate": 0, "ambiguous": 0, "gated": 0, "poor_fit": 0, "no_pose": 0}
        self._warned: set[str] = set()
        self._poses: deque[tuple[int, np.ndarray]] = deque(maxlen=256)
        self._pending: deque[PointCloud] = deque()
        self._arcs: deque[tuple[int, np.ndarray]] = deque()
        self._n_arcs = 0
        self._align_ms: list[float] = []
        self._input_age_ms: list[float] = []

    # -- source "cloud" -----------------------------------------------------------------
    def on_cloud(self, cloud: PointCloud) -> dict[str, IcpResult]:
        self._input_age_ms.append((self.now_ns() - cloud.stamp_ns) / 1e6)
        pts = np.asarray(cloud.points_m, float).reshape(-1, 3) if np.size(cloud.points_m) else np.zeros((0, 3))
        return {"correction": self._align(pts, cloud.stamp_ns)}

    # -- source "arcs" ------------------------------------------------------------------
    def on_pose(self, pose: Pose3D) -> list[tuple[str, IcpResult]]:
        transform = pose.matrix()
        if np.all(np.isfinite(transform)) and abs(np.linalg.det(transform[:3, :3]) - 1) < 1e-3:
            self._poses.append((pose.stamp_ns, transform))
        return self._drain()

    def on_scan(self, scan: PointCloud) -> list[tuple[str, IcpResult]]:
        self._input_age_ms.append((self.now_ns() - scan.stamp_ns) / 1e6)
        self._pending.append(scan)
        return self._drain()

    def _drain(self) -> list[tuple[str, IcpResult]]:
        """Turn pending scans into arcs once a pose at or after their stamp is in (or they are too old)."""
        out = []
        newest = self._poses[-1][0] if self._poses else None
        max_age = int(self.config.max_pose_age_s * 1e9)
        while self._pending:
            scan = self._pending[0]
            if newest is None and len(self._pending) > 32:
                self._pending.popleft()
                self._count("no_pose", "dropping a scan: no navigation pose received yet")
                continue
            if newest is None or (newest < scan.stamp_ns and newest - scan.stamp_ns > -max_age
                                  and len(self._pending) <= 32):
                break                                   # its pose may still come
            self._pending.popleft()
            result = self._add_scan(scan)
            if result is not None:
                out.append(("correction", result))
        return out

    def _add_scan(self, scan: PointCloud) -> IcpResult | None:
        cfg = self.config
        stamp, pose = min(reversed(self._poses), key=lambda p: abs(p[0] - scan.stamp_ns))   # newest wins ties
        if abs(stamp - scan.stamp_ns) > cfg.max_pose_age_s * 1e9:
            self._count("no_pose", "dropping a scan: no navigation pose close enough in time to it")
            return None
        pts = np.asarray(scan.points_m, float).reshape(-1, 3) if np.size(scan.points_m) else np.zeros((0, 3))
        arcs = arcs_from_scan(pts, pose, cfg.arc_samples, spread_rad=math.radians(cfg.spread_deg))
        self._arcs.append((scan.stamp_ns, arcs.astype(np.float32)))
        self._n_arcs += len(arcs)
        while self._arcs and (self._n_arcs - len(self._arcs[0][1]) >= cfg.max_arcs or
                              (cfg.window_s > 0 and self._arcs[0][0] < scan.stamp_ns - cfg.window_s * 1e9)):
            self._n_arcs -= len(self._arcs.popleft()[1])
        self.scans += 1
        if self.scans % cfg.align_every:
            return None
        src = np.concatenate([a for _, a in self._arcs]) if self._n_arcs else np.zeros((0, cfg.arc_samples, 3))
        return self._align(src, scan.stamp_ns)

    # -- common ---------------------------------------------------------------------------
    def _align(self, src: np.ndarray, stamp_ns: int) -> IcpResult:
        cfg = self.config
        n_finite = int(np.all(np.isfinite(src.reshape(len(src), -1)), axis=1).sum()) if len(src) else 0
        if n_finite < cfg.min_points:
            self._count("waiting", f"{n_finite} {cfg.source} to align, waiting for >= {cfg.min_points} "
                                   "(the structure has not entered the near field yet)")
            return IcpResult(stamp_ns=stamp_ns, frame_id=cfg.model_frame,
                             correction=Pose3D.from_matrix(self._last, frame_id=cfg.model_frame), cloud_size=n_finite)
        begin = time.perf_counter()
        out = self._solve(src)
        self._align_ms.append((time.perf_counter() - begin) * 1e3)
        self.runs += 1
        if out.reason or not out.converged:
            self._count("failed", out.reason or "ICP did not converge within max_iterations")
        if out.degenerate:
            self._count("degenerate", "degenerate geometry: some directions are not observable and were held "
                                      "at the prior (see covariance)")
        if out.ambiguous:
            self._count("ambiguous", "ambiguous fit: distinct poses fit about as well (symmetry); published "
                                     "untrusted, with every near-equal hypothesis and its cost")
        d2, gated, poor = float("nan"), False, False
        if out.converged and not out.degenerate and not out.ambiguous and cfg.max_rmse_m > 0 \
                and not out.rmse_m <= cfg.max_rmse_m:
            # Arcs that fit a good pose lie within a few range cells of the model (2-4 cm here); a fit
            # at 10 cm is the structure half seen, dragged by seabed returns (1.2 m off on a slope).
            poor = True
            self._count("poor_fit", f"fit residual above max_rmse_m ({cfg.max_rmse_m} m): not trusted")
            out.ambiguous = True
        if out.converged and not out.degenerate and np.all(np.isfinite(out.transform)):
            d2 = mahalanobis_to_prior(out.transform, out.covariance, self._model.centroid, sigma_m=cfg.gate_sigma_m,
                                      sigma_yaw_rad=math.radians(cfg.gate_sigma_yaw_deg))
            gated = not out.ambiguous and not d2 <= self._gate
            if gated:
                self._count("gated", f"correction inconsistent with the navigation prior (squared Mahalanobis "
                                     f"distance above {self._gate:.1f}, see prior_mahalanobis2): not trusted")
                out.ambiguous = True
        # Only a trusted result becomes the tracked pose (the next prior and the centre of the
        # ambiguity check's prior window). A degenerate one moved its observable directions on too
        # little structure (a leg or a mat seen alone fits at many yaws): adopting it let a later,
        # well-posed fit of the 3-fold tripod settle 120 deg off and be trusted.
        if out.converged and not out.ambiguous and not out.degenerate and cfg.track:
            self._last = out.transform
        elif cfg.track:
            self._checked = False
        return IcpResult(
            stamp_ns=stamp_ns, frame_id=cfg.model_frame,
            correction=Pose3D.from_matrix(out.transform, frame_id=cfg.model_frame),
            covariance=out.covariance, converged=out.converged, degenerate=out.degenerate,
            ambiguous=out.ambiguous, min_eigenvalue=out.min_eigenvalue, rmse_m=out.rmse_m,
            inlier_ratio=out.inlier_ratio, iterations=out.iterations, cloud_size=out.cloud_size,
            hypotheses=_hypothesis_rows(out.hypotheses), prior_mahalanobis2=d2, gated=gated, poor_fit=poor)

    def _solve(self, src: np.ndarray):
        """Align with the yaw-restart ambiguity check, or (tracking a checked pose) without it.

        Between checks the result is the local optimum next to a pose that was shown unique; it is
        kept only if it stays within ``distinct`` of it (10 deg, 0.5 m), else the full check runs.
        """
        cfg = self.config
        init = self._last if cfg.track else None
        if cfg.track and self._checked and self._since_check + 1 < cfg.recheck_every:
            out = align(src, self._model, init, self._tracking)
            if out.converged and not _moved(out.transform, self._last, self._model.centroid, self._settings):
                self._since_check += 1
                return out
        out = align(src, self._model, init, self._settings)
        self._checked = (out.converged and not out.ambiguous and not out.degenerate
                         and self._settings.yaw_hypotheses > 1)
        self._since_check = 0
        return out

    def teardown(self) -> None:
        self.log.info("icp localizer (%s, %s): %d alignments, flags %s", self.config.source, self.config.dof,
                      self.runs, self.flags)
        if self._align_ms:
            ms, age = np.asarray(self._align_ms), np.asarray(self._input_age_ms)
            self.log.info("icp localizer timing: align median %.1f ms (p90 %.1f); input age on arrival median "
                          "%.1f ms (p90 %.1f)", np.median(ms), np.percentile(ms, 90), np.median(age),
                          np.percentile(age, 90))

    def _count(self, flag: str, message: str) -> None:
        self.flags[flag] += 1
        key = message.split(" ", 1)[-1] if flag == "waiting" else message
        if key not in self._warned:
            self._warned.add(key)
            self.log.warning(message)
