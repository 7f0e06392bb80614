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


def test_included_files_appear_under_their_namespaces() -> None:
    """A file that includes others holds each included node once per include, as NAMESPACE.ID."""
    from tether.launch_compose import compose

    for path in sorted(LAUNCH.glob("*.yaml")):
        top = compose(path)
        includes = top.doc.get("include") or []
        if not includes:
            continue
        ids = {n.id for n in load_launch(path).nodes}
        for inc in includes:
            inner = load_launch(path.parent / inc["file"], args=inc.get("args"))
            prefix = f"{inc['namespace']}." if inc.get("namespace") else ""
            assert {prefix + n.id for n in inner.nodes} <= ids, (path.name, inc["file"])
