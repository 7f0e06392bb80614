"""Look-compute-move gathering (known results reproduced) and launch graphs as Kripke structures."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from nodes.verify.ctl import Checker
from nodes.verify.graph_model import GraphEdge, GraphNode, GraphSpec, default_properties, spec_from_launch, verify_spec
from nodes.verify.lcm import FAIRNESS, Algorithm, all_algorithms, gathering_model
from tether.launch import load_launch

REPO = Path(__file__).resolve().parents[3]
GATHER = "AF AG gathered"


def gathers(n: int, scheduler: str, algo: Algorithm, visibility: int | None = None) -> bool:
    return Checker(gathering_model(n, scheduler, algo, visibility=visibility), FAIRNESS).check(GATHER).holds


def test_two_oblivious_robots_gather_under_fsync_but_not_ssync_or_async():
    n = 7
    fsync = [a for a in all_algorithms(n) if gathers(n, "fsync", a)]
    assert [str(a) for a in fsync] == ["{1:away, 2:toward, 3:away}"]      # work on the even arc
    for scheduler in ("ssync", "async"):
        assert not any(gathers(n, scheduler, a) for a in all_algorithms(n)), scheduler


def test_the_ssync_counterexample_is_the_adversary_of_suzuki_yamashita():
    algo = Algorithm(("toward", "toward", "toward"))
    r = Checker(gathering_model(7, "ssync", algo), FAIRNESS).check(GATHER)
    assert not r.holds and r.loop_start is not None
    loop = r.trace[r.loop_start:]
    # in the loop the robots are adjacent and swap: both activated every time (fair, never gathered)
    assert all(s[2] == 3 and min((s[1] - s[0]) % 7, (s[0] - s[1]) % 7) == 1 for s in loop)


def test_meeting_is_not_gathering_under_async():
    algo = Algorithm(("toward", "toward", "toward"))
    k = gathering_model(7, "async", algo)
    assert Checker(k, FAIRNESS).check("AF gathered").holds       # they always meet ...
    assert not Checker(k, FAIRNESS).check(GATHER).holds          # ... but a stale move parts them again


def test_knowledge_of_a_robot_that_sees_only_its_view():
    k = gathering_model(7, "async", Algorithm(("toward", "toward", "toward")), visibility=1)
    c = Checker(k, FAIRNESS)
    assert c.check("AG (gathered -> K[r1] gathered)").holds      # it sees distance 0
    assert not c.check("AG (gathered -> K[r1] AG gathered)").holds   # not the other's pending move
    assert c.check("AG (delta_3 -> !K[r1] delta_3)").holds       # out of sight: it cannot know how far


def test_limited_visibility_cannot_gather_from_afar_even_in_fsync():
    algo = Algorithm(("away", "toward", "away"), blind="move")
    assert gathers(7, "fsync", algo)
    assert not gathers(7, "fsync", algo, visibility=2)


def predicted(spec: GraphSpec, focus: str | None, formula: str, faults: int) -> bool:
    """What the default properties must say, from the launch file's restart policies alone."""
    if formula == "AG !deadlock":
        return faults == 0 or any(n.restart != "never" and n.max_restarts > 0 for n in spec.nodes)
    if formula.startswith("AG has_publisher"):
        return True
    sub = formula.split("handled(")[1].split(")")[0].rsplit(".", 1)[0]     # ids may be ns.node
    node = spec.node(sub)
    return faults == 0 or (node.restart != "never" and node.max_restarts > 0)


@pytest.mark.parametrize("path", sorted((REPO / "launch").glob("*.yaml")), ids=lambda p: p.name)
def test_every_launch_file_verifies_as_its_restart_policies_predict(path: Path):
    spec = spec_from_launch(load_launch(path))
    checks = default_properties(spec)
    for faults in (0, 1):
        results = verify_spec(spec, checks, faults=faults)
        for (focus, formula), r in zip(checks, results):
            assert r.holds == predicted(spec, focus, formula, faults), (faults, r.explain())
            assert r.holds or r.trace


def test_a_dropping_queue_counts_and_a_dead_publisher_is_found():
    spec = GraphSpec((GraphNode("cam", "on-failure", 3), GraphNode("det", "never")),
                     (GraphEdge("cam/image", "det", "image", depth=1),))
    [r] = verify_spec(spec, [("cam/image", "EF dropped(det.image)")])
    assert r.holds                                              # latest-only: a newer frame may replace it
    [r] = verify_spec(spec, [(None, "AG EF up(det)")])
    assert not r.holds and "det:DOWN" in r.trace[-1]


def test_tether_verify_cli(tmp_path):
    launch = str(REPO / "launch" / "counter.yaml")
    ok = subprocess.run([sys.executable, "-m", "tether.cli", "verify", launch, "--ctl",
                         "AG (published -> AF (handled(scale.value) | counted(scale.value)))"],
                        capture_output=True, text=True, cwd=REPO, timeout=120)
    assert ok.returncode == 0 and "holds" in ok.stdout
    bad = subprocess.run([sys.executable, "-m", "tether.cli", "verify", launch], capture_output=True, text=True,
                         cwd=REPO, timeout=120)
    assert bad.returncode == 1 and "printer:DOWN" in bad.stdout and "4 of 5 properties hold" in bad.stdout
    bound = subprocess.run([sys.executable, "-m", "tether.cli", "verify", str(REPO / "launch" / "social_nav.yaml"),
                            "--max-states", "50"], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert bound.returncode == 3 and "explored 50 states" in bound.stderr
