"""Tracking evaluation: reference vs achieved pose, a summary at the end and a trajectory PNG.

Pure part: :func:`tracking_errors` interpolates the reference at the state stamps and
returns position / heading errors; :func:`summarize` reduces them. Node
:class:`TrackingEval`: inputs ``reference`` (control.TrajectoryPoint) and ``state``
(control.VehicleState), output ``error`` (std.Float64, position error in m per state);
``teardown`` logs the summary and writes ``png``.
"""
from __future__ import annotations

import math
import os

import msgspec
import numpy as np

from msgs.control import TrajectoryPoint, VehicleState
from msgs.std import Float64
from tether import Input, Node, NonNegativeFloat


def tracking_errors(ref_t: np.ndarray, ref_pose: np.ndarray, t: np.ndarray, pose: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Errors of ``pose`` against the reference interpolated at ``t``.

    Parameters
    ----------
    ref_t : (M,) float, s, increasing
    ref_pose : (M, 3) float, (x_m, y_m, theta_rad)
    t : (N,) float, s
    pose : (N, 3) float, (x_m, y_m, theta_rad)

    Returns
    -------
    keep : (N,) bool
        States inside the reference time span (others have no reference to compare with).
    pos_err_m : (K,) float
        Euclidean position error of the kept states.
    heading_err_rad : (K,) float
        Heading error wrapped to [-pi, pi) (the reference heading is unwrapped before
        interpolating, so a reference crossing +-pi interpolates the short way).
    """
    ref_t, t = np.asarray(ref_t, float), np.asarray(t, float)
    ref_pose, pose = np.asarray(ref_pose, float).reshape(-1, 3), np.asarray(pose, float).reshape(-1, 3)
    if ref_t.shape[0] != ref_pose.shape[0] or t.shape[0] != pose.shape[0]:
        raise ValueError("times and poses must have the same length (ref_t with ref_pose, t with pose)")
    if ref_t.size < 2:
        return np.zeros(t.shape, bool), np.zeros(0), np.zeros(0)
    if np.any(np.diff(ref_t) <= 0):
        raise ValueError("reference times must be strictly increasing; sort and de-duplicate them first")
    keep = (t >= ref_t[0]) & (t <= ref_t[-1]) & np.all(np.isfinite(pose), axis=1)
    tk, pk = t[keep], pose[keep]
    rx = np.interp(tk, ref_t, ref_pose[:, 0])
    ry = np.interp(tk, ref_t, ref_pose[:, 1])
    rth = np.interp(tk, ref_t, np.unwrap(ref_pose[:, 2]))
    pos = np.hypot(pk[:, 0] - rx, pk[:, 1] - ry)
    head = (pk[:, 2] - rth + np.pi) % (2 * np.pi) - np.pi
    return keep, pos, head


def summarize(pos_err_m: np.ndarray, heading_err_rad: np.ndarray) -> dict[str, float]:
    """RMS and max of the errors (mm and degrees); NaN when there is nothing to compare."""
    if len(pos_err_m) == 0:
        return {"n": 0, "rms_mm": math.nan, "max_mm": math.nan, "rms_heading_deg": math.nan,
                "max_heading_deg": math.nan}
    return {"n": int(len(pos_err_m)), "rms_mm": float(np.sqrt(np.mean(pos_err_m ** 2)) * 1e3),
            "max_mm": float(np.max(pos_err_m) * 1e3),
            "rms_heading_deg": float(np.degrees(np.sqrt(np.mean(heading_err_rad ** 2)))),
            "max_heading_deg": float(np.degrees(np.max(np.abs(heading_err_rad))))}


def plot_tracking(path: str, ref_pose: np.ndarray, pose: np.ndarray, t: np.ndarray, pos_err_m: np.ndarray,
                  title: str) -> None:
    """Write the x-y paths and the position error over time to ``path`` (PNG)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.8))
    ax.plot(ref_pose[:, 0], ref_pose[:, 1], "k--", lw=1, label="reference")
    ax.plot(pose[:, 0], pose[:, 1], "C0", lw=1.2, label="vehicle")
    step = max(1, len(pose) // 25)
    ax.quiver(pose[::step, 0], pose[::step, 1], np.cos(pose[::step, 2]), np.sin(pose[::step, 2]),
              color="C0", scale=25, width=0.004)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.24), ncol=2, fontsize=8)
    ax.set_title(title)
    bx.plot(t, pos_err_m * 1e3, "C3", lw=1)
    bx.set_xlabel("t (s)")
    bx.set_ylabel("position error (mm)")
    bx.grid(alpha=0.3)
    fig.tight_layout()
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    png: str = "out/tracking.png"       # '' = no plot
    skip_s: NonNegativeFloat = 0.0      # ignore the first seconds (start-up transient) in the summary
    title: str = "trajectory tracking"


class TrackingEval(Node):
    """Inputs ``reference``, ``state``; output ``error`` (m); summary + PNG at teardown."""

    Config = Config
    inputs = {"reference": Input(TrajectoryPoint, depth=256), "state": Input(VehicleState, depth=256)}
    outputs = {"error": Float64}

    def setup(self) -> None:
        self._ref: list[tuple[float, float, float, float]] = []
        self._states: list[tuple[float, float, float, float]] = []
        self.summary: dict[str, float] = {}

    def on_reference(self, msg: TrajectoryPoint) -> None:
        t = msg.stamp_ns * 1e-9
        if self._ref and t <= self._ref[-1][0]:
            return                               # out-of-order or repeated stamp: keep the series increasing
        self._ref.append((t, msg.x_m, msg.y_m, msg.theta_rad))

    def on_state(self, msg: VehicleState) -> dict[str, Float64] | None:
        t = msg.stamp_ns * 1e-9
        self._states.append((t, msg.x_m, msg.y_m, msg.theta_rad))
        if len(self._ref) < 2:
            return None
        (t0, x0, y0, _), (t1, x1, y1, _) = self._ref[-2], self._ref[-1]
        if not t0 <= t <= t1 + 0.5:              # only against a recent reference (extrapolated a little)
            return None
        a = (t - t0) / (t1 - t0)
        err = math.hypot(msg.x_m - (x0 + a * (x1 - x0)), msg.y_m - (y0 + a * (y1 - y0)))
        return {"error": Float64(stamp_ns=msg.stamp_ns, data=err)}

    def evaluate(self, skip_s: float | None = None) -> tuple[dict[str, float], np.ndarray, np.ndarray, np.ndarray,
                                                           np.ndarray]:
        """Summary over the states after ``skip_s`` (default: the configured one), and the arrays."""
        skip_s = self.config.skip_s if skip_s is None else skip_s
        ref = np.array(self._ref, float).reshape(-1, 4)
        st = np.array(self._states, float).reshape(-1, 4)
        if len(ref):
            st = st[st[:, 0] >= ref[0, 0] + skip_s]
        keep, pos, head = tracking_errors(ref[:, 0], ref[:, 1:], st[:, 0], st[:, 1:])
        return summarize(pos, head), ref, st, keep, pos

    def teardown(self) -> None:
        self.summary, _, _, _, _ = self.evaluate()
        s = self.summary
        full, ref, st, keep, pos = self.evaluate(0.0)
        self.log.info("tracking over the whole run (from the first reference, start-up included): %d states, "
                      "position RMS %.2f mm max %.2f mm, heading RMS %.3f deg max %.3f deg", full["n"],
                      full["rms_mm"], full["max_mm"], full["rms_heading_deg"], full["max_heading_deg"])
        if self.config.skip_s > 0:
            self.log.info("tracking after %.1f s: %d states, position RMS %.2f mm max %.2f mm, heading RMS %.3f deg "
                          "max %.3f deg", self.config.skip_s, s["n"], s["rms_mm"], s["max_mm"], s["rms_heading_deg"],
                          s["max_heading_deg"])
        if self.config.png and len(st) and len(ref):
            t0 = ref[0, 0]
            title = f"{self.config.title}: RMS {full['rms_mm']:.2f} mm, max {full['max_mm']:.1f} mm (whole run)"
            if self.config.skip_s > 0:
                title += f"\nRMS {s['rms_mm']:.2f} mm after {self.config.skip_s:g} s"
            plot_tracking(self.config.png, ref[:, 1:], st[:, 1:], st[keep, 0] - t0, pos, title)
            self.log.info("tracking plot written to %s", self.config.png)
