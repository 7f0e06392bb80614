"""launch/ackermann_can.yaml wires trajectory -> controller -> CAN master -> simulated drives -> vehicle."""
from __future__ import annotations

from pathlib import Path

from tether.launch import load_launch

LAUNCH = Path(__file__).resolve().parents[2] / "launch" / "ackermann_can.yaml"


def test_ackermann_can_launch_wiring():
    launch = load_launch(LAUNCH)
    nodes = {n.id: n for n in launch.nodes}
    assert nodes["can"].node == "drivers.canopen402:Cia402Bus"
    assert nodes["drives"].node == "sim.cia402_drive:Cia402DriveSim"
    assert nodes["can"].inputs["cmd"] == "controller/cmd"
    assert nodes["vehicle"].inputs["actuation"] == "drives/achieved"
    assert nodes["controller"].inputs["state"] == "vehicle/state"
    assert set(nodes["eval"].inputs) == {"reference", "state"}
    # master and drives meet on the same bus
    keys = ("interface", "channel", "port")
    assert [nodes["can"].params[k] for k in keys] == [nodes["drives"].params[k] for k in keys]
