"""Gesture teleoperation: the dead man's rule in the pure law, and the launched pipeline in
virtual time stopping the wheelchair on a dropped camera stream and on a crashed node."""
from __future__ import annotations

import numpy as np
import pytest

from msgs.hand import HandGesture
from nodes.control.gesture_map import GestureDrive
from nodes.control.gesture_teleop import GestureTeleop
from nodes.vision.hand_gesture import HandGestureNode
from sim.lockstep import run_lockstep
from tether.testing import Harness

LAUNCH = "launch/gesture_teleop.yaml"


def test_a_confident_mapped_gesture_drives_until_the_dead_man_timeout():
    law = GestureDrive({"point": (0.5, 0.0), "fist": (0.0, 0.0)}, min_confidence=0.6, deadman_s=0.3)
    assert law.command(t_s=0.0)[:2] == (0.0, 0.0)                           # nothing seen yet
    assert law.observe("point", 0.9, t_s=1.0)
    assert law.command(t_s=1.29)[:2] == (0.5, 0.0)
    v, w, why = law.command(t_s=1.31)
    assert (v, w) == (0.0, 0.0) and why.startswith("dead man")
    assert not law.observe("point", 0.3, t_s=1.4)                          # not confident: does not refresh
    assert not law.observe("wave", 0.99, t_s=1.4)                          # not mapped: does not refresh
    assert law.command(t_s=1.45)[:2] == (0.0, 0.0)
    law.observe("point", 0.9, t_s=2.0)
    law.observe("point", 0.9, t_s=1.5)                                     # an older frame arriving late
    assert law.command(t_s=2.2)[:2] == (0.5, 0.0) and law.command(t_s=2.31)[:2] == (0.0, 0.0)
    with pytest.raises(ValueError, match="deadman_s"):
        GestureDrive(deadman_s=0.0)


def test_teleop_node_judges_the_age_by_the_image_stamp():
    h = Harness(GestureTeleop, params={"rate_hz": 20, "deadman_s": 0.3})
    g = HandGesture(stamp_ns=int(0.95e9), present=True, gesture="point", confidence=0.9, count=1)
    h.feed([(1.0, "gesture", g)], until_s=1.5)
    v = [(o.t_ns / 1e9, o.msg.vx_mps) for o in h.outputs]
    assert all(x == 0.5 for t, x in v if 1.05 <= t <= 1.2) and all(x == 0.0 for t, x in v if t >= 1.3 or t < 1.0)
    assert sum(1.05 <= t <= 1.2 for t, _ in v) == 4
    h.feed([(1.6, "gesture", HandGesture(stamp_ns=int(1.6e9), present=False))], until_s=1.7)
    assert h.of("cmd")[-1].vx_mps == 0.0


def _speeds(run, topic="chair/odom"):
    return np.array([(m.stamp_ns / 1e9, m.twist.vx_mps, m.twist.wz_radps) for m in run.of(topic)])


def _cmds(run):
    return np.array([(m.stamp_ns / 1e9, m.vx_mps, m.wz_radps) for m in run.of("teleop/cmd")])


OVERRIDES = {"view": {"path": ""}, "camera": {"script": "point:30", "blackout_start_s": 3.0, "blackout_end_s": 5.0}}


def test_launched_teleop_drives_on_a_gesture_and_stops_when_the_camera_stream_drops():
    run = run_lockstep(LAUNCH, duration_s=6.0, step_s=0.01, overrides=OVERRIDES)
    cmd, odo = _cmds(run), _speeds(run)
    assert np.all(cmd[(cmd[:, 0] > 1.0) & (cmd[:, 0] < 3.0), 1] == 0.5)     # pointing: forward
    assert np.all(cmd[(cmd[:, 0] > 3.4) & (cmd[:, 0] < 5.0), 1:] == 0.0)    # blackout: stopped in 0.3 s (+ latency)
    assert np.all(np.abs(odo[(odo[:, 0] > 4.3) & (odo[:, 0] < 5.0), 1]) < 1e-6)   # and the chair has braked
    assert odo[odo[:, 0] < 3.0, 1].max() > 0.45
    assert np.all(cmd[cmd[:, 0] > 5.5, 1] == 0.5)                            # the stream is back: driving again


def test_launched_teleop_stops_when_the_recogniser_crashes(monkeypatch):
    real = HandGestureNode.on_image

    def crashing(self, msg):
        if msg.stamp_ns > 3e9:
            raise RuntimeError("recogniser died")
        return real(self, msg)

    monkeypatch.setattr(HandGestureNode, "on_image", crashing)
    over = {**OVERRIDES, "camera": {"script": "point:30"}}
    run = run_lockstep(LAUNCH, duration_s=5.0, step_s=0.01, overrides=over, catch_errors=True)
    cmd, odo = _cmds(run), _speeds(run)
    assert any(node == "gesture" for node, _, _ in run.errors)
    assert np.all(cmd[(cmd[:, 0] > 1.0) & (cmd[:, 0] < 3.0), 1] == 0.5)
    assert np.all(cmd[cmd[:, 0] > 3.4, 1:] == 0.0)
    assert np.all(np.abs(odo[odo[:, 0] > 4.3, 1]) < 1e-6)


def test_launched_teleop_crash_is_caught_by_the_wheelchair_watchdog(monkeypatch):
    real = GestureTeleop.on_tick

    def crashing(self, tick):
        if self.now_ns() > 3e9:
            raise RuntimeError("teleop died")
        return real(self, tick)

    monkeypatch.setattr(GestureTeleop, "on_tick", crashing)
    over = {**OVERRIDES, "camera": {"script": "point:30"}}
    run = run_lockstep(LAUNCH, duration_s=5.0, step_s=0.01, overrides=over, catch_errors=True)
    cmd, odo = _cmds(run), _speeds(run)
    assert cmd[:, 0].max() <= 3.0 and cmd[-1, 1] == 0.5                    # the last command said "forward"
    assert np.all(np.abs(odo[odo[:, 0] > 4.3, 1]) < 1e-6)                  # the chair's watchdog (0.5 s) stopped it
