"""Matplotlib for the bench plots: the headless backend and one way to write a figure.

Each ``plot`` function imports this module inside its body, so measuring (and ``bench --help``) never
pays for importing matplotlib.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # no display on bench machines; must precede the pyplot import
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker as ticker  # noqa: E402

__all__ = ["plt", "save", "ticker"]


def save(fig: plt.Figure, png: Path) -> Path:
    """Lay out ``fig``, write it to ``png`` at 120 dpi and free it."""
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    plt.close(fig)
    return Path(png)
