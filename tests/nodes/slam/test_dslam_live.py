"""The team as separate processes: two launchers (machines) over CurveZMQ tcp, a lossy capped link
between them, robots finding each other by place recognition; the monitor scores the result."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np
import pytest

from nodes.slam.graph_io import write_graph
from tether.transport import free_port_base

sys.path.insert(0, str(Path(__file__).parent))
from test_dslam import loop_world  # noqa: E402

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture
def env():
    base = tempfile.mkdtemp(prefix="td", dir="/tmp")
    out = dict(os.environ, TETHER_RUNTIME_DIR=os.path.join(base, "rt"), TETHER_KEYS_DIR=os.path.join(base, "keys"))
    yield out
    shutil.rmtree(base, ignore_errors=True)


def test_two_machines_build_one_map(tmp_path: Path, env: dict) -> None:
    graph = tmp_path / "loop.g2o"
    world = loop_world(21, laps=3, side=8, noise=0.5)
    laps = np.isin(world.edges, [[31, 32], [63, 64]]).all(axis=1)      # no rendezvous between the laps: the
    world.edges, world.z, world.info = world.edges[~laps], world.z[~laps], world.info[~laps]   # robots must find each other
    write_graph(graph, world)
    base = free_port_base(40)                  # alpha's ports from base, bravo's from base + 20
    common = f"graph: {graph}, robots: 3, keyframe_hz: 60, round_hz: 10, state_dir: {tmp_path / 'state'}"
    launch = tmp_path / "team.yaml"
    launch.write_text(textwrap.dedent(f"""
        name: dslamtest
        machines:
          alpha: {{host: 127.0.0.1, port_base: {base}}}
          bravo: {{host: 127.0.0.1, port_base: {base + 20}}}
        nodes:
          - {{id: robot0, node: nodes.slam.dslam_agent:DslamAgent, machine: alpha, params: {{robot: 0, {common}}},
              inputs: {{from_1: robot1/to_0, from_2: robot2/to_0}}}}
          - {{id: robot1, node: nodes.slam.dslam_agent:DslamAgent, machine: alpha, params: {{robot: 1, {common}}},
              inputs: {{from_0: robot0/to_1, from_2: robot2/to_1}}}}
          - {{id: robot2, node: nodes.slam.dslam_agent:DslamAgent, machine: bravo, params: {{robot: 2, {common}}},
              inputs: {{from_0: robot0/to_2, from_1: robot1/to_2}}}}
          - {{id: monitor, node: nodes.slam.dslam_monitor:TeamMonitor, machine: bravo,
              params: {{robots: 3, graph: {graph}, report_s: 1.0, out_dir: {tmp_path}}},
              inputs: {{robot_0: robot0/trajectory, robot_1: robot1/trajectory, robot_2: robot2/trajectory,
                       stats_0: robot0/_stats, stats_1: robot1/_stats, stats_2: robot2/_stats}}}}
        links:
          - {{between: [alpha, bravo], drop: 0.1, bandwidth_bps: 2000000, seed: 3}}
    """))
    cmd = [sys.executable, "-m", "tether.cli", "launch", str(launch), "--duration", "9"]
    alpha = subprocess.Popen([*cmd, "--machine", "alpha"], cwd=REPO, env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True)
    bravo = subprocess.run([*cmd, "--machine", "bravo"], cwd=REPO, env=env, capture_output=True, text=True, timeout=90)
    alpha_out = alpha.communicate(timeout=60)[0]
    out = bravo.stdout + bravo.stderr
    assert bravo.returncode == 0 and alpha.returncode == 0, out + alpha_out
    final = re.search(r"team final: cost ratio ([0-9.]+|inf) against the centralised optimum, (\d+) B sent", out)
    assert final, out
    ratio, sent = float(final.group(1)), int(final.group(2))
    assert ratio < 1.01 and sent > 0, out                      # one map, through place recognition and a lossy link
    assert "Traceback" not in out + alpha_out and "handler" not in out + alpha_out
    assert "security handshake" not in out + alpha_out    # same-host inputs of Curve publishers ride the Curve socket
    assert (tmp_path / "dslam_team.png").stat().st_size > 10_000
