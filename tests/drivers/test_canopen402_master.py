"""drivers.canopen402.Cia402Master against simulated drives on python-can's in-process
``virtual`` bus: bring-up, tracking, and the bus hard cases -- in none may a motor keep
running uncommanded."""
from __future__ import annotations

import contextlib
import itertools
import logging
import time

import can
import canopen
import msgspec
import pytest

from drivers import cia402 as p
from drivers.can_bus import open_bus
from drivers.canopen402 import DEFAULT_DRIVES, Cia402Master, Config
from sim.cia402_drive import DriveFaults, SimDrive, SimDriveBank

RUN = {"front_wheel": 65_000, "front_steer": 20_000, "rear_wheel": 65_000, "rear_steer": -20_000}
_channels = itertools.count()


@contextlib.contextmanager
def rig(faults: dict[str, DriveFaults] | None = None, **overrides):
    channel = f"cia402-test-{next(_channels)}"
    cfg = msgspec.structs.replace(Config(interface="virtual", channel=channel, sdo_timeout_s=0.1,
                                         boot_timeout_s=0.3, retry_s=0.3), **overrides)
    sim_bus, master_bus = open_bus("virtual", channel), open_bus("virtual", channel)
    now = time.monotonic()
    drives = {d.name: SimDrive(d.node_id, role=d.role, now_s=now, faults=(faults or {}).get(d.name))
              for d in cfg.drives}
    bank = SimDriveBank(sim_bus, drives).start()
    master = Cia402Master(master_bus, cfg)
    master.start()
    try:
        yield master, bank
    finally:
        master.close()
        bank.stop()
        sim_bus.shutdown()


def cycle(master: Cia402Master, seconds: float, setpoints=RUN, until=None) -> bool:
    """Step the master at 100 Hz for up to ``seconds``; True as soon as ``until()`` holds."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        master.step(time.monotonic(), setpoints)
        if until is not None and until():
            return True
        time.sleep(0.01)
    return until is None


def speeds(bank: SimDriveBank) -> dict[str, float]:
    with bank.lock:
        return {n: d.velocity for n, d in bank.drives.items()}


def all_still(bank: SimDriveBank) -> bool:
    return all(v == 0.0 for v in speeds(bank).values())


def running(bank: SimDriveBank) -> bool:
    a = bank.actuals()
    return (abs(a["front_wheel"] - RUN["front_wheel"]) < 500 and abs(a["rear_wheel"] - RUN["rear_wheel"]) < 500
            and abs(a["front_steer"] - RUN["front_steer"]) < 100 and abs(a["rear_steer"] - RUN["rear_steer"]) < 100)


def up_and_running(master, bank) -> None:
    assert cycle(master, 3.0, None, until=master.ready), "drives never came up"
    assert cycle(master, 3.0, until=lambda: running(bank)), f"never tracked: {bank.actuals()}"


def test_bring_up_maps_pdos_and_configures_each_drive():
    with rig() as (master, bank):
        assert cycle(master, 3.0, None, until=master.ready)
        for spec in DEFAULT_DRIVES:
            od = bank.drives[spec.name].od
            target = p.TARGET_VELOCITY if spec.role == "wheel" else p.TARGET_POSITION
            assert [od[(0x1600, s)].value for s in range(3)] == [2, 0x60400010, target << 16 | 0x20]
            assert [od[(0x1A00, s)].value for s in range(3)] == [2, 0x60410010, 0x60610008]
            assert [od[(0x1A01, s)].value for s in range(3)] == [2, 0x60640020, 0x606C0020]
            assert od[(0x1800, 5)].value == 10 and od[(0x1017, 0)].value == 100
            assert od[(0x1016, 1)].value == 127 << 16 | 300
            assert od[(0x1401, 1)].value & 0x80000000 and od[(0x1803, 1)].value & 0x80000000
            assert od[(p.MODES_OF_OPERATION, 0)].value == (p.MODE_PV if spec.role == "wheel" else p.MODE_PP)
        assert all_still(bank)                                      # configured, but nobody commanded motion


def test_tracks_set_points_and_watchdog_quick_stops_everything():
    with rig() as (master, bank):
        up_and_running(master, bank)
        assert all(d.state == p.OPERATION_ENABLED for d in master.drives.values())
        assert cycle(master, 3.0, None, until=lambda: all_still(bank)), speeds(bank)
        assert all(d.state == p.QUICK_STOP_ACTIVE for d in bank.drives.values())
        assert cycle(master, 3.0, until=lambda: running(bank))     # commands again: re-enabled


def test_emcy_mid_stream_stops_every_motor_until_reset():
    with rig() as (master, bank):
        up_and_running(master, bank)
        with bank.lock:
            bank.drives["rear_wheel"].inject_fault(0x2310)
        assert cycle(master, 3.0, until=lambda: all_still(bank)), speeds(bank)
        assert "0x2310" in master.latched
        cycle(master, 0.3)                                          # still commanded: stays stopped
        assert all_still(bank)
        assert master.drives["rear_wheel"].fault.startswith("EMCY 0x2310")
        master.reset()
        assert cycle(master, 3.0, until=lambda: running(bank))


def test_malformed_emcy_is_counted_not_fatal():
    with rig() as (master, bank):
        up_and_running(master, bank)
        bank.bus.send(can.Message(arbitration_id=p.EMCY + 1, data=b"\x10", is_extended_id=False))
        assert cycle(master, 1.0, until=lambda: master.errors >= 1)
        # not latched, still commanded (the steering may be inside its ~100-count profile-position overshoot)
        assert not master.latched and cycle(master, 1.0, until=lambda: running(bank))


@pytest.mark.parametrize("deaf", [False, True], ids=["mute", "disconnected"])
def test_heartbeat_loss_stops_every_motor(deaf):
    with rig() as (master, bank):
        up_and_running(master, bank)
        with bank.lock:
            bank.drives["front_steer"].faults.mute = True
            bank.drives["front_steer"].faults.deaf = deaf
            bank.drives["front_wheel"].faults.mute = True
            bank.drives["front_wheel"].faults.deaf = deaf
        assert cycle(master, 3.0, until=lambda: all_still(bank)), speeds(bank)
        # The PDO bound (200 ms) usually fires before the heartbeat's (300 ms): either names the drive.
        assert "heartbeat of front_" in master.latched or "feedback PDOs of front_" in master.latched
        if deaf:   # it never heard the quick stop: it stopped itself on the lost master heartbeat
            assert bank.drives["front_wheel"].state == p.FAULT and 0x8130 in bank.drives["front_wheel"].emcy_sent


def test_stalled_master_lets_the_drives_stop_themselves():
    with rig() as (master, bank):
        up_and_running(master, bank)
        deadline = time.monotonic() + 3.0                           # no more steps: no heartbeat, no RPDO
        while not all_still(bank) and time.monotonic() < deadline:
            time.sleep(0.02)
        assert all_still(bank)
        assert all(d.state == p.FAULT for d in bank.drives.values())


def test_drive_in_fault_at_start_is_reset_then_runs():
    with rig({"rear_steer": DriveFaults(start_in_fault=0x7300)}) as (master, bank):
        assert cycle(master, 3.0, None, until=master.ready)
        assert "0x7300" in master.drives["rear_steer"].fault
        assert cycle(master, 3.0, until=lambda: running(bank))
        assert 0x0000 in bank.drives["rear_steer"].emcy_sent         # the drive reported the reset


def test_persistent_fault_at_start_keeps_everything_still():
    with rig({"rear_steer": DriveFaults(start_in_fault=0x7300, sticky_fault=True)}) as (master, bank):
        assert cycle(master, 3.0, None, until=master.ready)
        cycle(master, 0.3)                                          # commanded, but one drive cannot run
        assert master.drives["rear_steer"].fault_resets == 1        # paced: one per fault_reset_interval_s
        cycle(master, 1.5)
        assert all_still(bank)
        assert master.drives["rear_steer"].fault_resets == master.cfg.max_fault_resets
        assert all(d.state != p.OPERATION_ENABLED for d in bank.drives.values())


def test_vendor_statusword_bits_0x0737():
    faults = {d.name: DriveFaults(vendor_bits=0x0100) for d in DEFAULT_DRIVES}
    with rig(faults) as (master, bank):
        up_and_running(master, bank)
        sw = master.drives["front_wheel"].statusword
        assert sw & 0x0100 and p.decode_state(sw) == p.OPERATION_ENABLED


def test_junk_after_the_indicated_size_is_ignored():
    faults = {d.name: DriveFaults(junk=b"\x8f\xaf\x8f\xaf") for d in DEFAULT_DRIVES}
    with rig(faults) as (master, bank):
        up_and_running(master, bank)                                # mode display / statusword reads decode


def test_position_actual_int32_wrap_is_unwrapped():
    faults = {"front_wheel": DriveFaults(position_offset=2**31 - 20_000)}
    with rig(faults) as (master, bank):
        up_and_running(master, bank)
        seen = []
        cycle(master, 1.0, until=lambda: seen.append(master.drives["front_wheel"].position) or seen[-1] > 2**31 + 20_000)
        assert seen[-1] > 2**31 + 20_000
        assert all(b >= a for a, b in zip(seen, seen[1:]))          # monotonic through the wrap


def test_sdo_abort_during_bring_up_leaves_everything_still(caplog):
    faults = {"rear_wheel": DriveFaults(sdo_abort={(0x1017, 0): 0x06010002})}
    with caplog.at_level(logging.ERROR, logger="drivers.canopen402"), rig(faults) as (master, bank):
        cycle(master, 1.0)                                          # commanded all along
        assert not master.ready() and not master.drives["rear_wheel"].configured
        assert all_still(bank)
    assert any("0x06010002 attempt to write a read-only object" in r.getMessage() for r in caplog.records)


def test_sdo_timeout_during_bring_up_leaves_everything_still(caplog):
    faults = {"front_steer": DriveFaults(sdo_silent={(0x1000, 0)})}
    with caplog.at_level(logging.ERROR, logger="drivers.canopen402"), rig(faults) as (master, bank):
        cycle(master, 1.0)
        assert not master.ready() and all_still(bank)
    assert any("front_steer" in r.getMessage() and "No SDO response" in r.getMessage() for r in caplog.records)


def test_missing_drive_is_reported_and_nothing_moves(caplog):
    with caplog.at_level(logging.ERROR, logger="drivers.canopen402"), rig() as (master, bank):
        with bank.lock:
            bank.drives["rear_steer"].faults.mute = True             # never answers, not even boot-up
            bank.drives["rear_steer"].faults.deaf = True
        cycle(master, 1.0)
        assert not master.drives["rear_steer"].configured and all_still(bank)
    assert any("rear_steer" in r.getMessage() and "no boot-up" in r.getMessage() for r in caplog.records)


def test_drive_rebooting_in_service_trips_and_is_reconfigured():
    with rig() as (master, bank):
        up_and_running(master, bank)
        with bank.lock:
            bank.drives["rear_wheel"].reboot(time.monotonic())
        assert cycle(master, 3.0, until=lambda: all_still(bank)), speeds(bank)
        assert "rear_wheel rebooted" in master.latched
        assert cycle(master, 3.0, until=master.ready)                # configured again in the background
        master.reset()
        assert cycle(master, 3.0, until=lambda: running(bank))


def test_object_dictionaries_from_the_shared_eds_and_dcf(shared_data):
    from drivers.canopen402 import check_object_dictionary
    eds = canopen.import_od(str(shared_data / "can" / "ros2_canopen_cia402_slave.eds"), node_id=1)
    for role in ("wheel", "steer"):       # no 0x1006: such a drive is not told the SYNC period (warned, skipped)
        assert check_object_dictionary(eds, role) == ([], {p.COMM_CYCLE_PERIOD})
    dcf = canopen.import_od(str(shared_data / "can" / "pilz_prbt_0_1.dcf"), node_id=1)
    problems, missing = check_object_dictionary(dcf, "wheel")
    assert problems == ["0x60FF missing"]                       # a joint module: no profile velocity target
    assert check_object_dictionary(dcf, "steer") == ([], {p.PROFILE_DECEL, p.QUICK_STOP_DECEL, p.COMM_CYCLE_PERIOD,
                                                         p.HOMING_SPEEDS, p.HOMING_ACCEL})
    with pytest.raises(ValueError, match="0x60FF missing"):
        Cia402Master(open_bus("virtual", "dcf-check"), Config(interface="virtual", channel="dcf-check",
                                                              eds=str(shared_data / "can" / "pilz_prbt_0_1.dcf")))


def test_runs_with_the_eds_object_dictionary(shared_data):
    with rig(eds=str(shared_data / "can" / "ros2_canopen_cia402_slave.eds")) as (master, bank):
        up_and_running(master, bank)


def test_feedback_pdos_that_stop_while_the_heartbeat_goes_on_stop_every_motor():
    with rig() as (master, bank):
        up_and_running(master, bank)
        with bank.lock:
            bank.drives["rear_wheel"].faults.pdo_mute = True       # heartbeat and SDO still answer
        assert cycle(master, 3.0, until=lambda: bool(master.latched))
        # The detector's own measure, not the wall clock (the virtual-time test pins the 200 ms):
        assert "feedback PDOs of rear_wheel (node 3)" in master.latched and "(bound 200 ms)" in master.latched
        assert master.drives["rear_wheel"].nmt_state != "LOST"     # it was not the heartbeat
        assert cycle(master, 3.0, until=lambda: all_still(bank)), speeds(bank)


def test_emcy_history_texts_and_the_error_code_read_after_an_in_service_fault():
    with rig() as (master, bank):
        up_and_running(master, bank)
        for code in (0x8120, 0x8210):                               # warnings: error passive, PDO length
            bank.bus.send(can.Message(arbitration_id=p.EMCY + 2, data=p.emcy_frame(code, 0x10), is_extended_id=False))
        with bank.lock:
            bank.drives["front_steer"].inject_fault(0x2310)
        d = master.drives["front_steer"]
        assert cycle(master, 3.0, until=lambda: d.error_code is not None), d.emcy_history
        assert [e.code for e in d.emcy_history][:3] == [0x8120, 0x8210, 0x2310]
        assert d.emcy_history[0].text == "CAN in error passive mode"
        assert d.emcy_history[1].text == "PDO not processed due to length error"
        assert d.error_code == 0x2310 and "EMCY 0x8120" in master.latched   # the first EMCY already tripped
