"""Sonar mosaic: keyframes of the seabed registered by phase correlation into a pose graph (seed 08).

Inputs ``ping`` (SonarPing), ``nav`` (Pose3D of the sonar head, the navigation prior) and,
optionally, ``truth`` (Pose3D, for the closing report only). Outputs ``mosaic`` (Grid:
the blended seabed, georeferenced), ``trajectory`` (Path2D: the optimised vehicle track)
and ``keyframe`` (Image: the latest ground image).

Every ``keyframe_every_m`` of travel (or ``keyframe_every_deg`` of turn) the ping is
projected onto the seabed plane (``seafloor_z_m``) in a frame attached to the vehicle --
so that a navigation error shows as a rigid motion between keyframes -- as a square image
of ``image_px`` cells of ``cell_m``, centred ``center_ahead_m`` ahead. Each keyframe is
registered (:mod:`nodes.slam.fourier`, with hints from the current estimate) to the
previous one and to older ones the estimate says overlap it (loop closures), gated by the
peak-to-noise ratio; the navigation's own step between keyframes is an edge too, so the
graph stays connected when the sea floor is featureless. The graph (in cells) is
re-optimised after each keyframe (GNC rejects false closures). At the end the node logs
the trajectory error against ``truth`` for navigation alone, chaining alone and the
graph, and writes the mosaic and the trajectories as PNGs to ``out_dir``.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import cv2
import msgspec
import numpy as np

from msgs.geometry import Path2D, Pose3D
from msgs.sensor import Grid, Image
from msgs.sonar import SonarPing
from nodes.slam import fourier, mosaic
from nodes.slam.pose_graph import GraphError, PoseGraph2D, between, compose, optimize
from nodes.sonar.icp import yaw_of
from nodes.sonar.seabed import SeabedGrid, SeabedProjector
from tether import Input, Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    seafloor_z_m: float = -8.0
    cell_m: float = 0.1
    image_px: int = 256
    center_ahead_m: float = 13.5
    keyframe_every_m: float = 2.0
    keyframe_every_deg: float = 15.0
    min_pnr: float = 8.0
    min_shared: float = 0.3             # loop-closure candidates: estimated overlap, fraction of an image
    max_closures: int = 4               # per keyframe, the nearest candidates
    angle_search_deg: float = 0.0       # refine the navigation's relative heading within +- this (0: trust it)
    flat_field_m: float = 4.0           # the illumination's scale, divided out of every keyframe (tuned: first leg, texture seed 3)
    mask_erode_m: float = 1.0           # keep this far inside the fan's edges
    nav_sigma_m: float = 0.05           # navigation step noise: sigma_m + sigma_per_m x distance
    nav_sigma_per_m: float = 0.05
    nav_sigma_deg: float = 1.0
    publish_every: int = 5              # keyframes between mosaic messages
    out_dir: str = ""                   # PNGs and the summary at the end ('' = none)

    def __post_init__(self) -> None:
        if self.cell_m <= 0 or self.image_px < 32 or self.keyframe_every_m <= 0:
            raise ValueError("cell_m > 0, image_px >= 32 and keyframe_every_m > 0")


class SonarMosaic(Node):
    """Pings + navigation -> keyframes -> pose graph -> mosaic (see the module docstring)."""

    Config = Config
    inputs = {"ping": Input(SonarPing, latest=True), "nav": Input(Pose3D, depth=64), "truth": Input(Pose3D, depth=64)}
    outputs = {"mosaic": Grid, "trajectory": Path2D, "keyframe": Image}

    def setup(self) -> None:
        cfg = self.config
        self.projector = SeabedProjector(SeabedGrid(cfg.seafloor_z_m, cfg.cell_m, cfg.image_px, cfg.center_ahead_m,
                                                    cfg.flat_field_m, cfg.mask_erode_m))
        self.nav: list[tuple[int, np.ndarray]] = []          # recent (stamp, 4x4) navigation poses
        self.truth: list[tuple[int, np.ndarray]] = []
        self.images: list[np.ndarray] = []
        self.masks: list[np.ndarray] = []
        self.prior: list[np.ndarray] = []                    # keyframe image poses from navigation (cells)
        self.true: list[np.ndarray | None] = []
        self.links = mosaic.Links()
        self.estimate = np.zeros((0, 3))
        self.keyframe_ms: list[float] = []
        self.pings = 0

    # -- inputs ------------------------------------------------------------------------------------
    def on_nav(self, msg: Pose3D) -> None:
        self.nav.append((msg.stamp_ns, msg.matrix()))
        del self.nav[:-256]

    def on_truth(self, msg: Pose3D) -> None:
        self.truth.append((msg.stamp_ns, msg.matrix()))
        del self.truth[:-4096]

    def on_ping(self, ping: SonarPing) -> list[tuple[str, object]] | None:
        self.pings += 1
        head = _nearest(self.nav, ping.stamp_ns)
        if head is None or ping.intensities.size == 0:
            return None
        pose = self._image_pose(head)
        if self.prior and not self._moved(self.prior[-1], pose):
            return None
        t0 = time.perf_counter()
        image, mask = self.projector.project(ping.intensities, ping.bearings_rad, ping.range_resolution_m,
                                             ping.vertical_aperture_rad, head)
        truth = _nearest(self.truth, ping.stamp_ns)
        self._add_keyframe(image, mask, pose, None if truth is None else self._image_pose(truth))
        self.keyframe_ms.append((time.perf_counter() - t0) * 1e3)
        out: list[tuple[str, object]] = [
            ("keyframe", Image(stamp_ns=ping.stamp_ns, frame_id="keyframe",
                               data=np.clip(image * 100, 0, 255).astype(np.uint8), encoding="mono8")),
            ("trajectory", self.trajectory(ping.stamp_ns))]
        if len(self.images) % self.config.publish_every == 0:
            out.append(("mosaic", self.mosaic(ping.stamp_ns)))
        return out

    # -- the graph -----------------------------------------------------------------------------------
    def _image_pose(self, head: np.ndarray) -> np.ndarray:
        """The keyframe image's pose (cells) for a head pose: centre ahead, columns along the heading."""
        yaw = yaw_of(head)
        cx = head[0, 3] + self.config.center_ahead_m * math.cos(yaw)
        cy = head[1, 3] + self.config.center_ahead_m * math.sin(yaw)
        return np.array([cx / self.config.cell_m, cy / self.config.cell_m, yaw])

    def _moved(self, last: np.ndarray, pose: np.ndarray) -> bool:
        cfg = self.config
        # Distance between vehicle positions (the image centres swing with the heading).
        a = compose(last, np.array([-cfg.center_ahead_m / cfg.cell_m, 0.0, 0.0]))
        b = compose(pose, np.array([-cfg.center_ahead_m / cfg.cell_m, 0.0, 0.0]))
        turned = abs((pose[2] - last[2] + math.pi) % (2 * math.pi) - math.pi)
        return (math.hypot(*(b[:2] - a[:2])) * cfg.cell_m >= cfg.keyframe_every_m
                or math.degrees(turned) >= cfg.keyframe_every_deg)

    def _add_keyframe(self, image: np.ndarray, mask: np.ndarray, prior: np.ndarray, truth: np.ndarray | None) -> None:
        cfg = self.config
        k = len(self.images)
        self.images.append(image)
        self.masks.append(mask)
        self.prior.append(prior)
        self.true.append(truth)
        if k == 0:
            self.estimate = prior[None, :].copy()
            return
        guess = compose(self.estimate[k - 1], between(self.prior[k - 1], prior))
        estimate = np.vstack([self.estimate, guess])
        candidates = [k - 1]
        older = [(math.hypot(*(estimate[j, :2] - guess[:2])), j) for j in range(k - 1)
                 if mosaic.shared_fraction(image.shape, estimate[j], guess) >= cfg.min_shared]
        candidates += [j for _, j in sorted(older)[:cfg.max_closures]]
        for j in candidates:
            angle, shift = mosaic.expected_registration(estimate[j], guess)
            reg = fourier.register(self.images[j], image, fixed_mask=self.masks[j], moving_mask=mask,
                                   angle_hint=angle, shift_hint=shift,
                                   angle_search=math.radians(cfg.angle_search_deg))
            if fourier.is_reliable(reg, min_pnr=cfg.min_pnr):
                z, cov = mosaic.relative_pose(reg)
                self.links.kept.append(mosaic.Link(j, k, z, cov, reg.pnr, sequential=(j == k - 1)))
            else:
                self.links.refused.append((j, k, reg.pnr))
        self.estimate = self._optimise(estimate)

    def _nav_edges(self) -> list[tuple[int, int, tuple, np.ndarray]]:
        cfg = self.config
        edges = []
        for k in range(1, len(self.prior)):
            z = between(self.prior[k - 1], self.prior[k])
            sigma = (cfg.nav_sigma_m + cfg.nav_sigma_per_m * math.hypot(*z[:2]) * cfg.cell_m) / cfg.cell_m
            edges.append((k - 1, k, tuple(z), np.diag([sigma ** -2, sigma ** -2, math.radians(cfg.nav_sigma_deg) ** -2])))
        return edges

    def graph(self, *, with_closures: bool = True) -> PoseGraph2D:
        links = [l for l in self.links.kept if with_closures or l.sequential]
        edges = self._nav_edges() + [(l.i, l.j, tuple(l.z), np.linalg.inv(l.covariance)) for l in links]
        return PoseGraph2D.from_edges(edges, {k: tuple(p) for k, p in enumerate(self.prior)})

    def _optimise(self, start: np.ndarray) -> np.ndarray:
        graph = self.graph()
        try:
            result = optimize(graph, initial=start, robust="gnc" if any(not l.sequential for l in self.links.kept) else None,
                              max_iterations=30)
        except GraphError as exc:
            self.log.error("pose graph not solved (%s); keeping the previous estimate", exc)
            return start
        return result.poses

    def chained(self) -> np.ndarray:
        """Chaining alone: consecutive registrations composed (the navigation step where one is refused)."""
        return mosaic.chain(self.links, len(self.prior), self.prior[0], prior=np.array(self.prior))

    # -- outputs -------------------------------------------------------------------------------------
    def vehicle_track(self, poses: np.ndarray) -> np.ndarray:
        """Image poses (cells) -> vehicle (head) positions (m) and headings."""
        back = np.array([-self.config.center_ahead_m / self.config.cell_m, 0.0, 0.0])
        out = np.array([compose(p, back) for p in poses]) if len(poses) else np.zeros((0, 3))
        out[:, :2] *= self.config.cell_m
        return out

    def trajectory(self, stamp_ns: int) -> Path2D:
        return Path2D(stamp_ns=stamp_ns, frame_id="world", poses=self.vehicle_track(self.estimate))

    def mosaic(self, stamp_ns: int) -> Grid:
        image, weight, (x0, y0) = mosaic.compose_mosaic(self.images, self.estimate, masks=self.masks)
        return Grid(stamp_ns=stamp_ns, frame_id="world", data=np.where(weight > 0.05, image, np.nan).astype(np.float32),
                    resolution_m=self.config.cell_m, origin_x_m=x0 * self.config.cell_m,
                    origin_y_m=y0 * self.config.cell_m)

    def report(self) -> dict[str, float]:
        """Trajectory RMSE (m) against the truth, all expressed from the first keyframe."""
        if len(self.prior) < 2 or any(t is None for t in self.true):
            return {}
        truth = np.array(self.true)

        def ate(poses: np.ndarray) -> float:
            rel = between(np.repeat(poses[:1], len(poses), 0), poses)
            ref = between(np.repeat(truth[:1], len(truth), 0), truth)
            return float(np.sqrt(np.mean(np.sum((rel[:, :2] - ref[:, :2]) ** 2, axis=1))) * self.config.cell_m)

        return {"ate_m_nav": ate(np.array(self.prior)), "ate_m_chain": ate(self.chained()),
                "ate_m_graph": ate(self.estimate), "keyframes": float(len(self.prior)),
                "closures": float(sum(not l.sequential for l in self.links.kept)),
                "ms_per_keyframe": float(np.median(self.keyframe_ms)) if self.keyframe_ms else 0.0}

    def teardown(self) -> None:
        summary = self.report()
        if summary:
            self.log.info("mosaic: %d keyframes from %d pings, %d loop closures (%d pairs refused); trajectory RMSE "
                          "navigation %.3f m, chaining %.3f m, graph %.3f m; %.0f ms per keyframe",
                          summary["keyframes"], self.pings, summary["closures"], len(self.links.refused),
                          summary["ate_m_nav"], summary["ate_m_chain"], summary["ate_m_graph"], summary["ms_per_keyframe"])
        if self.config.out_dir and len(self.images) >= 2:
            self.write_pictures(Path(self.config.out_dir))

    def write_pictures(self, out: Path) -> None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        out.mkdir(parents=True, exist_ok=True)
        grid = self.mosaic(0)
        data = grid.data
        finite = np.isfinite(data)
        vmax = float(np.percentile(data[finite], 99)) if finite.any() else 1.0
        cv2.imwrite(str(out / "mosaic.png"), np.clip(np.nan_to_num(data) / max(vmax, 1e-9) * 255, 0, 255).astype(np.uint8)[::-1])
        fig, ax = plt.subplots(figsize=(7, 7))
        extent = (grid.origin_x_m, grid.origin_x_m + data.shape[1] * grid.resolution_m,
                  grid.origin_y_m, grid.origin_y_m + data.shape[0] * grid.resolution_m)
        ax.imshow(np.nan_to_num(data), cmap="gray", origin="lower", extent=extent, vmin=0, vmax=vmax)
        tracks = {"navigation": np.array(self.prior), "chaining": self.chained(), "graph": self.estimate}
        if all(t is not None for t in self.true):
            tracks = {"truth": np.array(self.true), **tracks}
        colours = {"truth": "lime", "navigation": "tab:orange", "chaining": "tab:red", "graph": "tab:cyan"}
        anchor = tracks.get("truth", tracks["graph"])[0]
        for name, poses in tracks.items():
            aligned = compose(np.repeat(anchor[None], len(poses), 0), between(np.repeat(poses[:1], len(poses), 0), poses))
            v = self.vehicle_track(aligned)           # every track from the first keyframe's true pose
            ax.plot(v[:, 0], v[:, 1], ".-", ms=3, lw=1, color=colours[name], label=name)
        ax.set_xlabel("x east (m)   [tracks aligned at the first keyframe; mosaic from the graph]")
        ax.set_ylabel("y north (m)")
        ax.legend(fontsize=8)
        summary = self.report()
        if summary:
            ax.set_title(f"RMSE nav {summary['ate_m_nav']:.2f} m, chain {summary['ate_m_chain']:.2f} m, "
                         f"graph {summary['ate_m_graph']:.2f} m")
        fig.tight_layout()
        fig.savefig(out / "mosaic_trajectories.png", dpi=110)
        plt.close(fig)


def _nearest(history: list[tuple[int, np.ndarray]], stamp_ns: int) -> np.ndarray | None:
    if not history:
        return None
    stamps = np.array([s for s, _ in history])
    k = int(np.argmin(np.abs(stamps - stamp_ns)))
    return history[k][1] if abs(int(stamps[k]) - stamp_ns) < 500_000_000 else None
