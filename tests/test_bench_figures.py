"""bench/figures.py: the benches' one way to write a figure."""
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")


def test_a_figure_is_written_into_a_missing_folder_and_closed(tmp_path: Path) -> None:
    import matplotlib.pyplot as plt
    from figures import save_figure

    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    path = save_figure(fig, tmp_path / "fresh" / "clone" / "out.png", dpi=40, rect=(0, 0.1, 1, 1))
    assert path == tmp_path / "fresh" / "clone" / "out.png"
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert fig.number not in plt.get_fignums()          # closed: a sweep does not keep every figure
