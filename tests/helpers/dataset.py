"""Reading a dataset folder's frame arrays back, for comparisons between runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def npz_arrays(root: Path) -> dict[str, dict[str, np.ndarray]]:
    out = {}
    for path in sorted(root.rglob("*.npz")):
        with np.load(path) as data:
            out[str(path.relative_to(root))] = {k: data[k] for k in data.files}
    return out
