"""Sonar pipeline evaluation: rates, latency, cloud size and localisation error against ground truth.

At shutdown it logs a short summary, writes ``summary.json`` and two PNGs (the last fan
image; the cloud before and after ICP over the structure model, and under it the carved cloud of
``nodes.sonar.carved_cloud`` when its input ``carved`` is wired, coloured by elevation sigma) into
``out_dir``. The carved cloud is built with the navigation pose like the highlight cloud, so it is
drawn and scored (distance of its points to the structure: ``carved_*`` in the summary) after the
last trusted ICP correction when there is one.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import msgspec
import numpy as np

from msgs.geometry import Pose3D
from msgs.sensor import PointCloud
from msgs.sonar import FanImage, IcpResult, SonarPing
from nodes.sonar.evaluation import cloud_metrics, nearest, pose_error, save_cloud_png, save_fan_png
from tether import Input, Node, PositiveFloat


WRONG_M, WRONG_DEG = 0.5, 5.0     # a trusted correction further off than this is a confident wrong pose


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    out_dir: str = "out/sonar"
    scene: str = "tripod"          # whose structures to draw under the cloud (sim.fls scene name or path)
    model_spacing_m: PositiveFloat = 0.15
    png: bool = True


class SonarEvaluation(Node):
    """Inputs from the pipeline and the simulator's ground truth; output nothing, report at the end."""

    Config = Config
    inputs = {"ping": Input(SonarPing, depth=256), "image": Input(FanImage, latest=True),
              "cloud": Input(PointCloud, latest=True), "correction": Input(IcpResult, depth=256),
              "truth": Input(Pose3D, depth=256), "nav": Input(Pose3D, depth=256),
              "carved": Input(PointCloud, latest=True)}

    def setup(self) -> None:
        self._ping_stamps: list[int] = []
        self._truth: dict[int, np.ndarray] = {}
        self._nav: dict[int, np.ndarray] = {}
        self._rows: list[dict] = []
        self._latency_ms: list[float] = []
        self._images: dict[int, FanImage] = {}     # every 10th fan, by stamp (a few MB)
        self._image_count = 0
        self._cloud: PointCloud | None = None
        self._carved: PointCloud | None = None
        self._last_trusted: IcpResult | None = None

    def on_ping(self, ping: SonarPing) -> None:
        self._ping_stamps.append(ping.stamp_ns)

    def on_image(self, image: FanImage) -> None:
        if self._image_count % 10 == 0:
            self._images[image.stamp_ns] = image
        self._image_count += 1

    def on_cloud(self, cloud: PointCloud) -> None:
        self._cloud = cloud

    def on_carved(self, cloud: PointCloud) -> None:
        self._carved = cloud

    def on_truth(self, pose: Pose3D) -> None:
        self._truth[pose.stamp_ns] = pose.matrix()

    def on_nav(self, pose: Pose3D) -> None:
        self._nav[pose.stamp_ns] = pose.matrix()

    def on_correction(self, result: IcpResult) -> None:
        if result.iterations > 0:      # an alignment was run (not "waiting for data"): its latency counts
            self._latency_ms.append((time.time_ns() - result.stamp_ns) / 1e6)
        if result.converged and not result.degenerate and not result.ambiguous:
            self._last_trusted = result
        self._rows.append({"stamp_ns": result.stamp_ns, "C": result.correction.matrix(), "converged": result.converged,
                           "degenerate": result.degenerate, "ambiguous": result.ambiguous, "rmse": result.rmse_m,
                           "cloud_size": result.cloud_size})

    def _errors(self) -> list[dict]:
        if not self._truth or not self._nav:
            return []
        ts, ns = np.array(sorted(self._truth)), np.array(sorted(self._nav))
        out = []
        for row in self._rows:
            truth = self._truth[int(ts[nearest(ts, row["stamp_ns"])])]
            nav = self._nav[int(ns[nearest(ns, row["stamp_ns"])])]
            trusted = row["converged"] and not row["degenerate"] and not row["ambiguous"]
            est = row["C"] @ nav if trusted else nav
            e_t, e_h = pose_error(est, truth)
            n_t, n_h = pose_error(nav, truth)
            out.append({**row, "trusted": trusted, "err_m": e_t, "err_deg": math.degrees(e_h),
                        "nav_err_m": n_t, "nav_err_deg": math.degrees(n_h)})
        return out

    def summary(self) -> dict:
        stamps = np.array(self._ping_stamps, dtype=np.int64)
        span = (stamps[-1] - stamps[0]) / 1e9 if len(stamps) > 1 else 0.0
        errs = self._errors()
        trusted = [e for e in errs if e["trusted"]]
        tail = trusted[len(trusted) // 2:]          # after the cloud has grown: the steady state
        return {
            "pings": len(stamps),
            "pings_per_s": (len(stamps) - 1) / span if span > 0 else 0.0,
            "cloud_size": len(self._cloud.points_m) if self._cloud is not None else 0,
            "corrections": len(errs), "trusted_corrections": len(trusted),
            "latency_ms_p50": float(np.median(self._latency_ms)) if self._latency_ms else float("nan"),
            "nav_err_m": float(np.median([e["nav_err_m"] for e in errs])) if errs else float("nan"),
            "nav_err_deg": float(np.median([e["nav_err_deg"] for e in errs])) if errs else float("nan"),
            "loc_err_m": float(np.median([e["err_m"] for e in tail])) if tail else float("nan"),
            "loc_err_deg": float(np.median([e["err_deg"] for e in tail])) if tail else float("nan"),
            # every trusted correction, not just the steady state: a confident wrong pose must show
            "max_trusted_err_m": max((e["err_m"] for e in trusted), default=float("nan")),
            "max_trusted_err_deg": max((e["err_deg"] for e in trusted), default=float("nan")),
            "wrong_trusted": sum(e["err_m"] > WRONG_M or e["err_deg"] > WRONG_DEG for e in trusted),
            **self._carved_metrics(),
        }

    def _corrected(self, points: np.ndarray) -> np.ndarray:
        """``points`` moved by the last trusted ICP correction (unchanged without one)."""
        if self._last_trusted is None:
            return points
        c = self._last_trusted.correction.matrix()
        return points @ c[:3, :3].T + c[:3, 3]

    def _carved_metrics(self) -> dict:
        """Accuracy of the carved cloud (after the last trusted correction) against the scene's structures."""
        if self._carved is None:
            return {}
        from sim.fls import load_scene, sample_structures

        surface, _ = sample_structures(load_scene(self.config.scene), spacing_m=0.03)
        m = cloud_metrics(self._corrected(np.asarray(self._carved.points_m, float)), surface)
        return {"carved_points": m["points"], "carved_acc_median_m": m["acc_median_m"],
                "carved_acc_p90_m": m["acc_p90_m"], "carved_acc_frac_0p2": m["acc_frac_0p2"],
                "carved_corrected": self._last_trusted is not None}

    def teardown(self) -> None:
        s = self.summary()
        out = Path(self.config.out_dir)
        out.mkdir(parents=True, exist_ok=True)
        (out / "summary.json").write_text(json.dumps(s, indent=1))
        self.log.info("summary: %d pings at %.1f pings/s, ping-to-pose latency p50 %.0f ms, cloud %d points",
                      s["pings"], s["pings_per_s"], s["latency_ms_p50"], s["cloud_size"])
        self.log.info("summary: localisation error %.3f m / %.2f deg after ICP (navigation alone: %.3f m / %.2f deg); "
                      "%d of %d corrections trusted", s["loc_err_m"], s["loc_err_deg"], s["nav_err_m"],
                      s["nav_err_deg"], s["trusted_corrections"], s["corrections"])
        (self.log.error if s["wrong_trusted"] else self.log.info)(
            "summary: worst trusted correction %.3f m / %.2f deg; %d trusted corrections were wrong (> %.1f m or %.0f deg)",
            s["max_trusted_err_m"], s["max_trusted_err_deg"], s["wrong_trusted"], WRONG_M, WRONG_DEG)
        if "carved_points" in s:
            self.log.info("summary: carved cloud %d points, %.0f %% within 0.2 m of the structure (p90 %.2f m)%s",
                          s["carved_points"], 100 * s["carved_acc_frac_0p2"], s["carved_acc_p90_m"],
                          " after the last trusted ICP correction" if s["carved_corrected"] else
                          " (navigation pose: no trusted correction)")
        if self.config.png:
            self._pictures(out)

    def _fan_to_show(self) -> FanImage | None:
        """The kept fan nearest the middle of the trusted corrections (structure in view), else the last."""
        if not self._images:
            return None
        stamps = np.array(sorted(self._images))
        trusted = sorted(e["stamp_ns"] for e in self._errors() if e["trusted"])
        target = trusted[len(trusted) // 2] if trusted else int(stamps[-1])
        return self._images[int(stamps[nearest(stamps, target)])]

    def _pictures(self, out: Path) -> None:
        im = self._fan_to_show()
        if im is not None:
            save_fan_png(out / "fan.png", np.asarray(im.image), im.m_per_px, im.origin_row_px, im.origin_col_px,
                         title=f"sonar fan, ping {im.ping_id}")
        if self._cloud is not None and len(self._cloud.points_m):
            from sim.fls import load_scene, sample_structures

            model, _ = sample_structures(load_scene(self.config.scene), spacing_m=self.config.model_spacing_m)
            cloud = np.asarray(self._cloud.points_m, dtype=float)
            corrected = self._corrected(cloud) if self._last_trusted is not None else None
            carved = sigma = None
            if self._carved is not None:
                carved = self._corrected(np.asarray(self._carved.points_m, dtype=float))
                # sigma_m since it was appended to PointCloud; older logs carried it in intensity
                sigma = np.asarray(self._carved.sigma_m if len(self._carved.sigma_m) else self._carved.intensity,
                                   dtype=float)
            save_cloud_png(out / "cloud.png", cloud, model, corrected,
                           title=f"{len(cloud)} cloud points over the {self.config.scene} model", carved=carved,
                           carved_sigma=sigma, carved_label="carved cloud" + (" after ICP" if corrected is not None
                                                                               else " (navigation pose)"))
        self.log.info("pictures in %s", out)
