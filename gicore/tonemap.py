"""The one tone map used everywhere (network I/O, metrics, previews).

Linear HDR radiance ``x >= 0`` maps to display values in ``[0, 1)`` by Reinhard compression followed by
a 2.2 display gamma::

    T(x) = (x / (1 + x)) ** (1 / 2.2)
    T^-1(y) = y**2.2 / (1 - y**2.2)

It is monotone and invertible on ``[0, inf)``; ``inverse`` clips ``y`` just below 1 so that values a
network produces at the top of its range stay finite. Networks work in ``[-1, 1]`` (tanh outputs):
``to_signed`` / ``from_signed`` convert. NaN or Inf anywhere is an upstream bug (a diverged network, a
broken render) and every function here rejects it rather than passing it on.
"""

from __future__ import annotations

import numpy as np

GAMMA = 2.2
#: Largest display value ``inverse`` accepts before clipping (maps to ~4e4 linear).
Y_MAX = 1.0 - 1e-5


def _finite(what: str, x: np.ndarray) -> np.ndarray:
    x = np.asarray(x)
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{what} input contains NaN or Inf; check the renderer or network that produced it")
    return x


def tonemap(x: np.ndarray) -> np.ndarray:
    """Linear radiance (negative values clipped to 0) to display values in [0, 1)."""
    x = np.maximum(_finite("tonemap", x).astype(np.float32), 0.0)
    return (x / (1.0 + x)) ** (1.0 / GAMMA)


def inverse_tonemap(y: np.ndarray) -> np.ndarray:
    """Display values in [0, 1] back to linear radiance (exact inverse of :func:`tonemap`)."""
    y = np.clip(_finite("inverse_tonemap", y).astype(np.float32), 0.0, Y_MAX) ** GAMMA
    return y / (1.0 - y)


def to_signed(y: np.ndarray) -> np.ndarray:
    """[0, 1] display values to the [-1, 1] range of tanh outputs."""
    return 2.0 * y - 1.0


def from_signed(s: np.ndarray) -> np.ndarray:
    """[-1, 1] network values back to [0, 1] display values."""
    return np.clip((_finite("from_signed", s) + 1.0) * 0.5, 0.0, 1.0)
