"""The import map: benchmarks do not import each other in circles (issue 23, section 5)."""
from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _imports(path: Path) -> set[str]:
    """Top-level module names ``path`` imports anywhere (function bodies included)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names.add(node.module.split(".")[0])
    return names


def test_benchmarks_do_not_import_each_other_in_circles():
    benches = {p.stem: p for p in (REPO / "bench").glob("*.py")}
    graph = {name: _imports(path) & set(benches) - {name} for name, path in benches.items()}
    cycles = sorted({tuple(sorted((a, b))) for a, deps in graph.items() for b in deps if a in graph.get(b, set())})
    assert cycles == [], f"benchmarks importing each other: {cycles} (shared code belongs in a module both use)"


def test_capability_nodes_do_not_reach_up_into_simulators_or_drivers():
    """nodes/ sits below sim/ and drivers/: learning takes demonstrations as arrays and logs, the
    simulator makes them (sim/irl_demos.py). The sonar evaluation node draws the simulated scene
    it is scored against: an observer of a simulation by purpose, exempt."""
    upward = []
    for path in sorted((REPO / "nodes").rglob("*.py")):
        upward += [f"{path.relative_to(REPO)}: {n}" for n in sorted(_imports(path)) if n in ("sim", "drivers", "bench")]
    assert [u for u in upward if not u.startswith("nodes/sonar/evaluate.py")] == []


def test_import_verbs_come_from_entry_points(tmp_path):
    """The runtime finds importers by entry point; an unknown kind is one line naming the known ones."""
    import subprocess
    import sys

    from tether.imports import importers

    assert {"oculus", "candump", "can", "ping360"} <= set(importers())
    assert importers()["candump"].value == "drivers.candump:import_candump"
    out = subprocess.run([sys.executable, "-m", "tether.cli", "import", "nosuch", str(tmp_path / "x"), "-o",
                          str(tmp_path / "y.mcap")], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert out.returncode == 2 and "no importer 'nosuch'; registered: can, candump, oculus, ping360" in out.stderr
