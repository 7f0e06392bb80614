"""drivers.canopen402.Cia402Bus through tether.testing.Harness, paced in real time:
against simulated drives in another process over udp_multicast, and in-process over the
virtual bus for the command hard cases."""
from __future__ import annotations

import math
import os
import random
import subprocess
import sys
import time
from pathlib import Path

import msgspec
import pytest

from drivers.canopen402 import DEFAULT_DRIVES, Cia402Bus
from msgs.control import WheelCommand
from msgs.std import Empty
from drivers.can_bus import open_bus
from sim.cia402_drive import SimDrive, SimDriveBank
from tether.testing import Harness

REPO = Path(__file__).resolve().parents[2]
CMD = WheelCommand(v_front_mps=0.5, delta_front_rad=0.3, v_rear_mps=0.5, delta_rear_rad=-0.3)


def paced(h: Harness, seconds: float, cmd: WheelCommand | None = CMD, until=None) -> bool:
    """Advance the harness clock with wall time, feeding ``cmd`` every 20 ms."""
    t0 = time.monotonic() - h.now_ns() * 1e-9
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        t = time.monotonic() - t0
        h.feed([(t, "cmd", cmd)] if cmd is not None else [], until_s=t)
        if until is not None and until():
            return True
        time.sleep(0.02)
    return until is None


def latest_states(h: Harness) -> dict:
    return {s.name: s for s in h.of("drives")[-len(DEFAULT_DRIVES):]}


def tracking(h: Harness, cmd: WheelCommand = CMD) -> bool:
    s = latest_states(h)
    return (len(s) == 4 and all(x.state == "OPERATION ENABLED" for x in s.values())
            and abs(s["front_wheel"].velocity_unit - cmd.v_front_mps) < 0.01
            and abs(s["front_steer"].position_unit - cmd.delta_front_rad) < 0.01
            and abs(s["rear_steer"].position_unit - cmd.delta_rear_rad) < 0.01)


def stopped(h: Harness) -> bool:
    s = latest_states(h)
    return len(s) == 4 and all(x.velocity == 0 for x in s.values()) and all(x.quick_stop for x in s.values())


@pytest.fixture
def multicast_drives(tmp_path):
    """Simulated drives in their own process on a private udp_multicast port."""
    port = random.Random(os.getpid()).randrange(44_000, 48_000)
    log = open(tmp_path / "drives.log", "wb")
    proc = subprocess.Popen([sys.executable, "-m", "tether.cli", "run", "sim.cia402_drive:Cia402DriveSim",
                             "--param", "interface=udp_multicast", "--param", f"port={port}"],
                            cwd=REPO, stdout=log, stderr=subprocess.STDOUT)
    try:
        yield port
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
        log.close()


def test_drives_in_another_process_over_udp_multicast(multicast_drives):
    h = Harness(Cia402Bus, params={"interface": "udp_multicast", "port": multicast_drives, "boot_timeout_s": 0.5,
                                   "retry_s": 0.5})
    try:
        assert paced(h, 15.0, until=lambda: tracking(h)), latest_states(h)
        m = h.of("measured")[-1]
        assert m.v_front_mps == pytest.approx(0.5, abs=0.01) and m.delta_front_rad == pytest.approx(0.3, abs=0.01)
        frames = h.of("frames")
        tx = [f for f in frames if not f.is_rx]
        assert any(f.arbitration_id == 0x201 for f in tx) and any(f.arbitration_id == 0x181 and f.is_rx for f in frames)
        # udp_multicast echoes our own frames: none of ours may come back as received
        assert not any(f.is_rx and f.arbitration_id in (0x000, 0x201, 0x202, 0x203, 0x204, 0x77F) for f in frames)
        # commands stop: watchdog quick-stops every drive
        assert paced(h, 3.0, cmd=None, until=lambda: stopped(h)), latest_states(h)
    finally:
        h.close()


@pytest.fixture
def virtual_drives():
    channel = f"node-test-{os.getpid()}-{random.random()}"
    bus = open_bus("virtual", channel)
    now = time.monotonic()
    bank = SimDriveBank(bus, {d.name: SimDrive(d.node_id, role=d.role, now_s=now) for d in DEFAULT_DRIVES}).start()
    yield channel, bank
    bank.stop()
    bus.shutdown()


def test_non_finite_command_is_counted_and_does_not_feed_the_watchdog(virtual_drives, caplog):
    channel, bank = virtual_drives
    h = Harness(Cia402Bus, params={"interface": "virtual", "channel": channel, "publish_frames": False})
    try:
        assert paced(h, 5.0, until=lambda: tracking(h)), latest_states(h)
        bad = WheelCommand(v_front_mps=math.nan, delta_front_rad=0.0, v_rear_mps=0.5, delta_rear_rad=0.0)
        assert paced(h, 3.0, cmd=bad, until=lambda: stopped(h)), latest_states(h)
        assert h.node._rejected["bad"] > 0
        assert all(v == 0.0 for n, v in bank.actuals().items() if "wheel" in n)
    finally:
        h.close()
    assert any("ignored wheel command" in r.getMessage() for r in caplog.records)


def test_reset_input_clears_a_latched_fault(virtual_drives):
    channel, bank = virtual_drives
    h = Harness(Cia402Bus, params={"interface": "virtual", "channel": channel, "publish_frames": False})
    try:
        assert paced(h, 5.0, until=lambda: tracking(h))
        with bank.lock:
            bank.drives["front_wheel"].inject_fault(0x4210)
        assert paced(h, 3.0, until=lambda: stopped(h) or latest_states(h)["front_wheel"].state == "FAULT")
        assert paced(h, 3.0, until=lambda: all(v == 0.0 for n, v in bank.actuals().items() if "wheel" in n))
        s = latest_states(h)
        assert s["front_wheel"].emcy_code == 0x4210 and "excess temperature" in s["front_wheel"].fault
        assert paced(h, 0.5) is True and not tracking(h)            # still commanded, still stopped
        h.feed([(h.now_ns() * 1e-9, "reset", Empty())])
        assert paced(h, 5.0, until=lambda: tracking(h)), latest_states(h)
    finally:
        h.close()


def test_absurd_speed_is_scaled_to_the_limit_and_counted(virtual_drives):
    channel, bank = virtual_drives
    h = Harness(Cia402Bus, params={"interface": "virtual", "channel": channel, "publish_frames": False,
                                   "max_speed_mps": 1.0})
    try:
        fast = WheelCommand(v_front_mps=1e4, delta_front_rad=0.3, v_rear_mps=5e3, delta_rear_rad=-0.3)
        want = WheelCommand(v_front_mps=1.0, delta_front_rad=0.3, v_rear_mps=0.5, delta_rear_rad=-0.3)
        assert paced(h, 6.0, cmd=fast, until=lambda: tracking(h, want)), latest_states(h)
        s = latest_states(h)
        assert s["rear_wheel"].velocity_unit == pytest.approx(0.5, abs=0.01)        # the ratio is kept
        assert h.node._clamped > 0
        assert max(abs(v) for n, v in bank.actuals().items() if "wheel" in n) <= 1.0 * DEFAULT_DRIVES[0].counts_per_unit + 1
    finally:
        h.close()


def test_commands_stamped_in_the_past_do_not_keep_the_wheels_turning(virtual_drives, caplog):
    channel, bank = virtual_drives
    h = Harness(Cia402Bus, params={"interface": "virtual", "channel": channel, "publish_frames": False})
    try:
        assert paced(h, 5.0, until=lambda: tracking(h)), latest_states(h)
        t0 = time.monotonic() - h.now_ns() * 1e-9
        end = time.monotonic() + 3.0
        while time.monotonic() < end and not stopped(h):              # arrive on time, stamped 5 s ago
            t = time.monotonic() - t0
            old = msgspec.structs.replace(CMD, stamp_ns=int((t - 5.0) * 1e9))
            h.feed([(t, "cmd", old)], until_s=t)
            time.sleep(0.02)
        assert stopped(h), latest_states(h)
        assert h.node._rejected["stale"] > 0
    finally:
        h.close()
    assert any("stamped -5" in r.getMessage() or "stamped +5" in r.getMessage() for r in caplog.records)
