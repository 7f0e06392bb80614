"""The benches' figure files: one way to lay out, write and close a matplotlib figure."""
from __future__ import annotations

from pathlib import Path
from typing import Any


def save_figure(fig: Any, path: str | Path, *, dpi: int = 100, rect: tuple[float, float, float, float] | None = None,
                **savefig: Any) -> Path:
    """Lay ``fig`` out (``tight_layout``, within ``rect`` if given), write it to ``path`` (its folder made if
    missing: a fresh clone has no ``out/``), close it (a bench that sweeps does not keep every figure in memory)
    and return the path. ``savefig`` goes to :meth:`matplotlib.figure.Figure.savefig` (e.g. ``bbox_inches``)."""
    import matplotlib.pyplot as plt

    fig.tight_layout(**({} if rect is None else {"rect": rect}))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, **savefig)
    plt.close(fig)
    return path
