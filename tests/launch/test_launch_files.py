"""Every shipped launch file validates (classes import, wiring and types match, params fit)."""
from __future__ import annotations

from pathlib import Path

import pytest

from tether.launch import load_launch

LAUNCH = Path(__file__).resolve().parents[2] / "launch"


@pytest.mark.parametrize("path", sorted(LAUNCH.glob("*.yaml")), ids=lambda p: p.name)
def test_launch_file_validates(path: Path) -> None:
    launch = load_launch(path)
    assert launch.nodes
    for entry in launch.nodes:
        for name, src in entry.inputs.items():
            assert name in entry.ports.inputs
