"""UAV homing viewer: the path over the map (truth, INS, fixes) and the errors over time, as a PNG."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import msgspec
import numpy as np

from msgs.uav import GeoFix, UavState
from nodes.vision.geomap import brighton_map, procedural_map
from tether import Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    path: str = "out/uav_homing.png"
    map: str = "procedural"
    map_seed: int = 0
    target_e_m: float = 0.0
    target_n_m: float = 0.0
    rate_hz: float = 0.5


class UavView(Node):
    """Inputs ``truth``, ``ins``, ``fix``; writes ``path``; logs the final distance to the target."""

    Config = Config
    inputs = {"truth": UavState, "ins": UavState, "fix": GeoFix}
    timers = {"draw": "rate_hz"}

    def setup(self) -> None:
        c = self.config
        self.gm = brighton_map() if c.map == "brighton" else procedural_map(rng=np.random.default_rng(c.map_seed))
        self.truth: list[tuple[int, float, float]] = []
        self.ins: list[tuple[int, float, float]] = []
        self.fixes: list[tuple[int, bool, float, float]] = []

    def on_truth(self, m: UavState) -> None:
        self.truth.append((m.stamp_ns, m.e_m, m.n_m))

    def on_ins(self, m: UavState) -> None:
        self.ins.append((m.stamp_ns, m.e_m, m.n_m))

    def on_fix(self, m: GeoFix) -> None:
        self.fixes.append((m.stamp_ns, m.ok, m.e_m, m.n_m))

    def on_draw(self, tick: Any) -> None:
        if self.truth:
            self.write()

    def teardown(self) -> None:
        if self.truth:
            self.write()
            t = self.truth[-1]
            self.log.info("uav view: final distance to the target %.2f m", math.hypot(t[1] - self.config.target_e_m,
                                                                                     t[2] - self.config.target_n_m))

    def write(self) -> None:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        c = self.config
        T = np.array(self.truth)
        t0 = T[0, 0]
        fig, (ax, bx) = plt.subplots(1, 2, figsize=(14, 6))
        h, w = self.gm.image.shape[:2]
        corners = self.gm.to_world(np.array([[0, 0], [w, h]], float))
        ax.imshow(self.gm.image[..., ::-1], extent=(corners[0, 0], corners[1, 0], corners[1, 1], corners[0, 1]))
        ax.plot(T[:, 1], T[:, 2], "w-", lw=2, label="truth")
        if self.ins:
            I = np.array(self.ins)
            ax.plot(I[:, 1], I[:, 2], "y--", lw=1, label="INS (drifts)")
        F = np.array([(s, o, e, n) for s, o, e, n in self.fixes if o]) if self.fixes else np.zeros((0, 4))
        if len(F):
            ax.plot(F[:, 2], F[:, 3], "g.", ms=4, label="geo fixes")
        ax.plot([T[0, 1]], [T[0, 2]], "bo", label="start")
        ax.plot([c.target_e_m], [c.target_n_m], "r*", ms=15, label="target")
        ax.set_xlim(min(corners[:, 0].min(), T[:, 1].min()) - 10, max(corners[:, 0].max(), T[:, 1].max()) + 10)
        ax.set_ylim(min(corners[:, 1].min(), T[:, 2].min()) - 10, max(corners[:, 1].max(), T[:, 2].max()) + 10)
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)")
        ax.legend(loc="best", fontsize=8)
        dist = np.hypot(T[:, 1] - c.target_e_m, T[:, 2] - c.target_n_m)
        bx.semilogy((T[:, 0] - t0) / 1e9, np.maximum(dist, 1e-3), label="distance to target (truth)")
        if len(F):
            tr = {s: (e, n) for s, e, n in zip(T[:, 0], T[:, 1], T[:, 2])}
            err = [(s, math.hypot(e - tr[s][0], n - tr[s][1])) for s, _, e, n in F if s in tr]
            if err:
                E = np.array(err)
                bx.semilogy((E[:, 0] - t0) / 1e9, np.maximum(E[:, 1], 1e-3), "g.", label="fix error")
        bx.set_xlabel("time (s)")
        bx.set_ylabel("m")
        bx.grid(alpha=0.3, which="both")
        bx.legend()
        ok = sum(1 for f in self.fixes if f[1])
        fig.suptitle(f"UAV homing: {ok} of {len(self.fixes)} frames fixed; final distance {dist[-1]:.2f} m")
        fig.tight_layout()
        Path(c.path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(c.path, dpi=70)
        plt.close(fig)
