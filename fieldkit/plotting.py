"""The one way fieldkit makes a figure: matplotlib on Agg, saved the same way every time."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def figure(
    rows: int = 1, cols: int = 1, size: tuple[float, float] = (8.0, 4.5)
) -> tuple[Figure, Any]:
    """A matplotlib figure on the Agg backend (no display needed, same pixels everywhere)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(rows, cols, figsize=size, squeeze=False)


def save(fig: Figure, path: Path) -> None:
    """Save without the matplotlib version in the metadata, so reruns give the same file."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=100, metadata={"Software": None})
    plt.close(fig)


__all__ = ["figure", "save"]
