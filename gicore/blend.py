"""Composition of direct illumination (DI) and a global-illumination (GI) map.

Two modes (docs/architecture.md, Composition), both on linear radiance:

- ``blend`` — the paper's eq. 1, ``P = tau * DI + (1 - tau) * GI``, a per-pixel weighted average where
  GI is the network's (or server's) full GI image.
- ``residual`` — keeps the current frame's DI exact and adds only the indirect part of the GI map,
  ``P = DI + max(GI - DI_gi, 0)``, where ``DI_gi`` is the DI that produced the GI map, warped alongside
  it. With a stale GI map this leaves direct lighting and shadows sharp and only delays indirect light.
"""

from __future__ import annotations

import numpy as np


def _finite(name: str, x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float32)
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name} contains NaN or Inf")
    return x


def blend(di: np.ndarray, gi: np.ndarray, tau: float) -> np.ndarray:
    """Eq. 1 of the paper: ``tau * di + (1 - tau) * gi`` with ``tau`` in [0, 1]."""
    if not (0.0 <= tau <= 1.0):
        raise ValueError(f"tau must lie in [0, 1], got {tau}")
    di, gi = _finite("di", di), _finite("gi", gi)
    if di.shape != gi.shape:
        raise ValueError(f"di and gi differ in shape: {di.shape} vs {gi.shape}")
    return tau * di + (1.0 - tau) * gi


def residual(di: np.ndarray, gi: np.ndarray, di_of_gi: np.ndarray) -> np.ndarray:
    """Current DI plus the (non-negative) indirect part ``gi - di_of_gi`` of a possibly stale GI map."""
    di, gi, di_of_gi = _finite("di", di), _finite("gi", gi), _finite("di_of_gi", di_of_gi)
    if not (di.shape == gi.shape == di_of_gi.shape):
        raise ValueError(f"shapes differ: di {di.shape}, gi {gi.shape}, di_of_gi {di_of_gi.shape}")
    return di + np.maximum(gi - di_of_gi, 0.0)


COMPOSITIONS = ("blend", "residual")
