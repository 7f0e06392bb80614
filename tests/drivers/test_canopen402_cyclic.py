"""The CiA 402 master in the cyclic synchronous modes (steering CSP, wheels CSV) with SYNC at
100 Hz, and with homing, against the simulated drives on a synchronous bus in virtual time:
SYNC after the cycle's RPDOs, SYNC jitter, a lost SYNC producer, a drive that misses SYNC."""
from __future__ import annotations

import numpy as np
import pytest

from drivers import cia402 as p
from drivers.canopen402 import DEFAULT_DRIVES, STEER_COUNTS_PER_RAD, Cia402Master, Config
from sim.cia402_bank import LockstepDriveBank, SyncCanHub
from sim.cia402_drive import SimDriveConfig, make_drive

CYCLIC = dict(sync_hz=100.0, steer_mode="csp", wheel_mode="csv")
RUN = {"front_wheel": 65_000, "front_steer": 20_000, "rear_wheel": 65_000, "rear_steer": -20_000}


class Rig:
    """Master and four simulated drives on a lockstep hub; a tap records (time, COB-ID) of every frame."""

    def __init__(self, knobs: dict[str, SimDriveConfig] | None = None, **config) -> None:
        self.hub = SyncCanHub()
        self.bank = LockstepDriveBank(self.hub.bus("drives"), {d.name: make_drive(d, (knobs or {}).get(d.name), 0.0)
                                                               for d in DEFAULT_DRIVES})
        self.frames: list[tuple[float, int]] = []
        self.tap = self.hub.bus("tap")
        self.tap.receivers.append(lambda m: self.frames.append((self.hub.now_s, m.arbitration_id)))
        self.t = 0.0
        self.master = Cia402Master(self.hub.bus("master"), Config(**{**CYCLIC, **config}), clock=lambda: self.t)
        self.master.start()

    def run(self, until_s: float, setpoints=RUN, *, steps=None, stop=lambda: False) -> None:
        """Advance in 1 ms steps to ``until_s``, the master stepping at ``steps`` (default every 10 ms)."""
        steps = iter(steps if steps is not None else np.arange(round(self.t / 0.01) + 1, 10_000) * 0.01)
        nxt = next(steps, None)
        while self.t < until_s - 1e-9:
            self.t = round(self.t + 0.001, 6)
            self.hub.advance(self.t)
            while nxt is not None and nxt <= self.t + 1e-9:
                self.master.step(self.t, setpoints)
                nxt = next(steps, None)
            if stop():
                return

    def close(self) -> None:
        self.master.close()
        for bus in (self.bank.bus, self.tap):
            bus.shutdown()

    def actuals(self) -> dict[str, float]:
        return self.bank.actuals()

    def emcy(self) -> dict[str, list[int]]:
        return {name: d.emcy_sent for name, d in self.bank.drives.items()}


@pytest.fixture
def rig():
    rigs = []

    def make(**kw) -> Rig:
        rigs.append(Rig(**kw))
        return rigs[-1]
    yield make
    for r in rigs:
        r.close()


def test_cyclic_modes_run_with_sync_after_the_cycles_rpdos(rig):
    r = rig()
    r.run(1.0)
    m = r.master
    assert m.enabled() and not m.latched
    assert {d.name: d.mode for d in m.drives.values()} == {
        "front_wheel": p.MODE_CSV, "front_steer": p.MODE_CSP, "rear_wheel": p.MODE_CSV, "rear_steer": p.MODE_CSP}
    assert r.actuals() == pytest.approx(RUN, abs=5.0)
    assert all(d.od[(p.COMM_CYCLE_PERIOD, 0)].value == 10_000 for d in r.bank.drives.values())
    assert m.drives["front_wheel"].device_name == "tether sim wheel drive"      # 0x1008 by segmented upload
    syncs = [t for t, cob in r.frames if cob == p.SYNC]
    assert len(syncs) == m.syncs_sent >= 99 and np.allclose(np.diff(syncs), 0.01)
    # every SYNC comes after the four RPDOs of its cycle, so every drive acts on the same cycle's set-point
    late = [t for t in syncs[50:] if sorted(cob for tt, cob in r.frames if tt == t and 0x200 < cob < 0x280)
            != [0x201, 0x202, 0x203, 0x204]]
    assert late == []


def test_steer_set_points_are_slewed_at_the_steer_rate(rig):
    r = rig()
    r.run(0.5, setpoints={**RUN, "front_steer": 0, "rear_steer": 0})
    far = {**RUN, "front_steer": int(1.0 * STEER_COUNTS_PER_RAD), "rear_steer": 0}
    r.run(0.6, setpoints=far)
    moved = r.master.drives["front_steer"].target / STEER_COUNTS_PER_RAD
    assert moved == pytest.approx(0.1 * 4.0, abs=0.05)             # 100 ms at steer_speed_radps = 4, not a jump
    r.run(1.5, setpoints=far)
    assert r.actuals()["front_steer"] == pytest.approx(far["front_steer"], abs=50)
    assert not r.master.latched


def test_sync_jitter_is_tolerated(rig):
    rng = np.random.default_rng(3)
    r = rig()
    steps = np.round(0.01 * np.arange(1, 201) + rng.uniform(-0.003, 0.003, 200), 3)   # +-3 ms on a 10 ms grid
    r.run(2.0, steps=steps)
    gaps = np.diff([t for t, cob in r.frames if cob == p.SYNC])
    assert gaps.max() - gaps.min() >= 0.008                         # the SYNC really jittered
    assert r.master.enabled() and not r.master.latched
    assert all(codes == [] for codes in r.emcy().values())
    assert r.actuals() == pytest.approx(RUN, abs=5.0)


def test_catch_up_steps_after_a_stall_do_not_burst_sync(rig):
    """The master's caller stalls 25 ms (2.5 SYNC periods: no drive trips), then runs its missed steps
    back to back, a millisecond apart, as a real-time loop catching up does: one SYNC goes out, the
    missed slots are skipped, and the next SYNC keeps the grid -- never SYNCs milliseconds apart."""
    r = rig()
    r.run(1.0)
    resume = [1.026, 1.027, 1.028] + [round(1.03 + 0.01 * k, 3) for k in range(50)]
    r.run(1.5, steps=resume)
    syncs = [t for t, cob in r.frames if cob == p.SYNC and t > 0.9]
    gaps = np.diff(syncs)
    assert gaps.max() == pytest.approx(0.026, abs=1e-6)                 # the stall itself
    assert gaps.min() >= 0.005 - 1e-9                                   # no burst after it
    assert 1.026 in syncs and 1.04 in syncs and 1.03 not in syncs       # late SYNC, then back on the grid
    assert r.master.enabled() and all(codes == [] for codes in r.emcy().values())


def test_a_step_stamped_before_a_stall_does_not_make_the_next_sync_a_burst(rig):
    """A loop reads the clock, is stalled 15 ms, then steps with that stale reading: its SYNC goes out
    at the true time, so the next step 2 ms later must not send another (spacing by the clock)."""
    r = rig()
    r.run(1.0)
    stale = 1.0101                                         # the tick's clock reading, just before the stall
    r.t = 1.016
    r.hub.advance(r.t)
    r.master.step(stale, RUN)
    r.t = 1.018
    r.hub.advance(r.t)
    r.master.step(r.t, RUN)
    syncs = [t for t, cob in r.frames if cob == p.SYNC and t > 1.0]
    assert syncs == [1.016]


def test_sync_keeps_its_grid_when_steps_come_late(rig):
    """Steps 1-4 ms late (a loaded machine): every step still sends its SYNC, at most one per slot."""
    rng = np.random.default_rng(5)
    r = rig()
    steps = np.round(0.01 * np.arange(1, 201) + rng.uniform(0.001, 0.004, 200), 3)
    r.run(2.0, steps=steps)
    syncs = [t for t, cob in r.frames if cob == p.SYNC]
    assert len(syncs) == r.master.syncs_sent and len(syncs) >= 195
    assert np.diff(syncs).min() >= 0.006 - 1e-9 and not r.master.latched


def test_a_lost_sync_producer_stops_every_drive(rig):
    """The master stalls (no step: no RPDO, no SYNC): every drive quick-stops itself after three
    SYNC cycles, long before the heartbeat consumer (300 ms) would; nothing restarts when it resumes."""
    r = rig()
    r.run(1.0)
    assert all(abs(v) > 1000 for name, v in r.actuals().items() if "wheel" in name)
    stalled = r.t
    r.run(1.05, steps=[])
    assert {d.state for d in r.bank.drives.values()} == {p.QUICK_STOP_ACTIVE}
    assert r.emcy() == {name: [0x8700] for name in r.bank.drives}
    r.run(1.5, steps=[])                 # later the master's heartbeat is missed too (0x8130: fault)
    assert {d.state for d in r.bank.drives.values()} <= {p.QUICK_STOP_ACTIVE, p.FAULT}
    assert all(codes[0] == 0x8700 for codes in r.emcy().values())
    assert all(v == 0.0 for name, v in r.actuals().items() if "wheel" in name)       # no motor runs uncommanded
    first = min(t for t, cob in r.frames if cob & 0x780 == p.EMCY and cob != p.SYNC and t > stalled)
    assert first - stalled <= 0.0365                                 # 3.5 periods, on the 1 ms motor grid
    r.run(2.0)                                                       # the master is back, commands still coming
    assert "0x8700" in r.master.latched and not r.master.enabled()
    assert all(v == 0.0 for name, v in r.actuals().items() if "wheel" in name)


def test_a_drive_that_misses_sync_for_three_cycles_is_quick_stopped_and_so_are_the_others(rig):
    r = rig()
    r.run(1.0)
    r.bank.drives["rear_steer"].faults.sync_deaf = True
    deaf = r.t
    r.run(1.1)
    assert r.bank.drives["rear_steer"].state == p.QUICK_STOP_ACTIVE
    assert r.emcy()["rear_steer"] == [0x8700]
    t_emcy = min(t for t, cob in r.frames if cob == p.EMCY + 4)
    assert 0.03 < t_emcy - deaf <= 0.0365                           # three cycles missed, half a period's grace
    assert r.master.latched.startswith("rear_steer: EMCY 0x8700")
    r.run(2.0)
    assert {d.state for d in r.bank.drives.values()} == {p.QUICK_STOP_ACTIVE}
    assert all(v == 0.0 for name, v in r.actuals().items() if "wheel" in name)


OFF = int(0.3 * STEER_COUNTS_PER_RAD)        # steering physically at 0.3 rad at power-up
ENCODER = 40_000                              # and its incremental encoder reads 40 000 counts off


@pytest.mark.parametrize("method", [0, 19])
def test_homing_puts_the_steering_where_the_counts_say(rig, method):
    knobs = {name: SimDriveConfig(position_offset=OFF, encoder_offset=ENCODER)
             for name in ("front_steer", "rear_steer")}
    r = rig(knobs=knobs, homing_method=method)
    r.run(6.0, setpoints=None, stop=r.master.ready)
    ready_at = r.t
    assert r.master.ready()
    r.run(ready_at + 1.0)
    physical = r.actuals()["front_steer"]             # the sim's true steering angle, in counts
    if method == 0:                                   # not homed: the steering ends up off by the encoder error
        assert physical == pytest.approx(RUN["front_steer"] - ENCODER, abs=50)
        assert ready_at < 0.2
    else:                                             # homed on the switch at the true zero: right
        assert physical == pytest.approx(RUN["front_steer"], abs=50)
        assert ready_at > 0.5                         # it drove 0.3 rad to the switch at 0.5 rad/s first
    assert not r.master.latched


def test_a_homing_error_trips_the_master(rig):
    knobs = {"rear_steer": SimDriveConfig(home_switch=None)}
    r = rig(knobs=knobs, homing_method=19, homing_speed_radps=4.0)
    r.run(3.0)
    assert "rear_steer: homing error (method 19" in r.master.latched
    assert not r.master.enabled() and all(v == 0.0 for n, v in r.actuals().items() if "wheel" in n)
    r.bank.drives["rear_steer"].faults.home_switch = 0             # the switch wired back: reset homes again
    r.master.reset()
    r.run(8.0, stop=r.master.enabled)
    assert r.master.enabled() and not r.master.latched


@pytest.mark.parametrize("config, match", [
    (dict(steer_mode="csp", sync_hz=0.0), "cyclic synchronous modes need"),
    (dict(wheel_mode="csv", sync_hz=200.0, rate_hz=100.0), "sync_hz <= rate_hz"),
    (dict(steer_mode="cst"), "steer_mode"),
    (dict(homing_method=300), "int8"),
])
def test_bad_cyclic_configs_are_refused(config, match):
    with pytest.raises(ValueError, match=match):
        Cia402Master(SyncCanHub().bus("x"), Config(**config))


def test_driver_node_publishes_measured_at_the_control_rate():
    from drivers.canopen402 import Cia402Bus
    from msgs.control import WheelCommand
    from tether.testing import Harness
    hub = SyncCanHub()
    bank = LockstepDriveBank(hub.bus("drives"), {d.name: make_drive(d, None, 0.0) for d in DEFAULT_DRIVES})
    node_cls = type("Cia402Bus", (Cia402Bus,), {"open_bus": lambda self: hub.bus("master")})
    cmd = WheelCommand(v_front_mps=0.2, delta_front_rad=0.1, v_rear_mps=0.2, delta_rear_rad=-0.1)
    with Harness(node_cls, params={"publish_frames": False, "measured_hz": 50.0, **CYCLIC}) as h:
        for k in range(1, 1001):
            t = k * 1e-3
            hub.advance(t)
            h.feed([(t, "cmd", cmd)] if k % 20 == 0 else [], until_s=t)
        measured, states = h.of("measured"), h.of("drives")
    bank.bus.shutdown()
    assert 49 <= len(measured) <= 51 and 19 * 4 <= len(states) <= 21 * 4     # 50 Hz; drive states at 20 Hz
    last = measured[-1]
    assert (last.v_front_mps, last.delta_front_rad, last.delta_rear_rad) == pytest.approx((0.2, 0.1, -0.1), abs=2e-3)


def test_closing_the_master_quick_stops_cyclic_drives_at_once(rig):
    r = rig()
    r.run(1.0)
    r.master.close()                 # its last RPDOs are synchronous: it sends the SYNC that delivers them
    assert {d.state for d in r.bank.drives.values()} == {p.QUICK_STOP_ACTIVE}
    assert all(codes == [] for codes in r.emcy().values())          # stopped by command, not by the watchdog
