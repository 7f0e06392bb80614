"""Real CiA 402 drives (skipped unless TETHER_HARDWARE=1): bring-up only, nothing is commanded to move.

    TETHER_HARDWARE=1 TETHER_CAN_INTERFACE=socketcan TETHER_CAN_CHANNEL=can0 TETHER_CAN_NODES=1,2,3,4 \
        pytest tests/drivers/test_canopen402_hardware.py
"""
from __future__ import annotations

import os
import time

import pytest

from drivers import cia402 as p
from drivers.can_bus import open_bus
from drivers.canopen402 import DEFAULT_DRIVES, Cia402Master, Config

pytestmark = [pytest.mark.hardware,
              pytest.mark.skipif(os.environ.get("TETHER_HARDWARE") != "1", reason="needs real drives (TETHER_HARDWARE=1)")]


def test_real_drives_come_up_and_report_a_known_state():
    env = os.environ
    nodes = [int(n) for n in env.get("TETHER_CAN_NODES", "1,2,3,4").split(",")]
    drives = [d for d in DEFAULT_DRIVES if d.node_id in nodes]
    cfg = Config(interface=env.get("TETHER_CAN_INTERFACE", "socketcan"), channel=env.get("TETHER_CAN_CHANNEL", "can0"),
                 bitrate=int(env.get("TETHER_CAN_BITRATE", "500000")), drives=drives)
    master = Cia402Master(open_bus(cfg.interface, cfg.channel, cfg.bitrate), cfg)
    master.start()
    try:
        end = time.monotonic() + 10.0
        while not master.ready() and time.monotonic() < end:
            master.step(time.monotonic(), None)        # never a set-point: quick stop / hold only
            time.sleep(0.01)
        assert master.ready(), {d.name: d.nmt_state for d in master.drives.values()}
        for d in master.drives.values():
            assert d.state in {s for s, _, _ in p.STATE_MASKS} and d.state != p.OPERATION_ENABLED
    finally:
        master.close()
