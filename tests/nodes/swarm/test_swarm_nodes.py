"""SwarmSim and SwarmView through the in-process harness: what goes out, when the world stops, the PNG."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from nodes.swarm.swarm_view import SwarmView
from sim.swarm_node import SwarmSim
from tether.errors import ConfigError
from tether.testing import Harness


def test_sim_publishes_state_every_tick_and_metrics_every_second_until_done():
    with Harness(SwarmSim, params=dict(n_robots=8, rate_hz=10.0, duration_s=3.0, zones=1)) as h:
        h.advance_to(5.0)                                      # 50 ticks offered, 30 simulated
    states, metrics = h.of("state"), h.of("metrics")
    assert len(states) == 30
    assert [round(m.t_s, 6) for m in metrics] == [1.0, 2.0, 3.0]
    assert [m.done for m in metrics] == [False, False, True]
    last = states[-1]
    assert last.xy_m.shape == (8, 2) and last.carrying.dtype == bool and last.zones_m == [1.8]
    assert np.all((last.xy_m[:, 0] > 0) & (last.xy_m[:, 0] < 4)) and last.gate_width_m < 0
    assert metrics[-1].food >= 0 and 0 <= metrics[-1].contact_frac <= 1


def test_sim_config_is_checked():
    with pytest.raises(ConfigError):
        SwarmSim.make_config({"zones": 3})
    with pytest.raises(ConfigError):
        SwarmSim.make_config({"transfer": "teleport"})
    with pytest.raises(ConfigError):
        Harness(SwarmSim, params=dict(zones=1, transfer="p2p"))


def test_view_writes_the_arena_and_the_curve(tmp_path):
    sim = Harness(SwarmSim, params=dict(n_robots=12, rate_hz=10.0, duration_s=4.0))
    sim.advance_to(4.0)
    path = tmp_path / "swarm.png"
    view = Harness(SwarmView, params=dict(path=str(path), rate_hz=0.5, px_per_m=100.0))
    events = [(o.t_ns / 1e9 - sim.start_ns / 1e9, o.output, o.msg) for o in sim.outputs]
    view.feed(events)
    view.close()
    img = cv2.imread(str(path))
    assert img is not None and img.shape[1] == 400              # 4 m at 100 px/m
    assert img.shape[0] > 100 + 36                             # title + arena + delivery curve
    assert view.node.written >= 2
    green = (img[..., 1] > 140) & (img[..., 0] < 80) & (img[..., 2] < 80)   # robots with food are drawn
    assert green.sum() > 0 or not any(sim.of("state")[-1].carrying)
