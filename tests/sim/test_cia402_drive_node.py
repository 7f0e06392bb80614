"""sim.cia402_drive.Cia402DriveSim node: answers a master on the bus, publishes what the motors achieve."""
from __future__ import annotations

import os
import threading
import time

import pytest

from drivers.can_bus import open_bus
from drivers.canopen402 import Cia402Master, Config
from sim.cia402_drive import Cia402DriveSim
from tether.testing import Harness


def test_sim_node_answers_and_reports_achieved_motion():
    channel = f"sim-node-{os.getpid()}"
    h = Harness(Cia402DriveSim, params={"interface": "virtual", "channel": channel,
                                        "sim": {"rear_steer": {"vendor_bits": 256, "junk_hex": "8faf8faf"}}})
    master = Cia402Master(open_bus("virtual", channel), Config(interface="virtual", channel=channel))
    master.start()
    try:
        sp = {"front_wheel": 32_595, "front_steer": 16_297, "rear_wheel": 32_595, "rear_steer": -16_297}
        t0 = time.monotonic()
        end = t0 + 5.0
        while time.monotonic() < end:
            master.step(time.monotonic(), sp)
            h.advance_to(time.monotonic() - t0)                   # publishes at its timer rate
            got = h.of("achieved")
            if got and abs(got[-1].v_front_mps - 0.5) < 0.01 and abs(got[-1].delta_rear_rad + 0.5) < 0.01:
                break
            time.sleep(0.01)
        last = h.of("achieved")[-1]
        assert last.v_front_mps == pytest.approx(32_595 / master.drives["front_wheel"].spec.counts_per_unit, abs=0.01)
        assert last.delta_rear_rad == pytest.approx(-0.5, abs=0.01)
        assert master.drives["rear_steer"].statusword & 0x0100          # vendor bit configured by param
    finally:
        master.close()
        h.close()
    assert not any(t.name == "sim-cia402" and t.is_alive() for t in threading.enumerate())


def test_sim_node_says_its_longest_sync_gap_as_the_bench_reads_it(caplog):
    """The drives' longest SYNC gap, logged at teardown, is the line bench/ackermann_can.py parses for
    the launched runs (the bench's regex is imported, so a changed wording fails here, not silently there)."""
    import importlib.util
    spec = importlib.util.spec_from_file_location(
        "ackermann_can_bench", os.path.join(os.path.dirname(__file__), "..", "..", "bench", "ackermann_can.py"))
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    h = Harness(Cia402DriveSim, params={"interface": "virtual", "channel": f"sim-gap-{os.getpid()}"})
    drive = h.node.bank.drives["rear_steer"]
    drive.od[(0x1006, 0)].value = 10_000                             # SYNC every 10 ms, as the master sets it
    drive.max_sync_gap_s = 0.0271                                    # as its watchdog would have seen it
    with caplog.at_level("INFO"):
        h.close()
    m = bench.GAP_LINE.search(caplog.text)
    assert m and float(m.group(1)) == pytest.approx(27.1)
    assert "rear_steer" in caplog.text and "quick stop beyond 35.0 ms" in caplog.text
