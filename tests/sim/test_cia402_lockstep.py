"""The CiA 402 loop in lockstep: master and simulated drives on a synchronous in-process bus in
virtual time, and launch/ackermann_can.yaml itself (trajectory -> controller -> CANopen master ->
drives -> vehicle) run deterministically by sim.lockstep."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drivers.canopen402 import DEFAULT_DRIVES, STEER_COUNTS_PER_RAD, Cia402Bus, Cia402Master, Config
from msgs.control import WheelCommand
from sim.cia402_bank import LockstepDriveBank, SyncCanHub
from sim.cia402_drive import make_drive
from sim.lockstep import run_lockstep
from tether.testing import Harness

LAUNCH = Path(__file__).resolve().parents[2] / "launch" / "ackermann_can.yaml"
QUIET = {"eval": {"png": ""}, "can": {"publish_frames": False}}
RUN = {"front_wheel": 65_000, "front_steer": 20_000, "rear_wheel": 65_000, "rear_steer": -20_000}


def rig(faults=None, **config):
    hub = SyncCanHub()
    bank = LockstepDriveBank(hub.bus("drives"), {d.name: make_drive(d, (faults or {}).get(d.name), 0.0)
                                                 for d in DEFAULT_DRIVES})
    t = [0.0]
    master = Cia402Master(hub.bus("master"), Config(**config), clock=lambda: t[0])
    master.start()
    return hub, bank, master, t


def test_master_and_drives_on_the_synchronous_hub_run_in_virtual_time():
    def run() -> tuple[list, int]:
        hub, bank, master, t = rig()
        trace = []
        for k in range(1500):                                # 1.5 s virtual, master at 100 Hz
            t[0] = k * 1e-3
            hub.advance(t[0])
            if k % 10 == 0:
                master.step(t[0], RUN if k < 1000 else None)
                trace.append((master.enabled(), tuple(round(v, 6) for v in bank.actuals().values())))
        master.close()
        bank.bus.shutdown()
        return trace, hub.frames
    trace, frames = run()
    assert not trace[0][0] and trace[3][0]                  # brought up inside the first step, enabled by the 4th
    assert trace[99][1] == pytest.approx(tuple(RUN.values()), abs=2.0)
    assert not trace[-1][0] and trace[-1][1][0] == 0.0      # commands gone: quick stop, wheels at rest
    assert run() == (trace, frames)                         # same frames, same motion, every run


@pytest.mark.parametrize("feedback_ms, reason, t_max", [
    (0, "heartbeat of rear_steer lost", 0.61),                       # PDO bound off: the heartbeat's
    (200, "feedback PDOs of rear_steer (node 4) silent for", 0.52),  # the PDOs' bound comes first
])
def test_heartbeat_and_feedback_loss_are_judged_on_the_virtual_clock(feedback_ms, reason, t_max):
    hub, bank, master, t = rig(feedback_timeout_ms=feedback_ms)
    for k in range(300):
        t[0] = k * 1e-3
        hub.advance(t[0])
        if k % 10 == 0:
            master.step(t[0], RUN)
    assert master.enabled() and not master.latched
    bank.drives["rear_steer"].faults.mute = True
    for k in range(300, 1000):
        t[0] = k * 1e-3
        hub.advance(t[0])
        if k % 10 == 0:
            master.step(t[0], RUN)
            if master.latched:
                break
    # lost after 3 x 100 ms (heartbeat) or 200 ms (PDOs) of *virtual* time, however long the loop took
    assert master.latched.startswith(reason) and 0.49 < t[0] <= t_max
    master.close()
    bank.bus.shutdown()


def test_driver_node_ready_output_follows_the_drives():
    hub = SyncCanHub()
    bank = LockstepDriveBank(hub.bus("drives"), {d.name: make_drive(d, None, 0.0) for d in DEFAULT_DRIVES})
    node_cls = type("Cia402Bus", (Cia402Bus,), {"open_bus": lambda self: hub.bus("master")})
    cmd = WheelCommand(v_front_mps=0.2, delta_front_rad=0.1, v_rear_mps=0.2, delta_rear_rad=-0.1)
    with Harness(node_cls, params={"publish_frames": False, "cmd_timeout_s": 0.1}) as h:
        for k in range(1, 1001):
            t = k * 1e-3
            hub.advance(t)
            h.feed([(t, "cmd", cmd)] if k <= 500 and k % 20 == 0 else [], until_s=t)
        ready = [(m.stamp_ns * 1e-9, m.data) for m in h.of("ready")]
    bank.bus.shutdown()
    changes = [(round(t, 3), r) for (t, r), (_, before) in zip(ready, [(0.0, None)] + ready) if r != before]
    # not ready until commands arrive and every drive is OPERATION ENABLED; not ready once the
    # watchdog quick-stops them (commands stop at 0.5 s, timeout 0.1 s)
    assert [r for _, r in changes] == [False, True, False]
    assert 0.02 <= changes[1][0] <= 0.1 and 0.6 <= changes[2][0] <= 0.65
    assert bank.actuals()["front_wheel"] == 0.0


def tracking(run) -> tuple[dict, np.ndarray]:
    summary = run.node("eval").evaluate(0.0)[0]
    cmds = np.array([(c.v_front_mps, c.delta_front_rad, c.v_rear_mps, c.delta_rear_rad)
                     for c in run.of("controller/cmd")])
    return summary, cmds


@pytest.mark.parametrize("start", ["straight", "odd-steering-and-a-faulted-drive"])
def test_launched_loop_tracks_from_rest_without_a_branch_flip(start):
    """launch/ackermann_can.yaml, 13 s: through the first lobe tip, where a wheel started on the
    wrong branch must swing half a turn (the launched pipeline's old 54 mm bump)."""
    overrides = dict(QUIET)
    if start != "straight":       # steering left anywhere, a drive powered up in FAULT (reset by the master)
        overrides["drives"] = {"sim": {"front_steer": {"position_offset": int(-1.0 * STEER_COUNTS_PER_RAD)},
                                       "rear_steer": {"position_offset": int(0.6 * STEER_COUNTS_PER_RAD)},
                                       "front_wheel": {"start_in_fault": 0x2310}}}
    run = run_lockstep(LAUNCH, duration_s=13.0, overrides=overrides)
    summary, cmds = tracking(run)
    assert summary["max_mm"] < 2.0 and summary["rms_mm"] < 1.0        # whole run, start-up included
    assert cmds[:, [0, 2]].min() > -0.005                               # no wheel ever reverses (a flip does)
    assert cmds[:, 3].min() > -0.2 and cmds[:, 3].max() < 2.45         # rear on its forward side, off the stop
    ready = next(m.stamp_ns for m in run.of("can/ready") if m.data)
    refs, states = run.of("traj/reference"), run.of("vehicle/state")
    assert refs[0].stamp_ns >= ready                                   # the clock waited for the drives
    first_state = [s for s in states if s.stamp_ns <= refs[0].stamp_ns][-1]
    assert (refs[0].x_m, refs[0].y_m, refs[0].theta_rad) == pytest.approx(
        (first_state.x_m, first_state.y_m, first_state.theta_rad), abs=1e-9)
    held = [c for c in run.of("controller/cmd") if c.stamp_ns < refs[0].stamp_ns]
    assert held and all(c.v_front_mps == 0.0 for c in held)            # enabled standing still, steering held
    if start != "straight":
        assert held[0].delta_front_rad == pytest.approx(-1.0, abs=1e-4)
    master = run.node("can").master
    assert not master.latched
    # the launch file runs the cyclic synchronous modes: SYNC every 10 ms, steering CSP, wheels CSV
    assert master.syncs_sent >= 1250 and {d.mode for d in master.drives.values()} == {8, 9}


def test_the_old_start_is_caught_by_the_same_bounds():
    """The trajectory leaving at full speed from the origin without waiting (the former launch)."""
    overrides = dict(QUIET, traj={"wait_for_enable": False, "start_from_state": False, "ramp_s": 0.0,
                                  "align_s": 0.0})
    summary, cmds = tracking(run_lockstep(LAUNCH, duration_s=4.0, overrides=overrides))
    assert summary["max_mm"] > 50.0


def test_lockstep_refuses_source_nodes(tmp_path):
    path = tmp_path / "src.yaml"
    path.write_text("name: src\nnodes:\n  - {id: play, node: drivers.candump:CandumpPlayer, params: {path: x.log}}\n")
    with pytest.raises(ValueError, match="runs its own loop"):
        run_lockstep(path, duration_s=0.1)
