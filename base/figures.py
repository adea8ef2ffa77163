"""Writing a matplotlib figure: the one ending every plot of the library shares."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def save_figure(fig: Any, path: str | Path, dpi: float | None = None) -> Path:
    """Lay out `fig` (a matplotlib Figure), write it to `path` (its folder made where absent; `dpi`
    None: matplotlib's default) and close it. Returns the path written."""
    import matplotlib.pyplot as plt

    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return out
